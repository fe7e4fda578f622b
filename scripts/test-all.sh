#!/usr/bin/env bash
# The one command that runs every test: formatting, lints, and the whole
# workspace's test suite. `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
cargo test --workspace --locked
