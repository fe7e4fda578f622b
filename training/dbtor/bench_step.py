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

from .model import HIDDEN, STATE, PrimalDual
from .operator import PROFILE_LABEL, Operator
from . import ledger
from .train import compile_convolutions, loss_of, pick_device


# (name, --precision, --compile, --layout channels-last)
VARIANTS = [("fp32", "fp32", False, False), ("bf16", "bf16", False, False),
            ("bf16 + compile", "bf16", True, False), ("bf16 channels-last", "bf16", False, True),
            ("bf16 channels-last + compile", "bf16", True, True)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--only", nargs="+", default=None, metavar="VARIANT",
                    help="time these variants only (names as printed)")
    ap.add_argument("--layers", action="store_true",
                    help="also time each convolution layer's shape alone (bf16, channels-last), forward and backward")
    ap.add_argument("--profile", action="store_true",
                    help="also profile two steps of each variant (torch.profiler) and print each part's share")
    a = ap.parse_args(argv)
    device = pick_device(a.device)
    op = Operator(f"{a.data}/operator").to(device)
    where = (torch.cuda.get_device_name(device) if device.type == "cuda"
             else f"CPU, {torch.get_num_threads()} threads")
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    rows, shares = [], {}
    for name, precision, compile_, cl in VARIANTS:
        if a.only and name not in a.only:
            continue
        torch.manual_seed(0)
        net = PrimalDual(op).to(device)
        if cl:
            net.channels_last()
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
        if a.profile:
            shares[name] = profile_shares(step, sync)
    base_name, base = rows[0]
    print(f"\n{ledger.machine(device)}, {where}; geometry {op.image_shape[1]} x {op.image_shape[0]} pixels, "
          f"{op.sino_shape[0]} views x {op.sino_shape[1]} elements")
    print(f"| precision | s/step (median of {a.reps}, batch {a.batch}) | samples/s | vs {base_name} |\n|---|---|---|---|")
    for name, t in rows:
        print(f"| {name} | {t:.3f} | {a.batch / t:.2f} | {base / t:.2f}x |")
    if shares:
        print("\nShares of the profiled time (torch.profiler's self CPU time of two steps, "
              "by the part of the step each operation belongs to):\n")
        print("| variant | " + " | ".join(PARTS) + " |")
        print("|---" * (len(PARTS) + 1) + "|")
        for name, part in shares.items():
            total = sum(part.values()) or 1.0
            print(f"| {name} | " + " | ".join(f"{100 * part[k] / total:.0f} %" for k in PARTS) + " |")
    if a.layers:
        print(f"\nEach convolution layer alone (bf16 under autocast, channels-last, batch {a.batch}, "
              f"median of {a.reps}):\n")
        print("| layer | on | forward ms | GFLOP/s | backward ms | GFLOP/s |\n|---|---|---|---|---|---|")
        for space, shape, aux in [("image", op.image_shape, 2), ("sinogram", op.sino_shape, 3)]:
            for cin, cout in [(STATE + aux, HIDDEN), (HIDDEN, HIDDEN), (HIDDEN, STATE)]:
                tf, tb, flop = time_layer(cin, cout, shape, a.batch, a.reps, device, sync)
                print(f"| {cin} -> {cout} | {space} {shape[0]} x {shape[1]} | {1e3 * tf:.2f} | "
                      f"{flop / tf / 1e9:.0f} | {1e3 * tb:.2f} | {2 * flop / tb / 1e9:.0f} |")


def time_layer(cin, cout, shape, batch, reps, device, sync):
    """One 3x3 convolution of the network's, forward and backward (input and
    weight gradients), timed alone: (forward s, backward s, forward FLOP)."""
    conv = torch.nn.Conv2d(cin, cout, 3, padding=1).to(device).to(memory_format=torch.channels_last)
    x = (torch.randn(batch, cin, *shape, device=device).to(torch.bfloat16)
         .contiguous(memory_format=torch.channels_last).requires_grad_(True))

    def forward():
        with torch.autocast(device.type, dtype=torch.bfloat16):
            return conv(x)

    forward().float().sum().backward()  # warm-up
    tf, tb = [], []
    for _ in range(reps):
        sync()
        t = time.perf_counter()
        y = forward()
        sync()
        tf.append(time.perf_counter() - t)
        gy = torch.ones_like(y)
        sync()
        t = time.perf_counter()
        y.backward(gy)
        sync()
        tb.append(time.perf_counter() - t)
    return float(np.median(tf)), float(np.median(tb)), 2.0 * cin * cout * 9 * batch * shape[0] * shape[1]


# The parts of a step, in the order an operation is matched against them: by
# its own name or an enclosing one (the projector's record_function label,
# the optimiser's step, autograd's convolution backward).
PARTS = ["sparse projector", "convolutions, backward", "convolutions, forward",
         "compiled elementwise graphs", "optimiser", "copies and casts", "other"]


def part_of(event):
    names = []
    e = event
    while e is not None:
        names.append(e.name)
        e = e.cpu_parent
    def within(*keys):
        return any(k in n for n in names for k in keys)
    if within(PROFILE_LABEL):
        return "sparse projector"
    if within("convolution_backward"):
        return "convolutions, backward"
    if within("mkldnn_convolution", "aten::convolution", "onednn"):
        return "convolutions, forward"
    if within("CompiledFxGraph"):
        return "compiled elementwise graphs"
    if within("Optimizer.step"):
        return "optimiser"
    if event.name in ("aten::copy_", "aten::_to_copy", "aten::to"):
        return "copies and casts"
    return "other"


def profile_shares(step, sync):
    """Self CPU time of two profiled steps, summed by part (PARTS)."""
    from torch.profiler import ProfilerActivity, profile
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(2):
            step()
        sync()
    part = dict.fromkeys(PARTS, 0.0)
    for e in prof.events():
        part[part_of(e)] += e.self_cpu_time_total
    return part


if __name__ == "__main__":
    main()
