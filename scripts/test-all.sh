#!/usr/bin/env bash
# The one command that runs every test: formatting, lints, and the whole
# workspace's test suite. `.ci/run` calls exactly this. Each stage's wall
# time is printed at the end (issue #52: where CI's time goes).
set -euo pipefail
cd "$(dirname "$0")/.."
times=()
clippy_pid=""
clippy_dir="$PWD/target/clippy"
# The lints run beside the other stages, at nice 19, in their own target
# folder (cargo locks a build folder while its tests run): they type-check
# every crate, which shares nothing with the tests' optimised build, and
# take the cores the build's serial phases, the test binaries and the smoke
# test leave idle (docs/benchmarks.md, "CI time"). A lint failure fails the
# run at the next stage's end, or at the latest after the last stage.
clippy_check() {
    [ -n "$clippy_pid" ] || return 0
    if [ "${1:-}" != wait ] && kill -0 "$clippy_pid" 2>/dev/null; then
        return 0
    fi
    wait "$clippy_pid" || true
    clippy_pid=""
    local rc
    rc=$(cat "$clippy_dir/test-all.rc" 2>/dev/null || echo 1)
    times+=("$(printf '%-28s %5d s   beside the stages above' "cargo clippy" \
        "$(cat "$clippy_dir/test-all.s" 2>/dev/null || echo 0)")")
    if [ "$rc" != 0 ]; then
        cat "$clippy_dir/test-all.log" >&2
        times+=("  (failed: exit $rc)")
        exit "$rc"
    fi
}
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
    clippy_check
}
report() {
    # a run that stops early stops the lints too
    if [ -n "$clippy_pid" ]; then kill "$clippy_pid" 2>/dev/null || true; fi
    echo "test-all: time by stage (wall clock, $(nproc) CPUs)" >&2
    for t in "${times[@]}"; do echo "  $t" >&2; done
}
trap report EXIT
stage "cargo fmt --check" cargo fmt --all --check
mkdir -p "$clippy_dir"
# an earlier run's result must not stand for this one's
rm -f "$clippy_dir/test-all.rc" "$clippy_dir/test-all.s" "$clippy_dir/test-all.log"
(
    t0=$SECONDS rc=0
    CARGO_TARGET_DIR="$clippy_dir" setsid nice -n 19 cargo clippy --workspace --all-targets --locked \
        -- -D warnings > "$clippy_dir/test-all.log" 2>&1 &
    cargo_pid=$!
    trap 'kill -- -"$cargo_pid" 2>/dev/null; exit 143' TERM
    wait "$cargo_pid" || rc=$?
    echo $((SECONDS - t0)) > "$clippy_dir/test-all.s"
    echo "$rc" > "$clippy_dir/test-all.rc"
) &
clippy_pid=$!
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
# the lints, if they are still running
t_wait=$SECONDS
clippy_check wait
[ $((SECONDS - t_wait)) -lt 1 ] || times+=("$(printf '%-28s %5d s' "  (waited for the lints)" $((SECONDS - t_wait)))")
