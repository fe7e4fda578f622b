"""How far a model folder's int8 blocks read from its fp32 blocks, and
whether the difference is a drift (a bias or a gain) rather than noise:

    python -m dbtor.int8_drift --model ../models/dbtor-x4t3 --data DS [--slices 64] [--weights-only]

Both chains run in onnxruntime on the same slices of DS's validation split
(N8; never the training slices the export calibrated on), as
`export.run_onnx_sessions` does, the runtime's non-negativity applied to
both outputs. Printed, inside the breast (truth above 0.01 /mm) and outside
it: the mean of int8 - fp32 (1/mm and relative to fp32's mean), the slope
of int8 on fp32 inside the breast (1: the same contrast), the RMS
difference, and the spread over slices of each slice's relative mean
difference. `--weights-only` runs a copy of the int8 blocks with every
activation quantisation taken out (`export.drop_quantisations`), to tell
the weights' rounding from the activations'.
"""
import argparse
import json
import os
import shutil
import tempfile

import numpy as np
import onnxruntime as ort
import torch

from .data import Split
from .export import drop_quantisations, run_onnx_sessions
from .folder import check_operator, stats_of
from .operator import Operator
from .train import tensors


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--slices", type=int, default=64)
    ap.add_argument("--split", default="validation", choices=["validation", "train"])
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--weights-only", action="store_true")
    a = ap.parse_args(argv)
    with open(os.path.join(a.model, "manifest.json")) as f:
        man = json.load(f)
    stats = stats_of(man)
    op = Operator(os.path.join(a.data, "operator"))
    check_operator(man, op, a.data, a.model)
    so = ort.SessionOptions()
    so.intra_op_num_threads = 2
    tmp = tempfile.mkdtemp()
    try:
        def session(rel, strip=False):
            path = os.path.join(a.model, rel)
            if strip:
                path = shutil.copy(path, os.path.join(tmp, os.path.basename(rel)))
                drop_quantisations(path, lambda n, k, x: False)
            return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])

        fp = [session(b["fp32"]) for b in man["blocks"]]
        i8 = [session(b["int8"], a.weights_only) for b in man["blocks"]]
        split = Split(a.data, a.split, "N8")
        idx = np.random.default_rng(a.seed).choice(split.n, size=min(a.slices, split.n), replace=False)
        nb = len(man["blocks"]) // 2
        fs, qs, xs = [], [], []
        for s in range(0, len(idx), 4):
            g, m, x = tensors(split.batch(idx[s:s + 4]), stats)
            with torch.no_grad():
                fs.append(run_onnx_sessions(fp, op, g, m, nb)[:, 0].numpy() * stats["x_scale"])
                qs.append(run_onnx_sessions(i8, op, g, m, nb)[:, 0].numpy() * stats["x_scale"])
            xs.append(x[:, 0].numpy() * stats["x_scale"])
    finally:
        shutil.rmtree(tmp)
    f = np.maximum(np.concatenate(fs), 0.0).astype(np.float64)
    q = np.maximum(np.concatenate(qs), 0.0).astype(np.float64)
    x = np.concatenate(xs)
    br = x > 0.01
    d = q - f
    fb, qb = f[br] - f[br].mean(), q[br] - q[br].mean()
    per_slice = [d[k][br[k]].mean() / f[k][br[k]].mean() for k in range(len(f)) if br[k].any()]
    what = "int8 weights only" if a.weights_only else "int8"
    print(f"{man['name']}, {what} - fp32 on {len(f)} {a.split} slices (N8):")
    print(f"  inside the breast: mean {d[br].mean():+.3e} /mm ({d[br].mean() / f[br].mean():+.2%} of fp32's "
          f"{f[br].mean():.5f}), slope of int8 on fp32 {(fb * qb).sum() / (fb * fb).sum():.4f}, "
          f"RMS {np.sqrt((d[br] ** 2).mean()):.3e} /mm")
    print(f"  per slice, mean relative difference inside the breast: mean {np.mean(per_slice):+.2%}, "
          f"sd {np.std(per_slice):.2%}")
    print(f"  outside the breast: mean {d[~br].mean():+.3e} /mm, RMS {np.sqrt((d[~br] ** 2).mean()):.3e} /mm")


if __name__ == "__main__":
    main()
