"""Continue the current training run from its state in the repository (issue
#49 point 2): one command for whoever has free cores or a GPU.

    ./scripts/train-continue.sh [--minutes M | --until HH:MM] [--threads T] [--device auto]
    python -m dbtor.continue_run  (the same, from training/)
    python -m dbtor.continue_run new NAME (--dataset 'ARGS' [--dataset 'ARGS'] | --datasets-of RUN)
        --train 'ARGS' [--init-git COMMIT:PATH | --init-run COMMIT:RUN | --init PATH] [--current]

A run lives in `training/runs/NAME/`: `recipe.json` (written once by `new`:
the datasets' exact `host-sim dataset` arguments and the commit whose
generator made them, the trainer's options, where its weights started),
`state.dbts` (the whole state, dbtor/state.py, replaced at every save) and
`curve.csv`. `training/runs/CURRENT` names the run this command continues.

What it does:
1. each dataset of the recipe is looked up in the cache (`--cache`, default
   $DBTOR_CACHE or ~/.cache/dbtor); a missing one is generated there into a
   temporary folder renamed when complete, with RAYON_NUM_THREADS = --threads,
   by `--host-sim BINARY` or a host-sim that cargo builds from the recipe's
   generator commit: in this checkout where its host-sim, crates and Cargo.*
   are that commit's, else from that commit's tree (git archive) under
   CACHE/generator/ (a changed generator would make other phantoms, which
   the state's SHA-256 would refuse);
2. the trainer (train.py) restores the state (or, for the first segment, starts
   from the recipe's --init: a model folder, read from git history with
   --init-git, or another run's state as committed, --init-run), refuses a dataset whose files' SHA-256 differ from the state's
   (naming them), trains until the time limit or SIGTERM/SIGINT, saving the state every
   --save-every-minutes (default 10) and at the end, and appends its line to
   the ledger (training/LEDGER.md unless --ledger).

The local run folder (`CACHE/runs/NAME`: checkpoint.pt, run.json, curve.csv)
is a complete run folder for export.py.
"""
import argparse
import datetime
import hashlib
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
TRAINING = os.path.dirname(HERE)
REPO = os.path.dirname(TRAINING)
RUNS = os.path.join(TRAINING, "runs")
LEDGER = os.path.join(TRAINING, "LEDGER.md")


def git(*args, check=True):
    r = subprocess.run(["git", "-C", REPO, *args], capture_output=True, text=True)
    if check and r.returncode:
        sys.exit(f"git {' '.join(args)}: {r.stderr.strip()}")
    return r.stdout.strip()


def committed_state(src):
    """The bytes of the run state a recipe's init names (`git` commit,
    `run_state` path): from git history, or, where there is none (a GPU
    slot's bare copy of the working tree), the working tree's file when its
    SHA-256 is the recipe's (`sha256`, recorded by `new`)."""
    r = subprocess.run(["git", "-C", REPO, "show", f"{src['git']}:{src['run_state']}"], capture_output=True)
    if r.returncode == 0:
        return r.stdout
    here = os.path.join(REPO, src["run_state"])
    if src.get("sha256") and os.path.exists(here):
        with open(here, "rb") as f:
            data = f.read()
        if hashlib.sha256(data).hexdigest() == src["sha256"]:
            return data
        sys.exit(f"the recipe's init: {src['run_state']} here is not the state committed at {src['git'][:12]} "
                 f"(SHA-256 {hashlib.sha256(data).hexdigest()[:16]}..., the recipe's {src['sha256'][:16]}...), "
                 f"and git cannot show that one: {r.stderr.decode().strip()}")
    sys.exit(f"the recipe's init: git show {src['git'][:12]}:{src['run_state']} failed "
             f"({r.stderr.decode().strip()}) and no copy of it with the recipe's SHA-256 is here")


def cache_dir(a):
    return os.path.abspath(a.cache or os.environ.get("DBTOR_CACHE") or os.path.expanduser("~/.cache/dbtor"))


def dataset_key(name, k, entry):
    h = hashlib.sha256(json.dumps([entry["args"], entry["generator_commit"]]).encode()).hexdigest()[:12]
    return f"{name}-{k}-{h}"


GENERATOR = ("host-sim", "crates", "Cargo.lock", "Cargo.toml")
BUILT = {}


def host_sim_binary(a, commit, threads):
    """--host-sim, or host-sim built from the recipe's commit: from this
    checkout where its generator (host-sim, crates, Cargo.*) is that
    commit's, else from that commit's tree (git archive) in the cache."""
    if a.host_sim:
        return os.path.abspath(a.host_sim)
    if not shutil.which("cargo"):
        sys.exit("no host-sim: install Rust (cargo) or pass --host-sim BINARY")
    src = REPO
    if shutil.which("git") and os.path.exists(os.path.join(REPO, ".git")):
        r = subprocess.run(["git", "-C", REPO, "diff", "--quiet", commit, "--", *GENERATOR], capture_output=True)
        if r.returncode == 1:
            src = os.path.join(cache_dir(a), "generator", commit[:12])
            print(f"this checkout's generator differs from the recipe's commit {commit[:10]}: building "
                  f"host-sim from that commit's tree in {src}", flush=True)
            if not os.path.exists(os.path.join(src, "Cargo.toml")):
                os.makedirs(src, exist_ok=True)
                arch = subprocess.run(["git", "-C", REPO, "archive", commit], capture_output=True, check=True).stdout
                subprocess.run(["tar", "-x", "-C", src], input=arch, check=True)
    target = (os.environ.get("CARGO_TARGET_DIR") or os.path.join(REPO, "target")) if src == REPO \
        else os.path.join(src, "target")
    binary = os.path.join(target, "release", "host-sim")
    if BUILT.get(src) == binary:
        return binary
    print(f"building host-sim (cargo build --release -p host-sim in {src})", flush=True)
    subprocess.run(["cargo", "build", "--release", "--locked", "-q", "-p", "host-sim", "-j", str(threads)],
                   cwd=src, check=True, env=dict(os.environ, CARGO_TARGET_DIR=target))
    BUILT[src] = binary
    return binary


def run_host_sim(a, cmd, threads, child):
    """Run host-sim's `cmd` on `threads` threads (stderr hidden with
    --quiet), as the child a signal stops; its exit status and seconds."""
    t = time.time()
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    p = subprocess.Popen(cmd, env=env, cwd=REPO, stderr=subprocess.DEVNULL if a.quiet else None)
    child["p"] = p
    rc = p.wait()
    child["p"] = None
    return rc, time.time() - t


def make_dataset(a, entry, out, threads, child):
    """Generate one dataset of the recipe into `out` (through out.partial)."""
    binary = host_sim_binary(a, entry["generator_commit"], threads)
    part = out + ".partial"
    shutil.rmtree(part, ignore_errors=True)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    cmd = [binary, "dataset", "--out", part, *shlex.split(entry["args"])]
    print(f"generating {out}: {shlex.join(cmd)}", flush=True)
    rc, secs = run_host_sim(a, cmd, threads, child)
    if rc:
        shutil.rmtree(part, ignore_errors=True)
        sys.exit(f"host-sim dataset failed (exit {rc})")
    os.replace(part, out)
    print(f"dataset made in {secs:.0f} s", flush=True)


def unet_level(recipe):
    """The noise level a U-Net run learns from (its `--level`, N8 by
    default), or None for a run of another model."""
    t = shlex.split(recipe["train"])
    if "unet" not in [t[i + 1] for i, x in enumerate(t[:-1]) if x == "--model"]:
        return None
    return next((t[i + 1] for i, x in enumerate(t[:-1]) if x == "--level"), "N8")


def add_fbp(a, entry, d, level, threads, child):
    """A U-Net run's input: the FBP of `level`'s sinograms added to the
    dataset `d` (`host-sim fbp`, the same generator commit), once; made
    before the first segment hashes the dataset, so every segment's
    dataset (regenerated on any machine) holds it too."""
    with open(os.path.join(d, "manifest.json")) as f:
        splits = json.load(f)["splits"]
    # Registered in the manifest split by split, after its file is whole.
    if all(any(x["name"] == f"fbp-{level}" for x in sp["arrays"]) for sp in splits):
        return
    binary = host_sim_binary(a, entry["generator_commit"], threads)
    cmd = [binary, "fbp", "--data", d, "--level", level]
    print(f"adding the FBP: {shlex.join(cmd)}", flush=True)
    rc, secs = run_host_sim(a, cmd, threads, child)
    if rc:
        sys.exit(f"host-sim fbp failed (exit {rc}) on {d}")
    print(f"FBP added in {secs:.0f} s", flush=True)


def parse_until(s):
    """HH:MM (UTC, today or tomorrow) or an ISO date-time; a Unix time."""
    now = datetime.datetime.now(datetime.timezone.utc)
    try:
        hh, mm = (int(x) for x in s.split(":"))
        t = now.replace(hour=hh, minute=mm, second=0, microsecond=0)
        if t <= now:
            t += datetime.timedelta(days=1)
        return t.timestamp()
    except ValueError:
        t = datetime.datetime.fromisoformat(s)
        if t.tzinfo is None:
            t = t.replace(tzinfo=datetime.timezone.utc)
        return t.timestamp()


def cmd_new(argv):
    ap = argparse.ArgumentParser(prog="python -m dbtor.continue_run new")
    ap.add_argument("name")
    ap.add_argument("--dataset", action="append", default=[],
                    help="the arguments of `host-sim dataset` without --out (quoted); repeat for several")
    ap.add_argument("--train", required=True,
                    help="train.py's options (quoted), without --data/--out/--device/--threads/--max-minutes")
    ap.add_argument("--init-git", default=None, help="COMMIT:PATH of a model folder in git history")
    ap.add_argument("--init", default=None, help="a model folder or run (the first segment's --init)")
    ap.add_argument("--init-run", default=None,
                    help="COMMIT:NAME: start from the weights of run NAME's state as committed at COMMIT "
                         "(training/runs/NAME/state.dbts, read with git show and unpacked)")
    ap.add_argument("--datasets-of", default=None,
                    help="the datasets of run NAME's recipe (the same arguments and generator commit), "
                         "instead of --dataset")
    ap.add_argument("--why", default="", help="a sentence recorded in the recipe")
    ap.add_argument("--runs", default=RUNS)
    ap.add_argument("--current", action="store_true", help="make it training/runs/CURRENT")
    a = ap.parse_args(argv)
    d = os.path.join(a.runs, a.name)
    if os.path.exists(os.path.join(d, "recipe.json")):
        sys.exit(f"{d}: the run exists")
    commit = git("rev-parse", "HEAD")
    dirty = bool(git("status", "--porcelain", "--", "host-sim", "crates", "Cargo.lock"))
    train = shlex.split(a.train)
    for bad in ("--data", "--out", "--device", "--threads", "--max-minutes", "--state", "--init"):
        if bad in train:
            sys.exit(f"--train: {bad} is set by continue_run, not by the recipe")
    if bool(a.dataset) == bool(a.datasets_of):
        sys.exit("give --dataset (one or more) or --datasets-of RUN")
    init = None
    if a.init_run:
        c, _, run = a.init_run.partition(":")
        init = {"git": git("rev-parse", c), "run_state": f"training/runs/{run}/state.dbts"}
        blob = subprocess.run(["git", "-C", REPO, "show", f"{init['git']}:{init['run_state']}"],
                              capture_output=True)
        if blob.returncode:
            sys.exit(f"--init-run {a.init_run}: {blob.stderr.decode().strip()}")
        # its SHA-256: a machine without git history (a GPU slot's) takes
        # the working tree's file where it is that state
        init["sha256"] = hashlib.sha256(blob.stdout).hexdigest()
    elif a.init_git:
        c, _, p = a.init_git.partition(":")
        init = {"git": git("rev-parse", c), "path": p}
    elif a.init:
        init = {"path": os.path.abspath(a.init)}
    recipe = {
        "format": "dbtor-run/1",
        "name": a.name,
        "created": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "why": a.why,
        "datasets": ([{"command": "host-sim dataset --out DIR " + shlex.join(shlex.split(ds)),
                       "args": shlex.join(shlex.split(ds)),
                       "generator_commit": commit, "generator_dirty": dirty} for ds in a.dataset]
                     or load_run(a.runs, a.datasets_of)[2]["datasets"]),
        "train": shlex.join(train),
        "init": init,
    }
    if dirty:
        print("warning: host-sim or crates have uncommitted changes; the recipe's generator commit "
              "may not regenerate these datasets (the state's SHA-256 will tell)", file=sys.stderr)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "recipe.json"), "w") as f:
        json.dump(recipe, f, indent=1)
        f.write("\n")
    if a.current:
        with open(os.path.join(a.runs, "CURRENT"), "w") as f:
            f.write(a.name + "\n")
    print(f"{d}/recipe.json written")


def load_run(runs, name=None):
    """The run `name` (default: RUNS/CURRENT's) of the runs folder `runs`:
    its name, folder and recipe."""
    if name is None:
        with open(os.path.join(runs, "CURRENT")) as f:
            name = f.read().strip()
    rdir = os.path.join(runs, name)
    with open(os.path.join(rdir, "recipe.json")) as f:
        recipe = json.load(f)
    return name, rdir, recipe


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["new"]:
        return cmd_new(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", default=None, help="the run's name (default: training/runs/CURRENT)")
    lim = ap.add_mutually_exclusive_group()
    lim.add_argument("--minutes", type=float, default=None, help="stop (saved) after this long, all included")
    lim.add_argument("--until", default=None, help="stop (saved) by this time: HH:MM UTC or ISO date-time")
    ap.add_argument("--threads", type=int, default=None, help="torch and host-sim threads (default: all)")
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto")
    ap.add_argument("--cache", default=None, help="datasets and the local run folder (default $DBTOR_CACHE "
                                                  "or ~/.cache/dbtor)")
    ap.add_argument("--host-sim", default=None, help="a host-sim binary (otherwise built with cargo)")
    ap.add_argument("--ledger", default=LEDGER)
    ap.add_argument("--note", default="", help="recorded in the ledger line")
    ap.add_argument("--save-every-minutes", type=float, default=10.0)
    ap.add_argument("--no-compile", action="store_true", help="drop the recipe's --compile (speed only)")
    ap.add_argument("--runs", default=RUNS, help="the runs folder (default training/runs)")
    ap.add_argument("--extra", default="", help="more train.py options (quoted), e.g. '--stop-at 10'")
    ap.add_argument("--quiet", action="store_true", help="hide host-sim's progress")
    a = ap.parse_args(argv)
    start = time.time()
    deadline = None
    if a.minutes is not None:
        deadline = start + 60 * a.minutes
    elif a.until:
        deadline = parse_until(a.until)
    name, rdir, recipe = load_run(a.runs, a.run)
    state = os.path.join(rdir, "state.dbts")
    cache = cache_dir(a)
    threads = a.threads or os.cpu_count()

    child = {"p": None}

    def on_signal(sig, _):
        if child["p"] is not None:
            child["p"].terminate()
        sys.exit(f"stopped by signal {sig} before training (nothing to save)")

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    data = []
    fbp_level = unet_level(recipe)
    for k, entry in enumerate(recipe["datasets"]):
        d = os.path.join(cache, "datasets", dataset_key(name, k, entry))
        if not os.path.exists(os.path.join(d, "manifest.json")):
            make_dataset(a, entry, d, threads, child)
        if fbp_level:
            add_fbp(a, entry, d, fbp_level, threads, child)
        data.append(d)
    init = []
    if not os.path.exists(state) and recipe.get("init"):
        src = recipe["init"]
        if "run_state" in src:
            # Another run's state as committed: its weights, unpacked into a
            # run folder train.py's --init reads.
            dest = os.path.join(cache, "init", src["git"][:12] + "-" + os.path.basename(
                os.path.dirname(src["run_state"])))
            if not os.path.exists(os.path.join(dest, "checkpoint.pt")):
                blob = committed_state(src)
                os.makedirs(os.path.dirname(dest), exist_ok=True)
                packed = dest + ".dbts"
                with open(packed, "wb") as f:
                    f.write(blob)
                subprocess.run([sys.executable, "-m", "dbtor.state", "unpack", packed, "--out", dest],
                               check=True, cwd=os.path.join(REPO, "training"))
            init = ["--init", dest]
        elif "git" in src:
            dest = os.path.join(cache, "init", src["git"][:12])
            path = os.path.join(dest, src["path"])
            if not os.path.exists(path):
                os.makedirs(dest, exist_ok=True)
                arch = subprocess.run(["git", "-C", REPO, "archive", src["git"], src["path"]], capture_output=True,
                                      check=True).stdout
                subprocess.run(["tar", "-x", "-C", dest], input=arch, check=True)
            init = ["--init", path]
        else:
            init = ["--init", src["path"]]
    for s, h in old.items():
        signal.signal(s, h)

    train = shlex.split(recipe["train"])
    if a.no_compile and "--compile" in train:
        train.remove("--compile")
    out = os.path.join(cache, "runs", name)
    recipe_file = os.path.join(rdir, "recipe.json")
    args = ["--data", *data, "--out", out, *train, *init, "--state", state, "--run-name", name,
            "--recipe", recipe_file, "--device", a.device, "--threads", str(threads),
            "--save-every-minutes", str(a.save_every_minutes), "--ledger", a.ledger,
            "--ledger-note", a.note, *shlex.split(a.extra)]
    if deadline is not None:
        if deadline - time.time() < 60:
            sys.exit("less than a minute left before the time limit: nothing to do")
        args += ["--deadline", str(deadline)]
    print("python -m dbtor.train " + shlex.join(args), flush=True)
    # torch is imported only now, so that these reach its thread pools and compiler
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", str(threads))
    from . import train as trainer
    trainer.main(args)


if __name__ == "__main__":
    main()
