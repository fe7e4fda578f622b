#!/usr/bin/env bash
# The one command that runs every test: formatting, lints, and the whole
# workspace's test suite. `.ci/run` calls exactly this. Each stage's wall
# time and CPU time are printed at the end (issue #52: where CI's time goes).
set -euo pipefail
cd "$(dirname "$0")/.."
times=()
# cargo's own folder (CARGO_TARGET_DIR, else target/): the binaries the
# process tests run, the lints' folder and the background jobs' files
target_dir=$(mkdir -p "${CARGO_TARGET_DIR:-target}" && cd "${CARGO_TARGET_DIR:-target}" && pwd)
clippy_dir="$target_dir/clippy"
jobs_dir="$target_dir/test-all"
mkdir -p "$clippy_dir" "$jobs_dir"
# CPU seconds of a shell's finished children (`children_cpu PID`:
# /proc/PID/stat's cutime + cstime): a stage's or job's CPU time against its
# wall time says how much of the cores it left idle. Each stage and job runs
# in a subshell of its own, which reads its own, so that a job reaped during
# a stage is not counted as the stage's.
ticks=$(getconf CLK_TCK 2>/dev/null || echo 100)
children_cpu() {
    local s
    s=$(cat "/proc/$1/stat" 2>/dev/null) || { echo 0; return; }
    s=${s##*) }
    # shellcheck disable=SC2086
    set -- $s
    echo $(((${14} + ${15}) / ticks))
}
cores_busy() {
    awk -v c="$1" -v w="$2" 'BEGIN { printf "%.2f", (w > 0 ? c / w : 0) }'
}
# Jobs beside the stages (`beside NAME -- COMMAND...`), each in a session of
# its own (setsid: stopped as a whole by its process group), sharing the
# cores with the stages as an equal: Linux's autogroup (on where
# /proc/sys/kernel/sched_autogroup_enabled is 1, as on this project's
# machines) gives each session an equal share, so a nice value inside a job
# would not lower it; a job lowered below the stages (its autogroup at nice
# 19) was measured slower overall, the idle share between test binaries
# coming in slivers too short for it (docs/benchmarks.md, "CI time"). Their
# output, exit code, wall and CPU time in $jobs_dir/NAME.{log,rc,s,cpu}
# (spaces as dashes). A job's failure fails the run at the end of the stage
# during which it finished (its output printed), or at the latest when it
# is waited for; a run that stops early stops them, except the installs,
# which it waits for.
declare -A job_pid=() job_t0=()
job_file() { local n=${1// /-}; echo "$jobs_dir/$n.$2"; }
beside() {
    local name=$1
    shift 2
    # an earlier run's result must not stand for this one's
    rm -f "$(job_file "$name" rc)" "$(job_file "$name" s)" "$(job_file "$name" cpu)" "$(job_file "$name" log)"
    (
        t0=$SECONDS rc=0
        setsid "$@" > "$(job_file "$name" log)" 2>&1 &
        pid=$!
        trap 'kill -- -"$pid" 2>/dev/null; exit 143' TERM
        wait "$pid" || rc=$?
        echo $((SECONDS - t0)) > "$(job_file "$name" s)"
        children_cpu "$BASHPID" > "$(job_file "$name" cpu)"
        echo "$rc" > "$(job_file "$name" rc)"
    ) &
    job_pid[$name]=$!
    job_t0[$name]=$SECONDS
}
# A finished job's result (`job_check NAME`), or the job waited for
# (`job_check NAME wait`); every job after each stage (`jobs_check`).
job_check() {
    local name=$1 pid=${job_pid[$1]:-} rc wall cpu t_wait=$SECONDS
    [ -n "$pid" ] || return 0
    if [ "${2:-}" != wait ] && kill -0 "$pid" 2>/dev/null; then
        return 0
    fi
    wait "$pid" || true
    unset "job_pid[$name]"
    rc=$(cat "$(job_file "$name" rc)" 2>/dev/null || echo 1)
    wall=$(cat "$(job_file "$name" s)" 2>/dev/null || echo 0)
    cpu=$(cat "$(job_file "$name" cpu)" 2>/dev/null || echo 0)
    times+=("$(printf '%-28s %5d s   CPU %5d s (%s cores busy)   beside the stages, from %d s into the run' \
        "$name" "$wall" "$cpu" "$(cores_busy "$cpu" "$wall")" "${job_t0[$name]}")")
    [ $((SECONDS - t_wait)) -lt 1 ] || times+=("$(printf '%-28s %5d s' "  (waited for it)" $((SECONDS - t_wait)))")
    if [ "$rc" != 0 ]; then
        cat "$(job_file "$name" log)" >&2
        times+=("  (failed: exit $rc)")
        exit "$rc"
    fi
}
jobs_check() {
    local name
    for name in "${!job_pid[@]}"; do job_check "$name"; done
}
stage() {
    local name=$1
    shift
    local t0=$SECONDS rc=0 cpu wall
    rm -f "$jobs_dir/stage.cpu"
    (
        rc=0
        "$@" || rc=$?
        children_cpu "$BASHPID" > "$jobs_dir/stage.cpu"
        exit "$rc"
    ) || rc=$?
    wall=$((SECONDS - t0))
    cpu=$(cat "$jobs_dir/stage.cpu" 2>/dev/null || echo 0)
    # the disk left after each stage: a full disk fails the later stages
    # with errors that need not say so; the CPU time its processes used
    # (cores busy = CPU / wall; the jobs beside it not counted)
    times+=("$(printf '%-28s %5d s   CPU %5d s (%s cores busy)   disk free after: %s' "$name" "$wall" \
        "$cpu" "$(cores_busy "$cpu" "$wall")" \
        "$(df -h --output=avail . 2>/dev/null | tail -n 1 | tr -d ' ')")")
    if [ "$rc" != 0 ]; then
        times+=("  (failed: exit $rc)")
        exit "$rc"
    fi
    jobs_check
}
report() {
    local name
    for name in "${!job_pid[@]}"; do
        if [ "$name" = installs ]; then
            # never stopped mid-install (an interrupted dpkg leaves the
            # machine's packages half configured): waited for instead
            echo "test-all: waiting for the installs to finish before stopping" >&2
            wait "${job_pid[$name]}" 2>/dev/null || true
        else
            kill "${job_pid[$name]}" 2>/dev/null || true
        fi
    done
    echo "test-all: time by stage (wall clock, $(nproc) CPUs; whole run $SECONDS s)" >&2
    for t in "${times[@]}"; do echo "  $t" >&2; done
}
trap report EXIT
# What the tests need beyond the Rust toolchain (Debian packages: the
# validators and the process tests' peers; Python packages: the interop
# peers and the trainer's), installed where missing, beside the format
# check and the build, which need none of it: on a fresh machine the
# downloads cost no time of their own (scripts/install-test-deps.sh).
# Waited for before the first stage that needs them.
rustup component add rustfmt clippy >/dev/null 2>&1 || true
beside "installs" -- ./scripts/install-test-deps.sh
stage "cargo fmt --check" cargo fmt --all --check
# The lints, in their own target folder (cargo locks a build folder while
# its tests run): they type-check every crate, which shares nothing with
# the tests' optimised build (docs/benchmarks.md, "CI time").
beside "cargo clippy" -- env CARGO_TARGET_DIR="$clippy_dir" \
    cargo clippy --workspace --all-targets --locked -- -D warnings
# Every binary, once, in the tests' own profile (optimised, debug assertions
# on): the process tests (hil-tests: cli, daemon, stream, ...) and the
# training smoke test run these instead of building their own, and cargo
# test reuses every crate of this build (crates/workspace-hack keeps the
# features the same; hil-tests/tests/architecture.rs checks it): one build
# of the workspace in all (issue #52 point 7, CI's time).
stage "cargo build (binaries)" cargo build --profile test --locked --workspace --bins
export DBTOR_BIN_DIR="$target_dir/debug"
# the smoke test and the process tests need the installs
job_check "installs" wait
# The trainer (a few iterations on a small dataset, resumed, exported, and
# the export checked by the firmware's runtime) beside the test binaries:
# each leaves a share of the cores idle (1.3-1.8 of 2 busy), and it needs
# only the binaries above.
beside "training smoke test" -- ./training/smoke-test.sh
stage "cargo test" cargo test --workspace --locked
job_check "training smoke test" wait
cat "$(job_file "training smoke test" log)"
job_check "cargo clippy" wait
