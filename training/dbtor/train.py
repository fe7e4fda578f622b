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

--data takes one dataset or several of the same geometry (e.g. the mono and
the clinical-corrected acquisitions of a population): batches are drawn
uniformly from the union of their slices, so each is sampled in proportion
to its size; the normalisation and validation are over the union.

--state FILE keeps the run's whole state compactly where other machines find
it (dbtor/state.py; issue #49): written beside checkpoint.pt at every save and
every --save-every-minutes, restored from when it exists (the local exact
checkpoint.pt instead when it is the same save), with each dataset's SHA-256
checked against the state's (a different dataset is refused, naming its
files). --ledger FILE appends one line for this segment of the run
(ledger.py). `python -m dbtor.continue_run` drives both.
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
from . import folder, ledger, qat
from . import state as compact
from .model import PrimalDual
from .operator import Operator
from .unet import UNet

FIXED = ("model", "level", "iters", "batch", "blocks", "seed", "lr", "precision", "qat",
         "edge_weight", "edge_px")
# What a checkpoint made before an option existed was trained with.
OPTION_DEFAULTS = {"precision": "fp32", "qat": False, "edge_weight": 1.0, "edge_px": 0}


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


def edge_band(m, px):
    """The pixels of the mask `m` ([B,1,H,W], 0/1) within `px` pixels of its
    edge (the breast's surface: skin under both paddles and at the
    outline): the mask less its erosion by a (2 px + 1)-square."""
    outside = 1.0 - m
    near_outside = torch.nn.functional.max_pool2d(outside, 2 * px + 1, stride=1, padding=px)
    return m * near_outside


def loss_of(net, g, m, x, precision, edge_weight=1.0, edge_px=0):
    """The training loss: the mean squared error, or with `edge_weight` > 1
    and `edge_px` > 0 its weighted mean, the pixels of the breast within
    `edge_px` of its surface weighted `edge_weight` (--edge-weight,
    --edge-px: the skin and the tissue under it, where the dose is
    deposited first, issue #49). With precision "bf16" the forward pass
    runs under autocast on the inputs' device (CPU or CUDA) and the loss in
    float32."""
    with torch.autocast(g.device.type, dtype=torch.bfloat16, enabled=precision == "bf16"):
        z = net(g, m)
    e = (z.float() - x) ** 2
    if edge_weight == 1.0 or edge_px <= 0:
        return torch.mean(e)
    w = 1.0 + (edge_weight - 1.0) * edge_band(m, edge_px)
    return torch.sum(w * e) / torch.sum(w)


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


class Union:
    """Several splits of the same shapes as one: index i runs over the first
    split's slices, then the second's, ..."""

    def __init__(self, splits):
        self.parts = splits
        self.starts = np.cumsum([0] + [p.n for p in splits])
        self.n = int(self.starts[-1])
        self.images, self.sinos = splits[0].images, splits[0].sinos
        self.manifest = splits[0].manifest

    def batch(self, idx):
        if len(self.parts) == 1:
            return self.parts[0].batch(idx)
        idx = np.sort(np.asarray(idx))
        out = []
        for k, p in enumerate(self.parts):
            sel = idx[(idx >= self.starts[k]) & (idx < self.starts[k + 1])] - self.starts[k]
            if len(sel):
                out.append(p.batch(sel))
        return tuple(np.concatenate([o[j] for o in out]) for j in range(3))


def same_operator(d1, d2):
    """Whether two datasets hold the same projector (operator.json and the
    CSR files byte for byte)."""
    o1, o2 = (os.path.join(d, "operator") for d in (d1, d2))
    for f in sorted(os.listdir(o1)):
        p2 = os.path.join(o2, f)
        if not os.path.exists(p2) or os.path.getsize(p2) != os.path.getsize(os.path.join(o1, f)):
            return False
        with open(os.path.join(o1, f), "rb") as x, open(p2, "rb") as y:
            while True:
                bx, by = x.read(1 << 22), y.read(1 << 22)
                if bx != by:
                    return False
                if not bx:
                    break
    return True


def truncate_curve(text, iteration):
    """curve.csv's header and the rows up to `iteration` (a run resumed from
    a save drops the rows logged after it)."""
    lines = text.splitlines(keepends=True)
    keep = lines[:1]
    for ln in lines[1:]:
        try:
            if int(ln.split(",", 1)[0]) <= iteration:
                keep.append(ln)
        except ValueError:
            pass
    return "".join(keep)


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
    ap.add_argument("--data", required=True, nargs="+",
                    help="host-sim dataset folder(s) of one geometry; several are sampled in proportion to their size")
    ap.add_argument("--out", required=True, help="run folder (checkpoint, curve)")
    ap.add_argument("--model", choices=["dbtor", "lpd", "unet"], default="dbtor")
    ap.add_argument("--level", default="N8", help="noise level trained on")
    ap.add_argument("--iters", type=int, default=100000, help="total iterations (cosine schedule length)")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--blocks", type=int, default=10)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--edge-weight", type=float, default=1.0,
                    help="weight of the loss on the breast's pixels within --edge-px of its surface (1: plain MSE)")
    ap.add_argument("--edge-px", type=int, default=0, help="width of that band, pixels")
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
    ap.add_argument("--state", default=None,
                    help="the run's compact state file (dbtor/state.py): restored from where it exists, "
                         "written at every save")
    ap.add_argument("--run-name", default=None, help="the run's name (recorded in the state and ledger)")
    ap.add_argument("--recipe", default=None,
                    help="JSON file of the datasets' recipes (continue_run.py), recorded in the state")
    ap.add_argument("--save-every-minutes", type=float, default=None,
                    help="also save (checkpoint and state) whenever this long has passed since the last save")
    ap.add_argument("--deadline", type=float, default=None,
                    help="stop (with a checkpoint and validation) in time to be done by this Unix time")
    ap.add_argument("--ledger", default=None, help="append this segment's line to this ledger (ledger.py)")
    ap.add_argument("--ledger-note", default="", help="a note for the ledger line (e.g. 'nice 19, beside builds')")
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
    op = Operator(os.path.join(a.data[0], "operator")).to(device)
    unet = a.model == "unet"
    source = "fbp" if unet else "sino"
    in_shape = op.image_shape if unet else op.sino_shape
    trains, vals = [], []
    for d in a.data:
        tr = Split(d, "train", a.level, input=source)
        if tuple(tr.images.shape[1:]) != op.image_shape or tuple(tr.sinos.shape[1:]) != in_shape:
            sys.exit(f"{d}: array shapes {tr.images.shape[1:]}/{tr.sinos.shape[1:]} do not match the operator")
        if d != a.data[0] and not same_operator(a.data[0], d):
            sys.exit(f"{d}: its operator (geometry) is not {a.data[0]}'s; datasets trained together share one")
        trains.append(tr)
        vals.append(Split(d, "validation", a.level, input=source))
    train, val = Union(trains), Union(vals)

    ckpt_path = os.path.join(a.out, "checkpoint.pt")
    run_path = os.path.join(a.out, "run.json")
    curve_path = os.path.join(a.out, "curve.csv")
    opts = {k: getattr(a, k) for k in FIXED}
    recipe = None
    if a.recipe:
        with open(a.recipe) as f:
            recipe = json.load(f)
    # a run's recipe.json (continue_run.py) or a list, one entry per --data
    recipe_ds = recipe.get("datasets") if isinstance(recipe, dict) else recipe
    fingerprints = None
    if a.state and lead:
        # every file of every dataset, to be recorded or checked (a few seconds per GB)
        t = time.time()
        fingerprints = [compact.fingerprint(d) for d in a.data]
        print(f"dataset SHA-256 of {sum(map(len, fingerprints))} files in {time.time() - t:.1f} s", flush=True)
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
    ck, state_header = None, None
    if a.state and os.path.exists(a.state):
        state_header = compact.read_header(a.state)
        if a.run_name and state_header.get("run") != a.run_name:
            sys.exit(f"{a.state}: the state of run {state_header.get('run')!r}, not {a.run_name!r}")
        if lead:
            have = fingerprints
            want = state_header["datasets"]
            if len(want) != len(have):
                sys.exit(f"{a.state}: trained on {len(want)} dataset(s), given {len(have)} (--data)")
            for d, w, h in zip(a.data, want, have):
                try:
                    compact.compare_fingerprints(w["files"], h, d)
                except compact.StateError as e:
                    sys.exit(f"{e}; its recipe: {w.get('recipe')}")
        local = (torch.load(ckpt_path, weights_only=False, map_location=device)
                 if os.path.exists(ckpt_path) else None)
        if local is not None and local.get("save_id") == state_header.get("save_id"):
            ck = local
            if lead:
                print(f"the local checkpoint is the state's save ({state_header['save_id']}): resuming exactly", flush=True)
                if os.path.exists(curve_path):
                    with open(curve_path) as f:
                        text = f.read()
                    with open(curve_path, "w") as f:
                        f.write(truncate_curve(text, ck["iteration"]))
        else:
            try:
                ck, _ = compact.unpack(a.state, device=device)
            except compact.StateError as e:
                sys.exit(str(e))
            if lead:
                print(f"restored the compact state {a.state} (iteration {ck['iteration']})", flush=True)
                with open(run_path, "w") as f:
                    json.dump(state_header["run_json"], f, indent=2)
                repo_curve = os.path.join(os.path.dirname(os.path.abspath(a.state)), "curve.csv")
                if os.path.exists(repo_curve):
                    with open(repo_curve) as f:
                        text = f.read()
                    with open(curve_path, "w") as f:
                        f.write(truncate_curve(text, ck["iteration"]))
    elif os.path.exists(ckpt_path):
        ck = torch.load(ckpt_path, weights_only=False, map_location=device)
    if ck is not None:
        # Runs made before an option existed were trained as OPTION_DEFAULTS says.
        if {**OPTION_DEFAULTS, **ck["options"]} != opts:
            src = a.state if state_header is not None else ckpt_path
            sys.exit(f"{src}: made with {ck['options']}, asked for {opts}; use another --out")
        net.load_state_dict(ck["model"])
        adam.load_state_dict(ck["adam"])
        sched.load_state_dict(ck["schedule"])
        rng.bit_generator.state = ck["numpy_rng"]
        torch.set_rng_state(ck["torch_rng"].cpu())
        if device.type == "cuda" and len(ck.get("cuda_rng", [])) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all([s.cpu() for s in ck["cuda_rng"]])
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
        if lead and a.state:
            with open(curve_path, "w") as f:
                pass  # a fresh run's curve
        if unet:
            # The FBP input in the target's unit (x_scale), not standardised.
            stats.update(g_mean=0.0, g_std=stats["x_scale"])
        if lead:
            with open(run_path, "w") as f:
                json.dump({"options": opts,
                           "data": (os.path.abspath(a.data[0]) if len(a.data) == 1
                                    else [os.path.abspath(d) for d in a.data]),
                           "dataset_provenance": train.manifest["provenance"],
                           **({"datasets_provenance": [t.manifest["provenance"] for t in trains]}
                              if len(a.data) > 1 else {}),
                           "geometry": train.manifest["geometry"], "stats": stats,
                           "operator_norm": op.norm, "init": init,
                           "qat_form": a.qat_form if a.qat else None, "recipe": recipe,
                           "command": " ".join(["python -m dbtor.train"] + (argv or sys.argv[1:]))}, f, indent=2)

    # Every process starts from rank 0's weights (a fresh run's random
    # initialisation is the same on every rank: the same seed).
    model = net
    if world > 1:
        model = torch.nn.parallel.DistributedDataParallel(
            net, device_ids=[device.index] if device.type == "cuda" else None)
    share = a.batch // world

    if lead and a.state:
        with open(run_path) as f:
            run_json = json.load(f)
        datasets = state_header["datasets"] if state_header is not None else [
            {"recipe": recipe_ds[i] if recipe_ds and i < len(recipe_ds) else None,
             "digest": compact.fingerprint_digest(fp), "files": fp}
            for i, fp in enumerate(fingerprints)]
    saves = {"last": time.time(), "n": 0, "it": None}

    def save():
        saves["last"] = time.time()
        if not lead or saves["it"] == it:
            return
        saves["it"] = it
        ck = {"options": opts, "model": net.state_dict(), "adam": adam.state_dict(),
              "schedule": sched.state_dict(), "numpy_rng": rng.bit_generator.state,
              "torch_rng": torch.get_rng_state(), "iteration": it, "elapsed_s": elapsed,
              "stats": stats, "blocks": a.blocks, "model_kind": a.model,
              "save_id": f"{a.run_name or 'run'}@{it}/{os.urandom(6).hex()}"}
        if device.type == "cuda":
            ck["cuda_rng"] = torch.cuda.get_rng_state_all()
        tmp = ckpt_path + ".tmp"
        torch.save(ck, tmp)
        os.replace(tmp, ckpt_path)
        if a.state:
            curve.flush()
            n = compact.save(a.state, ck, {"run": a.run_name, "save_id": ck["save_id"],
                                           "samples_seen": it * a.batch, "datasets": datasets,
                                           "run_json": run_json})
            with open(curve_path) as f:
                compact.write_atomic(os.path.join(os.path.dirname(os.path.abspath(a.state)), "curve.csv"),
                                     f.read().encode())
            saves["n"] += 1
            print(f"saved the state at iteration {it}: {a.state} ({n:,} bytes)", flush=True)

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
    start_elapsed, start_it = elapsed, it
    last_val = {"it": None, "mse": None, "psnr": None, "s": 60.0}
    step_s = 0.0

    def validation():
        t = time.time()
        mse, psnr = validate(net, val, stats, device=device)
        last_val.update(it=it, mse=mse, psnr=psnr, s=time.time() - t)
        return mse, psnr

    end = a.iters if a.stop_at is None else min(a.iters, a.stop_at)
    while it < end:
        ts = time.time()
        # Every rank draws the same global batch and takes its share: the
        # run does not depend on the number of processes.
        idx = rng.choice(train.n, size=a.batch, replace=False)[rank * share:(rank + 1) * share]
        g, m, x = (t.to(device, non_blocking=True) for t in tensors(train.batch(idx), stats))
        loss = loss_of(model, g, m, x, a.precision, a.edge_weight, a.edge_px)
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
                val_mse, val_psnr = validation()
            if world > 1:
                torch.distributed.barrier()
        if lead and (it % a.log_every == 0 or val_mse != ""):
            cw.writerow([it, f"{elapsed:.1f}", f"{sched.get_last_lr()[0]:.3e}", f"{run_loss / run_n:.6f}",
                         val_mse, val_psnr])
            curve.flush()
            print(f"it {it} loss {run_loss / run_n:.5f} val_mse {val_mse} val_psnr {val_psnr} "
                  f"({elapsed / it if it else 0:.2f} s/it)", flush=True)
            run_loss, run_n = 0.0, 0
        if it % a.val_every == 0 or (a.save_every_minutes is not None
                                     and time.time() - saves["last"] > 60 * a.save_every_minutes):
            save()
        step_s = time.time() - ts if step_s == 0.0 else 0.9 * step_s + 0.1 * (time.time() - ts)
        halt = stop["now"] or (a.max_minutes is not None and time.time() - t0 > 60 * a.max_minutes)
        # --deadline: one more step, a validation and a save must still fit
        if a.deadline is not None and time.time() + step_s + 1.5 * last_val["s"] + 20 > a.deadline:
            halt = True
        if world > 1:
            # every rank stops at the same iteration: rank 0's signal and clock decide
            flag = torch.tensor([float(halt)], device=device)
            torch.distributed.broadcast(flag, 0)
            halt = bool(flag.item())
        if halt:
            break
    if lead and (a.ledger or a.state) and it > start_it and last_val["it"] != it:
        # the segment ends with its validation figures (for the ledger and the curve)
        val_mse, val_psnr = validation()
        cw.writerow([it, f"{elapsed:.1f}", f"{sched.get_last_lr()[0]:.3e}",
                     f"{run_loss / run_n:.6f}" if run_n else "", val_mse, val_psnr])
        curve.flush()
        print(f"it {it} val_mse {val_mse} val_psnr {val_psnr} (end of segment)", flush=True)
    save()
    train_s = time.time() - t0
    if lead:
        print(f"stopped at iteration {it} of {a.iters}; checkpoint {ckpt_path} "
              f"({world} process{'es' if world > 1 else ''} on {device.type})", flush=True)
        if a.ledger and it > start_it:
            row = ledger.append(a.ledger, run=a.run_name or os.path.basename(os.path.abspath(a.out)),
                                model=a.model, blocks=a.blocks, device=device, world=world,
                                precision=a.precision + (" + compile" if a.compile else ""),
                                batch=a.batch, it_start=start_it, it_end=it, wall_s=train_s,
                                val_mse=last_val["mse"], val_psnr=last_val["psnr"], note=a.ledger_note)
            print(f"ledger {a.ledger}: {row}", flush=True)
    if world > 1:
        torch.distributed.destroy_process_group()


if __name__ == "__main__":
    main()
