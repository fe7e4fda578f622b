#!/usr/bin/env bash
# The one command that runs every test: formatting, lints, and the whole
# workspace's test suite. `.ci/run` calls exactly this. Each stage's wall
# time is printed at the end (issue #52: where CI's time goes).
set -euo pipefail
cd "$(dirname "$0")/.."
times=()
stage() {
    local name=$1
    shift
    local t0=$SECONDS rc=0
    "$@" || rc=$?
    # the disk left after each stage: a full disk fails the later stages
    # with errors that need not say so
    times+=("$(printf '%-28s %5d s   disk free after: %s' "$name" $((SECONDS - t0)) \
        "$(df -h --output=avail . 2>/dev/null | tail -n 1 | tr -d ' ')")")
    if [ "$rc" != 0 ]; then
        times+=("  (failed: exit $rc)")
        exit "$rc"
    fi
}
report() {
    echo "test-all: time by stage (wall clock, $(nproc) CPUs)" >&2
    for t in "${times[@]}"; do echo "  $t" >&2; done
}
trap report EXIT
stage "cargo fmt --check" cargo fmt --all --check
stage "cargo clippy" cargo clippy --workspace --all-targets --locked -- -D warnings
# Every binary, once, in the tests' own profile (optimised, debug assertions
# on): the process tests (hil-tests: cli, daemon, stream, ...) and the
# training smoke test run these instead of building their own, and cargo
# test reuses every crate of this build (crates/workspace-hack keeps the
# features the same; hil-tests/tests/architecture.rs checks it): one build
# of the workspace in all (issue #52 point 7, CI's time).
stage "cargo build (binaries)" cargo build --profile test --locked --workspace --bins
export DBTOR_BIN_DIR="$PWD/target/debug"
stage "cargo test" cargo test --workspace --locked
# The trainer: a few iterations on a small dataset, resumed, exported, and the
# export checked by the firmware's runtime (needs training/requirements.txt).
if ! python3 -c 'import torch, onnx, onnxruntime' 2>/dev/null; then
    echo "training smoke test: PyTorch/onnx/onnxruntime missing; pip install -r training/requirements.txt (.ci/run does)" >&2
    exit 1
fi
stage "training smoke test" ./training/smoke-test.sh
