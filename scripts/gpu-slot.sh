#!/usr/bin/env bash
# One GPU slot of the current training run (issue #49 point 3): the whole
# slot as one command of at most 10 minutes on the device machine, its
# results as files under $OUT.
#
# Here, first (builds host-sim, strips and compresses it into .gpu-carry/,
# which .git/info/exclude keeps out of git; prints the call):
#   ./scripts/gpu-slot-prepare.sh
# Then the device tool's run, as the prepare script prints it:
#   command: OUT=$OUT ./scripts/gpu-slot.sh    carry: [".gpu-carry"]    timeout_s: 600
# Then, here: copy the files that came back (state.dbts, curve.csv into
# training/runs/NAME/; LEDGER.md over training/LEDGER.md) and commit them.
#
# What it does, each step logged with its second in $OUT/slot.log:
# 1. a self-check that fails within about 30 s: host-sim runs on this
#    image's glibc, the GPU is seen (nvidia-smi, torch.cuda), the run has
#    iterations left in its schedule (a finished run is refused), one bf16
#    training iteration on a tiny dataset, and the run's state unpacked and
#    packed again (its round trip);
# 2. the run's datasets regenerated from its recipe on every core into
#    $CACHE (continue_run.py checks their SHA-256 against the state's);
# 3. training on the device in the recipe's precision (bf16) until the
#    slot's budget, the state saved every 2 minutes and at the end, the
#    ledger's row written with the device's name and the samples/s measured;
# 4. $OUT: state.dbts, curve.csv, LEDGER.md, slot.log (each well under the
#    16 MiB a file may be; 5-6 MiB in all for dbtor-x4w).
#
# Expected on an H100: 50-150 samples/s (our estimate, not a measurement:
# the step's convolutions are about 700 GFLOP at batch 8, at 10-20 % of the
# GPU's bf16 rate, plus the projector's sparse products and the launches of
# 20 small blocks); the ledger's row is the measurement.
#
# The CPU path is rehearsed by training/smoke-test.sh (DEVICE=cpu, a tiny
# run of its own): everything but the GPU itself.
#
# Settings (environment): OUT (required), DEVICE (cuda; cpu to rehearse),
# BUDGET_S (the whole command's seconds, default 560 of the call's 600),
# RUNS (training/runs), RUN (RUNS/CURRENT's), CACHE (/tmp/dbtor-cache),
# HOST_SIM (a binary instead of .gpu-carry/host-sim.xz), LEDGER (the ledger
# copied into $OUT and appended to; training/LEDGER.md), PYTHON.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
: "${OUT:?OUT: the folder whose files come back}"
DEVICE=${DEVICE:-cuda}
BUDGET_S=${BUDGET_S:-560}
RUNS=$(realpath "${RUNS:-training/runs}")
RUN=${RUN:-$(cat "$RUNS/CURRENT")}
CACHE=${CACHE:-/tmp/dbtor-cache}
LEDGER=${LEDGER:-training/LEDGER.md}
PY=${PYTHON:-python3}
mkdir -p "$OUT" "$CACHE"
OUT=$(realpath "$OUT")
t0=$SECONDS
log() { echo "[gpu-slot $((SECONDS - t0)) s] $*" | tee -a "$OUT/slot.log" >&2; }
fail() { log "FAILED: $*"; exit 3; }
log "run $RUN, device $DEVICE, budget $BUDGET_S s, $(nproc) CPUs"

# 1. The self-check.
if [ -n "${HOST_SIM:-}" ]; then
    hs=$(realpath "$HOST_SIM")
else
    [ -f .gpu-carry/host-sim.xz ] || fail "no .gpu-carry/host-sim.xz: run ./scripts/gpu-slot-prepare.sh and carry .gpu-carry"
    xz -dc .gpu-carry/host-sim.xz > /tmp/host-sim && chmod +x /tmp/host-sim
    hs=/tmp/host-sim
fi
log "glibc here: $(ldd --version 2>&1 | head -n 1)"
"$hs" --help > /dev/null 2>> "$OUT/slot.log" || fail "host-sim does not run on this image (its glibc symbols: .gpu-carry/host-sim.glibc)"
device_name=cpu
if [ "$DEVICE" = cuda ]; then
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader >> "$OUT/slot.log" 2>&1 \
        || fail "nvidia-smi sees no GPU"
    device_name=$($PY -c 'import torch; assert torch.cuda.is_available(), "CUDA sees no GPU"; print(torch.cuda.get_device_name(0))') \
        || fail "PyTorch sees no CUDA device"
fi
log "device: $device_name"
# A run that has finished its schedule has nothing to train: refuse in
# seconds rather than spend the slot regenerating its datasets.
if [ -f "$RUNS/$RUN/state.dbts" ]; then
    left=$(cd training && $PY -m dbtor.state show "$RUNS/$RUN/state.dbts" | $PY -c \
        'import json, sys; h = json.load(sys.stdin); print(h["options"]["iters"] - h["iteration"], h["iteration"], h["options"]["iters"])') \
        || fail "cannot read the state's header ($RUNS/$RUN/state.dbts)"
    read -r n done_it all_it <<< "$left"
    [ "$n" -gt 0 ] || fail "run $RUN has finished its schedule (iteration $done_it of $all_it): nothing to train; make the next run first (python -m dbtor.continue_run new NAME ... --current)"
    log "run $RUN: iteration $done_it of $all_it"
fi
sc=$(mktemp -d)
# host-sim's log goes into slot.log: a failure here (a full disk, say) must
# say why in the files that come back.
if ! "$hs" dataset --out "$sc/ds" --slices 1500 --test-phantoms 0 --levels N8 --binning 4 \
    > "$sc/host-sim.log" 2>&1; then
    cat "$sc/host-sim.log" >> "$OUT/slot.log"
    tail -n 5 "$sc/host-sim.log" >&2
    df -h "$sc" "$OUT" 2>&1 | tee -a "$OUT/slot.log" >&2 || true
    fail "host-sim could not make the self-check's dataset in $sc (its log above and in slot.log)"
fi
cat "$sc/host-sim.log" >> "$OUT/slot.log"
(cd training && $PY -m dbtor.train --data "$sc/ds" --out "$sc/run" --iters 1 --batch 2 --blocks 2 \
    --val-every 1 --log-every 1 --device "$DEVICE" --precision bf16 >> "$OUT/slot.log" 2>&1) \
    || fail "one bf16 training iteration"
if [ -f "$RUNS/$RUN/state.dbts" ]; then
    (cd training && $PY -m dbtor.state unpack "$RUNS/$RUN/state.dbts" --out "$sc/unpacked" >> "$OUT/slot.log" 2>&1 \
        && $PY -m dbtor.state roundtrip "$sc/unpacked/checkpoint.pt" >> "$OUT/slot.log" 2>&1) \
        || fail "the state's round trip ($RUNS/$RUN/state.dbts)"
else
    log "run $RUN has no state yet: its first segment starts from the recipe's init"
fi
rm -rf "$sc"
log "self-check passed"

# 2-3. Datasets and training, to the budget (continue_run's --minutes counts
# the datasets' generation too); 20 s kept for the copies.
cp "$LEDGER" "$OUT/LEDGER.md"
minutes=$($PY -c "print(max(0.5, ($BUDGET_S - $((SECONDS - t0)) - 20) / 60))")
log "training for $minutes minutes"
(cd training && $PY -m dbtor.continue_run --run "$RUN" --runs "$RUNS" --device "$DEVICE" --cache "$CACHE" \
    --host-sim "$hs" --minutes "$minutes" --save-every-minutes 2 --ledger "$OUT/LEDGER.md" --quiet \
    --note "gpu-slot.sh on $device_name" 2>&1 | tee -a "$OUT/slot.log" | tail -n 5 >&2) \
    || log "the trainer exited with an error (the last saved state is copied)"

# 4. What comes back.
cp "$RUNS/$RUN/state.dbts" "$RUNS/$RUN/curve.csv" "$OUT/"
log "done: $(cd "$OUT" && ls -l | tail -n +2 | awk '{print $NF" "$5}' | paste -sd, -)"
cd "$root"
