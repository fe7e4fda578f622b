#!/usr/bin/env bash
# Generate the external VICTRE set's uncompressed breasts one after another
# (issue #48 point 5; README.md, "Proposed 10-breast set"). EVALUATION ONLY.
# Usage: scripts/victre/generate-set.sh WORKDIR [SEED ...]
#   WORKDIR: where build-generator.sh built (WORKDIR/build/breastPhantom,
#   WORKDIR/breastPhantom/cfg); volumes go to WORKDIR/out/SEED (out of git).
#   With no seeds, all ten. A seed whose volume exists is skipped.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
work=${1:?usage: generate-set.sh WORKDIR [SEED ...]}
shift
# seed class size-scale (the README's table)
table="48001 dense 0.72
48002 dense 1.00
48003 dense 1.30
48004 hetero 0.67
48005 hetero 1.00
48006 hetero 1.22
48007 scattered 0.73
48008 scattered 1.00
48009 fatty 1.00
48010 fatty 1.33"
want=("$@")
while read -r seed cls k; do
    if [ ${#want[@]} -gt 0 ] && [[ ! " ${want[*]} " == *" $seed "* ]]; then continue; fi
    out="$work/out/$seed"
    if [ -f "$out/p_$seed.raw.gz" ]; then echo "$seed: exists, skipped"; continue; fi
    mkdir -p "$out"
    python3 "$here/make-cfg.py" "$work/breastPhantom/cfg" "$cls" "$k" "$seed" "$out" > "$out/$seed.cfg"
    echo "$seed: $cls x $k -> $out ($(date -u +%H:%M:%S))"
    OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} /usr/bin/time -v nice -n 10 \
        "$work/build/breastPhantom" -c "$out/$seed.cfg" > "$out/run.log" 2> "$out/time.log"
    grep -E "Elapsed|Maximum resident" "$out/time.log" | sed "s/^/$seed: /"
done <<< "$table"
