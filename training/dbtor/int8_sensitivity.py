"""Which blocks lose the most when quantised: each exported block's int8
version swapped in alone, and all int8 but one block, scored on validation
slices (PSNR and SSIM against the truth in 1/cm with the truth's range, the
conventions of dbt-eval).

    python -m dbtor.int8_sensitivity --model ../models/dbtor-x4 --data DS [--slices 16] [--level N8]
    python -m dbtor.int8_sensitivity ... --but primal09 --but primal08,primal09   # chosen mixes only

Runs the exported ONNX blocks with onnxruntime and the dataset's CSR operator
through export.run_onnx_sessions (the unrolled loop of model.py). The raw
network output is scored (no support).
"""
import argparse
import json
import os

import numpy as np
import onnxruntime as ort
from skimage.metrics import structural_similarity

from .data import Split
from .export import run_onnx_sessions
from .folder import check_operator, stats_of
from .operator import Operator
from .train import tensors


def mean_psnr_ssim(images, truths):
    """Mean PSNR (dB) and SSIM of `images` against `truths` (stacks of 2-D
    arrays, 1/cm), each slice with its truth's range: dbt-eval's conventions."""
    ps, ss = [], []
    for z, t in zip(np.asarray(images, np.float64), np.asarray(truths, np.float64)):
        r = t.max() - t.min()
        ps.append(10 * np.log10(r * r / np.mean((z - t) ** 2)))
        ss.append(structural_similarity(t, z, data_range=r))
    return float(np.mean(ps)), float(np.mean(ss))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--level", default="N8")
    ap.add_argument("--slices", type=int, default=16)
    ap.add_argument("--but", action="append", default=[],
                    help="score all int8 but these blocks (comma separated, e.g. primal08,primal09); "
                         "repeatable; skips the block-by-block sweep")
    a = ap.parse_args(argv)
    with open(os.path.join(a.model, "manifest.json")) as f:
        man = json.load(f)
    nrm = man["normalisation"]
    op = Operator(os.path.join(a.data, "operator"))
    check_operator(man, op, a.data, a.model)
    use_mask = man.get("kind", "dbtor") == "dbtor"
    sessions = {p: [ort.InferenceSession(os.path.join(a.model, b[p]), providers=["CPUExecutionProvider"])
                    for b in man["blocks"]] for p in ("fp32", "int8")}
    stats = stats_of(man)
    val = Split(a.data, "validation", a.level)
    idx = np.linspace(0, val.n - 1, min(a.slices, val.n)).astype(int)
    g, m, x = tensors(val.batch(idx), stats)
    truth = x.numpy()[:, 0] * nrm["x_scale_per_mm"] * 10.0  # 1/cm
    n = len(man["blocks"])

    def score(precs):
        z = run_onnx_sessions([sessions[p][k] for k, p in enumerate(precs)], op, g, m, n // 2, use_mask)
        return mean_psnr_ssim(z.numpy()[:, 0] * nrm["x_scale_per_mm"] * 10.0, truth)

    names = [f"{b['role']}{b['index']:02d}" for b in man["blocks"]]
    print(f"{len(idx)} validation slices, {a.level}; PSNR (dB) and SSIM of the network output")
    print(f"{'configuration':<24} {'PSNR':>6} {'SSIM':>6}")
    for label, precs in [("all fp32", ["fp32"] * n), ("all int8", ["int8"] * n)]:
        p, s = score(precs)
        print(f"{label:<24} {p:6.2f} {s:6.3f}", flush=True)
    for keep in a.but:
        kept = [b.strip() for b in keep.split(",") if b.strip()]
        unknown = [b for b in kept if b not in names]
        if unknown:
            raise SystemExit(f"--but {keep}: no block {unknown[0]!r} (blocks: {', '.join(names)})")
        p, s = score(["fp32" if names[j] in kept else "int8" for j in range(n)])
        print(f"{'all int8 but ' + keep:<24} {p:6.2f} {s:6.3f}", flush=True)
    if a.but:
        return
    for k in range(n):
        only = score(["int8" if j == k else "fp32" for j in range(n)])
        but = score(["fp32" if j == k else "int8" for j in range(n)])
        print(f"{'only ' + names[k] + ' int8':<24} {only[0]:6.2f} {only[1]:6.3f}   "
              f"{'all int8 but ' + names[k]:<22} {but[0]:6.2f} {but[1]:6.3f}", flush=True)


if __name__ == "__main__":
    main()
