#!/usr/bin/env bash
# Compress the external VICTRE set's generated breasts and report each through
# the product's pipeline (issue #48 point 5). EVALUATION ONLY: never train,
# tune, calibrate or choose a model or threshold on these breasts.
# Usage: scripts/victre/evaluate-set.sh WORKDIR [SEED ...]
#   Reads WORKDIR/out/SEED/p_SEED.mhd (generate-set.sh), writes
#   WORKDIR/set/victre-SEED.toml + .raw (the compressed breast) and
#   WORKDIR/eval/SEED (dbt-eval accuracy: accuracy.json), then the table.
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
    "$bin" victre-compress --mhd "$out/p_$seed.mhd" --thickness-ratio "$(ratio "$cls")" --contact 0.5 \
        --out "$work/set/victre-$seed.toml"
    "$bin" accuracy --model models/dbtor-x4t3qa --reconstructors int8 --dose-uncertainty 0.05 \
        --phantom "$work/set/victre-$seed.toml" --out "$work/eval/$seed" > "$work/eval/$seed.log" 2>&1
    dirs+=("$seed ($cls)=$work/eval/$seed")
done
[ ${#dirs[@]} -gt 0 ] || { echo "no generated breast"; exit 1; }
scripts/density-check-table.py "${dirs[@]}"
scripts/intervals-table.py "${dirs[@]}"
