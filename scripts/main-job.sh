#!/usr/bin/env bash
# The main job. Until the acquisition pipeline exists (see README, "Status"),
# this runs the most complete path that does: the firmware's self-test of the
# shipped geometry and projector (adjointness, analytic slab line integrals,
# operator norm) at the paper's full geometry, in release mode.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo run --release --locked -q -p dbtor-firmware --bin dbtor-diag -- selftest "$@"
