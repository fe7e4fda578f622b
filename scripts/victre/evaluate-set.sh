#!/usr/bin/env bash
# Compress the external VICTRE set's generated breasts and report each through
# the product's pipeline (issue #48 point 5). EVALUATION ONLY: never train,
# tune, calibrate or choose a model or threshold on these breasts.
# Usage: scripts/victre/evaluate-set.sh WORKDIR [SEED ...]
#   Reads WORKDIR/out/SEED/p_SEED.mhd (generate-set.sh), writes
#   WORKDIR/set/victre-SEED.toml + .raw (the compressed breast) and
#   WORKDIR/eval/SEED (dbt-eval accuracy: accuracy.json), then the tables
#   (REPORT_ONLY=1: the tables of the runs already made).
# Compression: dbt-eval victre-compress, contact fraction 0.5 (README.md,
# section 3), thickness = the VICTRE pipeline's ratio for the class times the
# breast's height (dense 0.488, hetero 0.502, scattered 0.507, fatty 0.546).
set -euo pipefail
cd "$(dirname "$0")/../.."
work=${1:?usage: evaluate-set.sh WORKDIR [SEED ...]}
shift
bin=${DBT_EVAL:-target/release/dbt-eval}
ratio() { case $1 in dense) echo 0.488;; hetero) echo 0.502;; scattered) echo 0.507;; fatty) echo 0.546;; esac; }
mkdir -p "$work/set" "$work/eval"
dirs=()
for out in "$work"/out/4800*; do
    seed=$(basename "$out")
    if [ $# -gt 0 ] && [[ ! " $* " == *" $seed "* ]]; then continue; fi
    [ -f "$out/p_$seed.raw.gz" ] || { echo "$seed: not generated yet, skipped"; continue; }
    cls=$(sed -n 's/^# VICTRE_\([a-z]*\)\.cfg.*/\1/p' "$out/$seed.cfg")
    if [ -z "${REPORT_ONLY:-}" ]; then
    "$bin" victre-compress --mhd "$out/p_$seed.mhd" --thickness-ratio "$(ratio "$cls")" --contact 0.5 \
        --out "$work/set/victre-$seed.toml"
    "$bin" accuracy --model models/dbtor-x4t3qa --reconstructors int8 --dose-uncertainty 0.05 \
        --phantom "$work/set/victre-$seed.toml" --out "$work/eval/$seed" > "$work/eval/$seed.log" 2>&1
    fi
    dirs+=("$seed ($cls)=$work/eval/$seed")
done
[ ${#dirs[@]} -gt 0 ] || { echo "no generated breast"; exit 1; }
python3 - "${dirs[@]}" <<'PY'
import json, sys
print("| breast | thickness (mm) | truth G (%) | reported - truth (pp) | physics - truth (pp) | MGD (%) | fill of the box | data residual beyond the noise | density check | 95 % interval holds the truth (G, MGD) |")
print("|---|---|---|---|---|---|---|---|---|---|")
for arg in sys.argv[1:]:
    label, _, path = arg.partition("=")
    c = json.load(open(f"{path}/accuracy.json"))["reconstructors"][0]["cases"][0]
    holds = lambda iv, t: "-" if not iv["limits"] else ("yes" if iv["limits"][0] <= t <= iv["limits"][1] else "no")
    chk = c["density_check"]
    print(f"| {label} | {c['thickness_mm']:.1f} | {100 * c['g_true']:.1f} | {100 * (c['g_reported'] - c['g_true']):+.1f} | "
          f"{100 * (c['g_physics'] - c['g_true']):+.1f} | {100 * (c['mgd_est'] / c['mgd_true'] - 1):+.1f} | "
          f"{c['plausibility']['volume']['fill']:.3f} | {c['data_fit']['excess']:.4f} | "
          f"{'confirmed' if chk['confirmed'] else 'NOT confirmed: ' + '; '.join(chk['reasons'])} | "
          f"{holds(c['intervals']['glandularity'], c['g_true'])}, {holds(c['intervals']['mgd'], c['mgd_true'])} |")
PY
scripts/density-check-table.py "${dirs[@]}"
scripts/intervals-table.py "${dirs[@]}"
