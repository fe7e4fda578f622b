"""What the compact state costs a resumed run (issue #49 point 2): from one
save of a run, continue N iterations three ways on the same batches and
compare the training losses and the final validation:

- exact: the local checkpoint.pt (float32 weights and Adam's moments as trained);
- compact: the state file of the same save (state.py: exact weights,
  bfloat16 moments), restored by the trainer;
- compact log8: the same with the 8-bit log code for the moments;
- bf16 weights: the exact checkpoint with its weights rounded to bfloat16
  (what keeping only bf16 weights in the state would cost).

    python -m dbtor.resume_check [--run NAME] [--iters 10] [--threads 1] [--cache DIR]

The run's datasets must be in the cache (continue_run.py puts them there) and
the local checkpoint must be the state's save (the same save_id). Runs
without --compile (speed only; the three variants alike). Nothing of the run
is changed: the variants run in a temporary folder.
"""
import argparse
import csv
import os
import shlex
import shutil
import sys
import tempfile

import torch

from . import continue_run as cr
from . import state as compact
from . import train as trainer


VARIANTS = ("exact", "compact", "compact log8", "bf16 weights")


def losses(run_dir):
    with open(os.path.join(run_dir, "curve.csv")) as f:
        rows = list(csv.DictReader(f))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", default=None)
    ap.add_argument("--runs", default=cr.RUNS)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    name, rdir, recipe = cr.load_run(a.runs, a.run)
    cache = cr.cache_dir(a)
    data = [os.path.join(cache, "datasets", cr.dataset_key(name, k, e)) for k, e in enumerate(recipe["datasets"])]
    local = os.path.join(cache, "runs", name)
    tmp = tempfile.mkdtemp(prefix="resume-check-")
    # copies first: a trainer still running may save again meanwhile
    saved = os.path.join(tmp, "saved")
    os.makedirs(os.path.join(saved, "state"))
    for f in ("checkpoint.pt", "run.json"):
        shutil.copy(os.path.join(local, f), saved)
    state = os.path.join(saved, "state", "state.dbts")
    shutil.copy(os.path.join(rdir, "state.dbts"), state)
    header = compact.read_header(state)
    ck = torch.load(os.path.join(saved, "checkpoint.pt"), weights_only=False)
    if ck.get("save_id") != header.get("save_id"):
        shutil.rmtree(tmp, ignore_errors=True)
        sys.exit(f"{local}/checkpoint.pt is save {ck.get('save_id')}, the state {header.get('save_id')}: "
                 "not the same save")
    it0 = ck["iteration"]
    train = [x for x in shlex.split(recipe["train"]) if x != "--compile"]
    base = ["--data", *data, *train, "--stop-at", str(it0 + a.iters), "--log-every", "1",
            "--threads", str(a.threads), "--device", "cpu"]
    results = {}
    try:
        for variant in VARIANTS:
            out = os.path.join(tmp, variant.replace(" ", "-"))
            os.makedirs(out)
            shutil.copy(os.path.join(saved, "run.json"), out)
            extra = []
            if variant == "exact":
                shutil.copy(os.path.join(saved, "checkpoint.pt"), out)
            elif variant.startswith("compact"):
                # the state file of this save, written with the moments' code named
                sfile = os.path.join(out + "-state", "state.dbts")
                hx = {k: header[k] for k in ("run", "save_id", "samples_seen", "datasets", "run_json")}
                compact.save(sfile, ck, hx, moments="log8" if "log8" in variant else "bf16")
                print(f"{variant}: {os.path.getsize(sfile):,} bytes", flush=True)
                extra = ["--state", sfile, "--run-name", name]
            else:
                c = dict(ck)
                c["model"] = {k: v.to(torch.bfloat16).float() for k, v in ck["model"].items()}
                torch.save(c, os.path.join(out, "checkpoint.pt"))
            print(f"--- {variant}", flush=True)
            trainer.main(["--out", out, *base, *extra])
            results[variant] = [r for r in losses(out) if int(r["iteration"]) > it0]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ex = results["exact"]
    print(f"\n{name}, from iteration {it0} ({header['save_id']}), {a.iters} iterations, "
          f"{a.threads} thread(s), no compile\n")
    print("| iteration | " + " | ".join(f"{v} loss" for v in VARIANTS) + " |\n" + "|---" * (len(VARIANTS) + 1) + "|")
    for i, r in enumerate(ex):
        print(f"| {r['iteration']} | " + " | ".join(results[v][i]["train_loss"] for v in VARIANTS) + " |")
    for v in VARIANTS[1:]:
        d = [abs(float(x["train_loss"]) - float(e["train_loss"])) / float(e["train_loss"])
             for x, e in zip(results[v], ex)]
        last, lex = results[v][-1], ex[-1]
        print(f"{v}: training loss within {max(d):.2e} (relative) of the exact resume's, mean {sum(d) / len(d):.2e}; "
              f"validation at {last['iteration']}: MSE {float(last['val_mse']):.6f} vs {float(lex['val_mse']):.6f}, "
              f"PSNR {float(last['val_psnr_db']):.4f} vs {float(lex['val_psnr_db']):.4f} dB")


if __name__ == "__main__":
    main()
