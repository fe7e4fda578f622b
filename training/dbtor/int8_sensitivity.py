"""Which blocks lose the most when quantised: each exported block's int8
version swapped in alone, and each left in fp32 alone, scored on validation
slices (PSNR and SSIM against the truth, the conventions of dbt-eval).

    python -m dbtor.int8_sensitivity --model ../models/dbtor-x4 --data DS [--slices 16] [--level N8]

Runs the exported ONNX blocks with onnxruntime and the CSR operator of the
dataset (operator.py), the unrolled loop of model.py.
"""
import argparse
import json
import os

import numpy as np
import onnxruntime as ort
from skimage.metrics import structural_similarity

from .data import Split
from .operator import Operator


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--level", default="N8")
    ap.add_argument("--slices", type=int, default=16)
    a = ap.parse_args(argv)
    man = json.load(open(os.path.join(a.model, "manifest.json")))
    nrm = man["normalisation"]
    op = Operator(os.path.join(a.data, "operator"))
    if abs(op.norm - nrm["operator_norm"]) > 1e-6 * op.norm:
        raise SystemExit("the dataset's operator is not the model's")
    Pm = op.P
    Ptm = op.Pt
    mask_used = man.get("kind", "dbtor") == "dbtor"
    so = ort.SessionOptions()
    so.intra_op_num_threads = 2
    sess = {prec: [ort.InferenceSession(os.path.join(a.model, b[prec]), so) for b in man["blocks"]]
            for prec in ("fp32", "int8")}
    val = Split(a.data, "validation", a.level)
    idx = np.linspace(0, val.n - 1, min(a.slices, val.n)).astype(int)
    g_all, m_all, x_all = val.batch(idx)
    import torch

    def fwd(img):
        return torch.sparse.mm(Pm, torch.from_numpy(img.reshape(-1, 1))).numpy().reshape(op.sino_shape)

    def adj(s):
        return torch.sparse.mm(Ptm, torch.from_numpy(s.reshape(-1, 1))).numpy().reshape(op.image_shape)

    def recon(g, m, precs):
        gn = ((g - nrm["g_mean"]) / nrm["g_std"]).astype(np.float32)
        m = m.astype(np.float32)
        h = np.zeros((1, 5, *op.sino_shape), np.float32)
        f = np.zeros((1, 5, *op.image_shape), np.float32)
        pm = fwd(m)
        for i in range(len(man["blocks"]) // 2):
            k = 2 * i
            pf = fwd(np.ascontiguousarray(f[0, 1]))
            aux = [pf, gn, pm] if mask_used else [pf, gn]
            h = sess[precs[k]][k].run(None, {"state": h, "aux": np.stack(aux)[None].astype(np.float32)})[0]
            bh = adj(np.ascontiguousarray(h[0, 0]))
            aux = [bh, m] if mask_used else [bh]
            f = sess[precs[k + 1]][k + 1].run(None, {"state": f, "aux": np.stack(aux)[None].astype(np.float32)})[0]
        return f[0, 0] * nrm["x_scale_per_mm"]

    def score(precs):
        ps, ss = [], []
        for g, m, x in zip(g_all, m_all, x_all):
            z = recon(g, m, precs) * 10.0  # 1/cm
            t = x.astype(np.float64) * 10.0
            r = t.max() - t.min()
            ps.append(10 * np.log10(r * r / np.mean((z - t) ** 2)))
            ss.append(structural_similarity(t, z.astype(np.float64), data_range=r))
        return np.mean(ps), np.mean(ss)

    n = len(man["blocks"])
    names = [f"{b['role']}{b['index']:02d}" for b in man["blocks"]]
    base = score(["fp32"] * n)
    q = score(["int8"] * n)
    print(f"{'configuration':<28} {'PSNR dB':>8} {'SSIM':>7}")
    print(f"{'all fp32':<28} {base[0]:8.2f} {base[1]:7.3f}")
    print(f"{'all int8':<28} {q[0]:8.2f} {q[1]:7.3f}")
    for k in range(n):
        only = score(["fp32" if j != k else "int8" for j in range(n)])
        but = score(["int8" if j != k else "fp32" for j in range(n)])
        print(f"{'only ' + names[k] + ' int8':<28} {only[0]:8.2f} {only[1]:7.3f}   "
              f"{'all int8 but ' + names[k]:<22} {but[0]:8.2f} {but[1]:7.3f}", flush=True)


if __name__ == "__main__":
    main()
