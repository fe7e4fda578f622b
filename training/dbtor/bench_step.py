"""Time one training step (forward, backward, Adam) of DBToR at each
precision the trainer offers, on random inputs of the dataset's geometry.

    python -m dbtor.bench_step --data DS [--batch 4] [--reps 5]

Prints the median seconds per step of fp32, bf16 (autocast) and bf16 with
--compile, and their ratios to fp32 (train.py's options of the same names).
"""
import argparse
import time

import numpy as np
import torch

from .model import PrimalDual
from .operator import Operator
from .train import compile_convolutions, loss_of


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--reps", type=int, default=5)
    a = ap.parse_args(argv)
    op = Operator(f"{a.data}/operator")
    rows = []
    for name, precision, compile_ in [("fp32", "fp32", False), ("bf16", "bf16", False),
                                      ("bf16 + compile", "bf16", True)]:
        torch.manual_seed(0)
        net = PrimalDual(op)
        if compile_:
            compile_convolutions(net)
        adam = torch.optim.Adam(net.parameters(), lr=1e-4)
        g = torch.randn(a.batch, 1, *op.sino_shape)
        m = (torch.rand(a.batch, 1, *op.image_shape) > 0.5).float()
        x = torch.randn(a.batch, 1, *op.image_shape)

        def step():
            loss = loss_of(net, g, m, x, precision)
            adam.zero_grad(set_to_none=True)
            loss.backward()
            adam.step()

        step()  # warm-up (and compilation)
        ts = []
        for _ in range(a.reps):
            t = time.perf_counter()
            step()
            ts.append(time.perf_counter() - t)
        rows.append((name, float(np.median(ts))))
        print(f"{name:<16} {rows[-1][1]:.3f} s/step", flush=True)
    base = rows[0][1]
    print(f"\n| precision | s/step (median of {a.reps}, batch {a.batch}) | vs fp32 |\n|---|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.3f} | {base / t:.2f}x |")


if __name__ == "__main__":
    main()
