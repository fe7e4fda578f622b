#!/usr/bin/env bash
# A training run's shipping bar on the validation split (issue #49 point 4;
# the bar itself is the run's training/runs/RUN/BAR.md, written before any
# evaluation of its weights): export the run's final weights, calibrate the
# glandularity on the anatomical validation breasts, then run every row the
# bar names and print one table with each criterion's verdict. Never the
# test split: that is run once, afterwards, by hand, whatever the verdict.
#
#   ./scripts/shipping-bar.sh RUN [OUT]
#
# RUN: a run under training/runs whose final checkpoint is in the trainer's
# cache ($CACHE/runs/RUN/checkpoint.pt, written by train-continue.sh or a
# GPU slot's continue_run; `python -m dbtor.state unpack` remakes it from
# the committed state.dbts). OUT: the model folder and the accuracy runs
# (default /tmp/RUN-bar).
#
# Settings (environment):
#   RECONSTRUCTORS  fp32,int8 (default) or fp32 alone: the bar needs both,
#                   so fp32 first settles a run that fp32 already fails
#                   without the int8 export's cost
#   GPTQ            0 (default: the int8 weights rounded to the nearest) or
#                   N: rounded by asymmetric GPTQ on N training slices, as
#                   the shipped dbtor-x4t3qa's (about 20 min on 2 cores)
#   PHANTOMS        validation breasts per row (10, the bars')
#   CALIBRATION     validation breasts the calibration is fitted on (16)
#   SKIN            the skin rule, as `dbt-eval classification --skin`
#                   spells it (default: the firmware's); the calibrations
#                   and every row use it
#   CACHE           the trainer's cache (~/.cache/dbtor)
#   SKIP_EXPORT=1   reuse OUT/model (a second pass, e.g. int8 after fp32)
#
# The criteria are the ones BAR.md states for dbtor-x4w and dbtor-x4x
# (glandularity bias and 95 % limits, patient-MGD bias and sd); a run whose
# BAR.md says otherwise needs its own table.
set -euo pipefail
cd "$(dirname "$0")/.."
RUN=${1:?usage: shipping-bar.sh RUN [OUT]}
OUT=${2:-/tmp/$RUN-bar}
RECONSTRUCTORS=${RECONSTRUCTORS:-fp32,int8}
GPTQ=${GPTQ:-0}
PHANTOMS=${PHANTOMS:-10}
CALIBRATION=${CALIBRATION:-16}
CACHE=${CACHE:-$HOME/.cache/dbtor}
SKIN=${SKIN:-}
skin=()
[ -n "$SKIN" ] && skin=(--skin "$SKIN")
EVAL=${EVAL:-target/release/dbt-eval}
[ -f "training/runs/$RUN/BAR.md" ] || { echo "no training/runs/$RUN/BAR.md: write the bar before evaluating" >&2; exit 2; }
ckpt="$CACHE/runs/$RUN/checkpoint.pt"
[ -f "$ckpt" ] || { echo "no $ckpt: unpack the run's state (python -m dbtor.state unpack)" >&2; exit 2; }
seed=$(python3 -c 'import json,sys; r=json.load(open(sys.argv[1])); import re; print(re.search(r"--seed (\d+)", r["datasets"][0]["args"]).group(1))' "training/runs/$RUN/recipe.json")
data=$(ls -d "$CACHE/datasets/$RUN-0-"* | head -n 1)
[ -d "$data" ] || { echo "no dataset $CACHE/datasets/$RUN-0-*" >&2; exit 2; }
model="$OUT/model"
mkdir -p "$OUT"
t0=$SECONDS
log() { echo "[shipping-bar $((SECONDS - t0)) s] $*" | tee -a "$OUT/bar.log" >&2; }
log "skin rule: ${SKIN:-the firmware default}"
log "run $RUN, checkpoint $(python3 -c 'import torch,sys; print(torch.load(sys.argv[1], map_location="cpu", weights_only=False).get("iteration", "?"))' "$ckpt" 2>/dev/null || echo '?'), train seed $seed, reconstructors $RECONSTRUCTORS, GPTQ $GPTQ"
log "CPU: $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) CPUs"
if [ "${SKIP_EXPORT:-0}" != 1 ]; then
    rm -rf "$model"
    gptq=()
    [ "$GPTQ" -gt 0 ] && gptq=(--gptq "$GPTQ" --gptq-asymmetric)
    (cd training && python3 -m dbtor.export --run "$CACHE/runs/$RUN" --data "$data" --out "$model" \
        --name "$RUN-n8" --calibration 16 --fixtures 2 "${gptq[@]}") >> "$OUT/bar.log" 2>&1
    log "exported $model"
fi
# Each precision calibrated on the anatomical validation breasts under the
# rule (mono; the clinical row's corrected inputs fall back to it, as the
# firmware's do: dbt_model::calibration::pick_calibration). A fit under
# another rule than the file's starts the file afresh, so every precision
# the rows read is fitted here, under this rule.
for p in ${RECONSTRUCTORS//,/ }; do
    "$EVAL" calibrate --model "$model" --precision "$p" --population anatomical \
        --phantoms "$CALIBRATION" --train-seed "$seed" "${skin[@]}" >> "$OUT/bar.log" 2>&1
    log "$p: calibrated on $CALIBRATION anatomical validation breasts"
done
common=(--split validation --train-seed "$seed" --phantoms "$PHANTOMS" --model "$model"
    --dose-uncertainty 0.05 --reconstructors "$RECONSTRUCTORS" "${skin[@]}")
row() {
    local name=$1
    shift
    "$EVAL" accuracy "${common[@]}" --out "$OUT/$name" "$@" >> "$OUT/bar.log" 2>&1
    log "row $name done"
}
row anatomical-mono --population anatomical
row procedural-mono --population procedural
row anatomical-clinical --population anatomical --physics clinical --descatter --linearise
python3 - "$OUT" <<'EOF'
import json, sys
out = sys.argv[1]
# (row, criteria): glandularity |bias| and limits (pp), MGD |bias| and sd (%).
bars = {
    "anatomical-mono": (2.0, 5.0, 10.0, 10.0),
    "procedural-mono": (1.0, 3.0, 10.0, 10.0),
    "anatomical-clinical": (3.0, None, None, None),
}
print("| row | reconstructor | glandularity reported (pp): bias, sd, 95 % limits | patient MGD (%): bias, sd, max abs | bar |")
print("|---|---|---|---|---|")
verdict = True
for name, (gb, gl, mb, ms) in bars.items():
    d = json.load(open(f"{out}/{name}/accuracy.json"))
    for r in d["reconstructors"]:
        g, m = r["summary"]["glandularity_reported_pp"], r["summary"]["mgd_percent"]
        miss = []
        if abs(g["bias"]) > gb:
            miss.append(f"glandularity bias {g['bias']:+.2f} beyond +-{gb}")
        if gl is not None and max(abs(g["loa"][0]), abs(g["loa"][1])) > gl:
            miss.append(f"limits beyond +-{gl}")
        if mb is not None and abs(m["bias"]) > mb:
            miss.append(f"MGD bias {m['bias']:+.1f} beyond +-{mb}")
        if ms is not None and m["sd"] > ms:
            miss.append(f"MGD sd {m['sd']:.1f} above {ms}")
        verdict &= not miss
        print(f"| {name} ({g['n']}) | {r['reconstructor']} | {g['bias']:+.2f}, {g['sd']:.2f}, [{g['loa'][0]:+.2f}, {g['loa'][1]:+.2f}] "
              f"| {m['bias']:+.2f}, {m['sd']:.2f}, {m['max_abs']:.1f} | {'met' if not miss else 'missed: ' + '; '.join(miss)} |")
print()
print("every row met:", "YES" if verdict else "NO")
EOF
log "done"
