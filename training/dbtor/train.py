"""Train DBToR, LPD or the U-Net baseline; resumable.

    python -m dbtor.train --data DS --out RUN [--model dbtor|lpd|unet] [--level N8]
        [--iters 100000] [--batch 4] [--blocks 10] [--max-minutes M] [--seed 0]
        [--precision fp32|bf16] [--compile] [--init RUN|MODEL] [--qat]

RUN/checkpoint.pt holds the model, Adam, the cosine schedule, the iteration
and the RNG states; running the same command again continues from it (the
options must match: they are stored and checked). RUN/curve.csv gets one line
per logged step, RUN/run.json the options and normalisation.

--precision bf16 runs the forward pass under torch.autocast(bfloat16): the
convolutions in bfloat16 (AMX/AVX-512-BF16 on CPUs that have it), weights, Adam,
the loss and the projector (operator.py) in float32; validation and export stay
float32. --compile compiles each block's convolution stack (torch.compile); it
changes speed only, so it is not part of the options a resume checks.

--qat fine-tunes for int8 (quantisation-aware training, qat.py): every block
runs with the rounding of the exported QDQ graph, the activation ranges
re-measured on export.py's calibration slices at the start and at every
validation; validation figures are then those of the simulated int8 network.
Use it with --init from a trained run; export.py --int8-run takes the int8
blocks from such a run.

--device cuda (or auto, the default: cuda where PyTorch sees a GPU, else the
CPU) runs the network, the projector's sparse products and the loss on the
GPU, under torch.autocast(cuda, bfloat16) with --precision bf16. Launched by
torchrun (`torchrun --standalone --nproc_per_node N -m dbtor.train ...`), one
process per GPU (or per CPU share, backend gloo) trains one model with
DistributedDataParallel: --batch is the global batch, split evenly over the
processes, each drawing its share of the same random batch, so the run's
arithmetic, checkpoint and resume do not depend on how many processes ran it
(only rank 0 writes the checkpoint, curve and run.json and validates). A run
may be resumed with another device or process count.

The U-Net (unet.py) learns from the FBP of the sinograms (the dataset's
`fbp-<level>`, made by `host-sim fbp`) instead of the sinograms; its input is
scaled like the target (g_mean = 0, g_std = x_scale), and --blocks is unused.
"""
import argparse
import csv
import json
import math
import os
import signal
import sys
import time

import numpy as np
import torch

from .data import Split, statistics
from . import folder, qat
from .model import PrimalDual
from .operator import Operator
from .unet import UNet

FIXED = ("model", "level", "iters", "batch", "blocks", "seed", "lr", "precision", "qat")


def tensors(batch, stats):
    g, m, x = batch
    g = torch.from_numpy((g - stats["g_mean"]) / stats["g_std"]).float().unsqueeze(1)
    m = torch.from_numpy(m.astype(np.float32)).unsqueeze(1)
    x = torch.from_numpy(x / stats["x_scale"]).float().unsqueeze(1)
    return g, m, x


def compile_convolutions(net):
    """--compile: torch.compile each block's convolution stack (every
    nn.Sequential), in place so that the state_dict keys are unchanged."""
    for m in net.modules():
        if isinstance(m, torch.nn.Sequential):
            m.compile(dynamic=False)


def loss_of(net, g, m, x, precision):
    """The training loss (mean squared error); with precision "bf16" the
    forward pass runs under autocast on the inputs' device (CPU or CUDA) and
    the loss in float32."""
    with torch.autocast(g.device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
        z = net(g, m)
    return torch.mean((z.float() - x) ** 2)


def pick_device(name, local_rank=0):
    """--device: `cpu`, `cuda` (refused, naming why, where PyTorch sees no
    GPU) or `auto` (cuda where there is one)."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        if not torch.cuda.is_available():
            sys.exit("--device cuda: PyTorch sees no CUDA device (torch "
                     f"{torch.__version__}, CUDA build {torch.version.cuda}); use --device cpu")
        return torch.device("cuda", local_rank % torch.cuda.device_count())
    if name != "cpu":
        sys.exit(f"--device {name!r}: cpu, cuda or auto")
    return torch.device("cpu")


def distributed():
    """(rank, world size, local rank) from torchrun's environment; (0, 1, 0)
    without it."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    return int(os.environ.get("RANK", "0")), world, int(os.environ.get("LOCAL_RANK", "0"))


def validate(net, split, stats, n=32, batch=8, device=None):
    """Mean squared error (image units of x_scale) and PSNR (dB, data range of each
    truth) on the first `n` slices of an even spread over the validation split."""
    idx = np.linspace(0, split.n - 1, min(n, split.n)).astype(int)
    mse, psnr = [], []
    net.eval()
    with torch.no_grad():
        for s in range(0, len(idx), batch):
            g, m, x = (t.to(device) if device is not None else t
                       for t in tensors(split.batch(idx[s:s + batch]), stats))
            z = net(g, m)
            e = ((z - x) ** 2).flatten(1).mean(1)
            rng = x.flatten(1).amax(1) - x.flatten(1).amin(1)
            mse += e.tolist()
            psnr += (10 * torch.log10(rng ** 2 / e)).tolist()
    net.train()
    return float(np.mean(mse)), float(np.mean(psnr))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="host-sim dataset folder")
    ap.add_argument("--out", required=True, help="run folder (checkpoint, curve)")
    ap.add_argument("--model", choices=["dbtor", "lpd", "unet"], default="dbtor")
    ap.add_argument("--level", default="N8", help="noise level trained on")
    ap.add_argument("--iters", type=int, default=100000, help="total iterations (cosine schedule length)")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--blocks", type=int, default=10)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-minutes", type=float, default=None, help="stop (with a checkpoint) after this long")
    ap.add_argument("--stop-at", type=int, default=None, help="stop (with a checkpoint) at this iteration")
    ap.add_argument("--log-every", type=int, default=50)
    ap.add_argument("--val-every", type=int, default=500)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--precision", choices=["fp32", "bf16"], default="fp32",
                    help="bf16: convolutions under CPU autocast (weights and optimiser stay float32)")
    ap.add_argument("--compile", action="store_true", help="torch.compile each block's convolutions")
    ap.add_argument("--device", default="auto",
                    help="cpu, cuda or auto (cuda where PyTorch sees a GPU); not part of the run's options")
    ap.add_argument("--init", default=None,
                    help="start a new run from the weights of another run's checkpoint (RUN/checkpoint.pt or RUN) "
                         "or of a firmware model folder (models/NAME: its fp32 blocks, checksums verified): "
                         "fine-tuning, e.g. on another geometry; same model kind and blocks; fresh optimiser, "
                         "schedule and normalisation (this dataset's)")
    ap.add_argument("--qat", action="store_true",
                    help="quantisation-aware fine-tuning for the int8 export (qat.py); with --compile the "
                         "quantised blocks are compiled, with --precision bf16 the convolutions run in "
                         "bfloat16 and the rounding in float32")
    ap.add_argument("--qat-form", choices=list(qat.FORMS), default="conv-inputs",
                    help="the int8 graph simulated (export.py --int8-form)")
    ap.add_argument("--qat-calibration", type=int, default=16,
                    help="training slices the int8 ranges are measured on (export.py --calibration)")
    a = ap.parse_args(argv)
    if a.qat and a.model == "unet":
        sys.exit("--qat: DBToR or LPD only")
    rank, world, local_rank = distributed()
    if world > 1 and a.qat:
        sys.exit("--qat runs in one process (its ranges are measured on the whole network); launch it without torchrun")
    if a.batch % world:
        sys.exit(f"--batch {a.batch} is the global batch: it must split evenly over the {world} processes")
    device = pick_device(a.device, local_rank)
    if world > 1:
        torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")
        if device.type == "cuda":
            torch.cuda.set_device(device)
    lead = rank == 0
    if a.threads:
        torch.set_num_threads(a.threads)
    os.makedirs(a.out, exist_ok=True)
    op = Operator(os.path.join(a.data, "operator")).to(device)
    unet = a.model == "unet"
    source = "fbp" if unet else "sino"
    train = Split(a.data, "train", a.level, input=source)
    val = Split(a.data, "validation", a.level, input=source)
    in_shape = op.image_shape if unet else op.sino_shape
    if tuple(train.images.shape[1:]) != op.image_shape or tuple(train.sinos.shape[1:]) != in_shape:
        sys.exit(f"{a.data}: array shapes {train.images.shape[1:]}/{train.sinos.shape[1:]} do not match the operator")

    ckpt_path = os.path.join(a.out, "checkpoint.pt")
    run_path = os.path.join(a.out, "run.json")
    opts = {k: getattr(a, k) for k in FIXED}
    torch.manual_seed(a.seed)
    net = UNet() if unet else PrimalDual(op, blocks=a.blocks, use_mask=(a.model == "dbtor"))
    net.to(device)
    if a.qat:
        qat.enable(net, compile=a.compile, form=a.qat_form)
    elif a.compile:
        compile_convolutions(net)
    adam = torch.optim.Adam(net.parameters(), lr=a.lr, betas=(0.9, 0.999), eps=1e-8, weight_decay=0)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(adam, T_max=a.iters)
    rng = np.random.default_rng(a.seed)
    it, elapsed = 0, 0.0
    if os.path.exists(ckpt_path):
        ck = torch.load(ckpt_path, weights_only=False, map_location=device)
        # Runs made before --precision and --qat existed were float32 without QAT.
        if {"precision": "fp32", "qat": False, **ck["options"]} != opts:
            sys.exit(f"{ckpt_path}: made with {ck['options']}, asked for {opts}; use another --out")
        net.load_state_dict(ck["model"])
        adam.load_state_dict(ck["adam"])
        sched.load_state_dict(ck["schedule"])
        rng.bit_generator.state = ck["numpy_rng"]
        torch.set_rng_state(ck["torch_rng"].cpu())
        it, elapsed, stats = ck["iteration"], ck["elapsed_s"], ck["stats"]
        if lead:
            print(f"resumed at iteration {it} ({elapsed / 60:.1f} min trained)", flush=True)
    else:
        init = None
        if a.init and folder.is_model_folder(a.init):
            # A firmware model folder (models/NAME): its fp32 blocks' weights.
            try:
                sd, man = folder.load_state_dict(a.init, a.model, a.blocks)
            except folder.FolderError as e:
                sys.exit(f"--init {e}")
            net.load_state_dict(sd)
            prov = man.get("provenance", {})
            init = {"model_folder": os.path.abspath(a.init), "name": man.get("name"),
                    "iteration": prov.get("iterations"), "options": prov.get("options"),
                    "manifest_sha256": folder.manifest_sha256(a.init)}
            print(f"initialised from model folder {a.init} ({man.get('name')}, "
                  f"iteration {prov.get('iterations')})", flush=True)
        elif a.init:
            src = os.path.join(a.init, "checkpoint.pt") if os.path.isdir(a.init) else a.init
            if not os.path.exists(src):
                sys.exit(f"--init {a.init}: no checkpoint at {src} (and no manifest.json: not a model folder)")
            ick = torch.load(src, weights_only=False, map_location=device)
            if ick.get("model_kind") != a.model or ick.get("blocks") != a.blocks:
                sys.exit(f"--init {src}: a {ick.get('model_kind')} of {ick.get('blocks')} blocks, "
                         f"not a {a.model} of {a.blocks}")
            net.load_state_dict(ick["model"])
            init = {"checkpoint": os.path.abspath(src), "iteration": ick["iteration"],
                    "options": ick["options"]}
            print(f"initialised from {src} (iteration {ick['iteration']})", flush=True)
        stats = statistics(train)
        if unet:
            # The FBP input in the target's unit (x_scale), not standardised.
            stats.update(g_mean=0.0, g_std=stats["x_scale"])
        if lead:
            with open(run_path, "w") as f:
                json.dump({"options": opts, "data": os.path.abspath(a.data),
                           "dataset_provenance": train.manifest["provenance"],
                           "geometry": train.manifest["geometry"], "stats": stats,
                           "operator_norm": op.norm, "init": init,
                           "qat_form": a.qat_form if a.qat else None,
                           "command": " ".join(["python -m dbtor.train"] + (argv or sys.argv[1:]))}, f, indent=2)

    # Every process starts from rank 0's weights (a fresh run's random
    # initialisation is the same on every rank: the same seed).
    model = net
    if world > 1:
        model = torch.nn.parallel.DistributedDataParallel(
            net, device_ids=[device.index] if device.type == "cuda" else None)
    share = a.batch // world

    def save():
        if not lead:
            return
        tmp = ckpt_path + ".tmp"
        torch.save({"options": opts, "model": net.state_dict(), "adam": adam.state_dict(),
                    "schedule": sched.state_dict(), "numpy_rng": rng.bit_generator.state,
                    "torch_rng": torch.get_rng_state(), "iteration": it, "elapsed_s": elapsed,
                    "stats": stats, "blocks": a.blocks, "model_kind": a.model}, tmp)
        os.replace(tmp, ckpt_path)

    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    signal.signal(signal.SIGINT, lambda *_: stop.update(now=True))
    curve = open(os.path.join(a.out, "curve.csv"), "a", newline="") if lead else None
    cw = csv.writer(curve) if lead else None
    if lead and curve.tell() == 0:
        cw.writerow(["iteration", "elapsed_s", "lr", "train_loss", "val_mse", "val_psnr_db"])
    def calibrate_int8():
        qat.calibrate(net, qat.calibration_batches(train, stats, a.qat_calibration))

    if a.qat:
        calibrate_int8()
    t0, run_loss, run_n = time.time(), 0.0, 0
    start_elapsed = elapsed
    end = a.iters if a.stop_at is None else min(a.iters, a.stop_at)
    while it < end:
        # Every rank draws the same global batch and takes its share: the
        # run does not depend on the number of processes.
        idx = rng.choice(train.n, size=a.batch, replace=False)[rank * share:(rank + 1) * share]
        g, m, x = (t.to(device, non_blocking=True) for t in tensors(train.batch(idx), stats))
        loss = loss_of(model, g, m, x, a.precision)
        adam.zero_grad(set_to_none=True)
        loss.backward()  # DistributedDataParallel averages the gradients over the ranks
        adam.step()
        sched.step()
        it += 1
        elapsed = start_elapsed + time.time() - t0
        if world > 1:
            loss = loss.detach().clone()
            torch.distributed.all_reduce(loss)
            loss /= world
        run_loss += loss.item()
        run_n += 1
        val_mse = val_psnr = ""
        if it % a.val_every == 0 or it == end:
            if a.qat:
                calibrate_int8()
            if lead:
                val_mse, val_psnr = validate(net, val, stats, device=device)
            if world > 1:
                torch.distributed.barrier()
        if lead and (it % a.log_every == 0 or val_mse != ""):
            cw.writerow([it, f"{elapsed:.1f}", f"{sched.get_last_lr()[0]:.3e}", f"{run_loss / run_n:.6f}",
                         val_mse, val_psnr])
            curve.flush()
            print(f"it {it} loss {run_loss / run_n:.5f} val_mse {val_mse} val_psnr {val_psnr} "
                  f"({elapsed / it if it else 0:.2f} s/it)", flush=True)
            run_loss, run_n = 0.0, 0
        if it % a.val_every == 0:
            save()
        halt = stop["now"] or (a.max_minutes is not None and time.time() - t0 > 60 * a.max_minutes)
        if world > 1:
            # every rank stops at the same iteration: rank 0's signal and clock decide
            flag = torch.tensor([float(halt)], device=device)
            torch.distributed.broadcast(flag, 0)
            halt = bool(flag.item())
        if halt:
            break
    save()
    if lead:
        print(f"stopped at iteration {it} of {a.iters}; checkpoint {ckpt_path} "
              f"({world} process{'es' if world > 1 else ''} on {device.type})", flush=True)
    if world > 1:
        torch.distributed.destroy_process_group()


if __name__ == "__main__":
    main()
