#!/usr/bin/env bash
# Prepare a GPU slot here (issue #49 point 3; see scripts/gpu-slot.sh): the
# release host-sim built, stripped and compressed into .gpu-carry/ (about
# 6 MiB: the working tree that travels must stay under 64 MiB), its glibc
# symbol versions listed beside it (the device image must offer the newest),
# .gpu-carry/ kept out of git; then the device call to make.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -q -p host-sim
mkdir -p .gpu-carry
grep -qx '/.gpu-carry/' .git/info/exclude 2>/dev/null || echo '/.gpu-carry/' >> .git/info/exclude
strip -o .gpu-carry/host-sim target/release/host-sim
objdump -T .gpu-carry/host-sim | grep -o 'GLIBC_[0-9.]*' | sort -uV > .gpu-carry/host-sim.glibc
xz -T0 -6 -f .gpu-carry/host-sim
tracked=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -n 1 | cut -f1)
carried=$(du -cb .gpu-carry | tail -n 1 | cut -f1)
echo "host-sim for the device: $(du -h .gpu-carry/host-sim.xz | cut -f1), needs $(tail -n 1 .gpu-carry/host-sim.glibc)"
echo "working tree that travels: $(( (tracked + carried) / 1048576 )) MiB of 64 (tracked files and .gpu-carry; untracked files count too)"
echo "the device call: run(command=\"OUT=\$OUT ./scripts/gpu-slot.sh\", carry=[\".gpu-carry\"], timeout_s=600)"
