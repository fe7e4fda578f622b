#!/usr/bin/env bash
# Each test binary of the workspace run alone, as cargo test runs it (from
# its package's folder), with its wall, user and system time and the share
# of the machine's cores it kept busy; the slowest first, the totals last.
# Issue #52 point 7: where the test stage of CI's time goes, and how much of
# the cores the tests leave idle (what running other work beside them could
# use). Builds the test binaries first if needed (the tests' profile) and
# uses the binaries of `cargo build --profile test --workspace --bins` for
# the process tests (DBTOR_BIN_DIR), as scripts/test-all.sh does.
#
#   ./scripts/test-binaries-time.sh [> table.md]
#
# A binary that fails is listed with its exit status and its output is
# shown on stderr; the script then exits 1. Needs jq and GNU time (/usr/bin/time).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v jq >/dev/null || { echo "test-binaries-time: needs jq" >&2; exit 1; }
[ -x /usr/bin/time ] || { echo "test-binaries-time: needs GNU time at /usr/bin/time" >&2; exit 1; }
cargo build --profile test --locked --workspace --bins -q
export DBTOR_BIN_DIR="${DBTOR_BIN_DIR:-$PWD/target/debug}"
list=$(mktemp)
out=$(mktemp)
rows=$(mktemp)
trap 'rm -f "$list" "$out" "$out.time" "$rows"' EXIT
cargo test --workspace --locked --no-run --message-format=json 2>/dev/null \
    | jq -r 'select(.reason == "compiler-artifact" and .executable != null and .profile.test == true)
             | "\(.manifest_path)\t\(.executable)\t\(.target.name)"' > "$list"
cores=$(nproc)
failed=0
while IFS=$'\t' read -r manifest exe name; do
    dir=$(dirname "$manifest")
    rc=0
    (cd "$dir" && /usr/bin/time -f "%e %U %S" -o "$out.time" "$exe" > "$out" 2>&1) || rc=$?
    read -r wall user sys < <(tail -n 1 "$out.time")
    if [ "$rc" != 0 ]; then
        failed=1
        echo "test-binaries-time: $name ($dir) exited with $rc:" >&2
        cat "$out" >&2
    fi
    printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$wall" "$user" "$sys" "$rc" "$name" "${dir#"$PWD"/}" >> "$rows"
done < "$list"
echo "Test binaries run alone on $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'), $cores CPUs, at $(git rev-parse --short HEAD)"
echo
echo "| test binary | package folder | wall s | user + sys s | cores busy | exit |"
echo "| --- | --- | --- | --- | --- | --- |"
sort -t$'\t' -k1 -g -r "$rows" | awk -F'\t' -v n="$cores" '{
    cpu = $2 + $3; busy = ($1 > 0) ? cpu / $1 : 0
    printf "| %s | %s | %.1f | %.1f | %.2f of %d | %s |\n", $5, $6, $1, cpu, busy, n, $4 }'
awk -F'\t' -v n="$cores" '{ w += $1; c += $2 + $3; k++ } END {
    printf "\n%d binaries: %.0f s wall, %.0f s of CPU; the cores were %.0f %% busy (%.0f core-s idle)\n",
        k, w, c, (w > 0) ? 100 * c / (n * w) : 0, n * w - c }' "$rows"
exit "$failed"
