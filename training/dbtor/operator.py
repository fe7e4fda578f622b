"""The Rust projector as a PyTorch operator (CSR from `DIR/operator`, see
crates/dbt-store/src/operator.rs). Rows: sinogram samples view-major; columns:
image pixels row-major; values: intersection lengths in mm."""
import json
import os

import numpy as np
import torch


class Operator:
    def __init__(self, directory):
        with open(os.path.join(directory, "operator.json")) as f:
            self.meta = json.load(f)
        if self.meta.get("format") != "dbtor-operator/1":
            raise ValueError(f"{directory}/operator.json: not a dbtor-operator/1 file")
        n_rows, n_cols, nnz = self.meta["n_rows"], self.meta["n_cols"], self.meta["nnz"]
        indptr = np.fromfile(os.path.join(directory, "indptr.u64"), dtype="<u8")
        indices = np.fromfile(os.path.join(directory, "indices.u32"), dtype="<u4")
        values = np.fromfile(os.path.join(directory, "values.f32"), dtype="<f4")
        if indptr.size != n_rows + 1 or indices.size != nnz or values.size != nnz:
            raise ValueError(f"{directory}: array sizes disagree with operator.json")
        g = self.meta["geometry"]
        self.image_shape = (g["image"]["rows"], g["image"]["columns"])
        self.sino_shape = (g["views"]["count"], g["detector"]["elements"])
        self.norm = float(self.meta["norm"])
        # The network sees P / ||P|| (so its inputs keep unit scale).
        v = torch.from_numpy(values.astype(np.float32) / np.float32(self.norm))
        self.P = torch.sparse_csr_tensor(
            torch.from_numpy(indptr.astype(np.int64)),
            torch.from_numpy(indices.astype(np.int64)),
            v,
            size=(n_rows, n_cols),
        )
        self.Pt = self.P.t().to_sparse_csr()

    def to(self, device):
        """The operator's matrices on `device` (train.py --device cuda: the
        sparse products run on the GPU); returns self."""
        self.P = self.P.to(device)
        self.Pt = self.Pt.to(device)
        return self

    def forward(self, img):
        """[B, 1, H, W] -> [B, 1, V, D], normalised operator."""
        return _Project.apply(img, self)

    def adjoint(self, sino):
        """[B, 1, V, D] -> [B, 1, H, W], normalised adjoint."""
        return _Backproject.apply(sino, self)


# The sparse products' label in torch.profiler's events (bench_step --profile).
PROFILE_LABEL = "dbtor.projector"


def _mm(a, x, out_shape):
    # Always in float32: the sparse product has no bfloat16 kernel, and under
    # --precision bf16 (train.py) only the convolutions run in bfloat16.
    b = x.shape[0]
    flat = x.reshape(b, -1).t().float().contiguous()
    with torch.autocast(flat.device.type, enabled=False), torch.profiler.record_function(PROFILE_LABEL):
        y = torch.sparse.mm(a, flat).t().contiguous()
    return y.reshape(b, 1, *out_shape)


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, img, op):
        ctx.op = op
        return _mm(op.P, img, op.sino_shape)

    @staticmethod
    def backward(ctx, grad):
        return _mm(ctx.op.Pt, grad, ctx.op.image_shape), None


class _Backproject(torch.autograd.Function):
    @staticmethod
    def forward(ctx, sino, op):
        ctx.op = op
        return _mm(op.Pt, sino, op.image_shape)

    @staticmethod
    def backward(ctx, grad):
        return _mm(ctx.op.P, grad, ctx.op.sino_shape), None
