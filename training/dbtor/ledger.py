"""The training ledger (issue #49 point 2): one Markdown table, one row per
segment of a run (a trainer process from its start or resume to its stop),
appended by train.py --ledger (continue_run.py passes training/LEDGER.md).
The figures are the trainer's own; rows are never edited by hand.

Columns: run, model, date (UTC, the segment's end), machine (CPU model, CPUs
and the flags that matter for training: avx512f, avx512_bf16, amx_bf16; or
the GPU), device and processes, torch threads, precision, samples seen at
the start and the end (iterations x batch), iterations, wall time of the
segment's training (validations and saves included), samples/s over it,
validation MSE and PSNR (the trainer's 32 validation slices) at the end, the
repository commit the trainer started from, a note.
"""
import datetime
import os
import subprocess

import torch

HEADER = """# Training ledger

One row per segment of a training run, appended by the trainer
(`python -m dbtor.train --ledger`, which `scripts/train-continue.sh` passes);
never edited by hand. Samples = iterations x batch. Wall time: the segment's
training loop, its validations and saves included. Validation: the trainer's
32 validation slices (MSE in units of the run's x_scale, PSNR in dB) at the
segment's last iteration. Format and state: training/README.md, "Runs kept in
the repository".

| run | model | date (UTC) | machine | device | threads | precision | samples start | samples end | iterations | wall s | samples/s | val MSE | val PSNR dB | commit | note |
|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|
"""

FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_fp16", "amx_bf16", "amx_tile")


def cpu_description():
    model, flags = "unknown CPU", set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                k, _, v = line.partition(":")
                k = k.strip()
                if k == "model name" and model == "unknown CPU":
                    model = v.strip()
                elif k == "flags" and not flags:
                    flags = set(v.split())
    except OSError:
        pass
    have = [f for f in FLAGS if f in flags]
    return f"{model}, {os.cpu_count()} CPUs" + (f", {' '.join(have)}" if have else "")


def machine(device):
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} (host: {cpu_description()})"
    return cpu_description()


def commit():
    try:
        here = os.path.dirname(os.path.abspath(__file__))
        return subprocess.run(["git", "-C", here, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10).stdout.strip() or "-"
    except (OSError, subprocess.SubprocessError):
        return "-"


# the commit the trainer started from (read when train.py imports this module)
STARTED_AT = commit()


def append(path, *, run, model, blocks, device, world, precision, batch, it_start, it_end, wall_s,
           val_mse, val_psnr, note=""):
    """Append one row (the file and its header made if missing); returns the row."""
    samples = (it_end - it_start) * batch
    cells = [
        run,
        f"{model} ({blocks} + {blocks} blocks)" if model != "unet" else model,
        datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M"),
        machine(device),
        device.type + (f" x {world}" if world > 1 else ""),
        str(torch.get_num_threads()),
        precision,
        f"{it_start * batch:,}",
        f"{it_end * batch:,}",
        f"{it_start:,} -> {it_end:,}",
        f"{wall_s:,.0f}",
        f"{samples / wall_s:.3f}" if wall_s > 0 else "-",
        f"{val_mse:.6f}" if val_mse is not None else "-",
        f"{val_psnr:.3f}" if val_psnr is not None else "-",
        STARTED_AT,
        note.replace("|", "/") or "-",
    ]
    row = "| " + " | ".join(c.replace("|", "/") for c in cells) + " |\n"
    new = not os.path.exists(path) or os.path.getsize(path) == 0
    with open(path, "a") as f:
        if new:
            f.write(HEADER)
        f.write(row)
    return row.strip()
