"""Time one training step (forward, backward, Adam) of DBToR at each
precision the trainer offers, on random inputs of the dataset's geometry:
the training-throughput benchmark (issue #29 point 1).

    python -m dbtor.bench_step --data DS [--batch 4] [--reps 5] [--device auto|cpu|cuda]

Prints the median seconds per step of fp32, bf16 (autocast) and bf16 with
--compile, the training samples per second, and their ratios to fp32
(train.py's options of the same names), on the device train.py would use
(`--device`: the CPU, or the GPU where PyTorch sees one), with the device's
name and the CPU's thread count beside them.
"""
import argparse
import time

import numpy as np
import torch

from .model import PrimalDual
from .operator import Operator
from .train import compile_convolutions, loss_of, pick_device


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--device", default="auto")
    a = ap.parse_args(argv)
    device = pick_device(a.device)
    op = Operator(f"{a.data}/operator").to(device)
    where = (torch.cuda.get_device_name(device) if device.type == "cuda"
             else f"CPU, {torch.get_num_threads()} threads")
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    rows = []
    for name, precision, compile_ in [("fp32", "fp32", False), ("bf16", "bf16", False),
                                      ("bf16 + compile", "bf16", True)]:
        torch.manual_seed(0)
        net = PrimalDual(op).to(device)
        if compile_:
            compile_convolutions(net)
        adam = torch.optim.Adam(net.parameters(), lr=1e-4)
        g = torch.randn(a.batch, 1, *op.sino_shape).to(device)
        m = (torch.rand(a.batch, 1, *op.image_shape) > 0.5).float().to(device)
        x = torch.randn(a.batch, 1, *op.image_shape).to(device)

        def step():
            loss = loss_of(net, g, m, x, precision)
            adam.zero_grad(set_to_none=True)
            loss.backward()
            adam.step()

        step()  # warm-up (and compilation)
        sync()
        ts = []
        for _ in range(a.reps):
            t = time.perf_counter()
            step()
            sync()
            ts.append(time.perf_counter() - t)
        rows.append((name, float(np.median(ts))))
        print(f"{name:<16} {rows[-1][1]:.3f} s/step", flush=True)
    base = rows[0][1]
    print(f"\n{where}; geometry {op.image_shape[1]} x {op.image_shape[0]} pixels, "
          f"{op.sino_shape[0]} views x {op.sino_shape[1]} elements")
    print(f"| precision | s/step (median of {a.reps}, batch {a.batch}) | samples/s | vs fp32 |\n|---|---|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.3f} | {a.batch / t:.2f} | {base / t:.2f}x |")


if __name__ == "__main__":
    main()
