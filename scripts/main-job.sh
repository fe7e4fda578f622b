#!/usr/bin/env bash
# The main job. Until the firmware pipeline exists (see README, "Status"), this
# runs the most complete path that does, in release mode:
#  1. the firmware's self-test of the shipped geometry and projector at the
#     paper's full geometry (adjointness, analytic slab line integrals, norm);
#  2. a simulated acquisition of test-set phantoms (procedural breasts, Poisson
#     noise) reconstructed with the MLTR and FBP baselines and scored against
#     the truth, at the paper geometry binned x4 so it takes seconds
#     (`dbt-eval baselines` without flags is the full-size evaluation).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -q -p dbtor-firmware -p dbt-eval
./target/release/dbtor-diag selftest "$@"
./target/release/dbt-eval baselines --binning 4 --phantoms 2 --slices 2 \
    --json eval/results/main-job-baselines.json
