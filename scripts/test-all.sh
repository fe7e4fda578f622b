#!/usr/bin/env bash
# The one command that runs every test: formatting, lints, and the whole
# workspace's test suite. `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings
cargo test --workspace --locked
# The trainer: a few iterations on a small dataset, resumed, exported, and the
# export checked by the firmware's runtime (needs training/requirements.txt).
if ! python3 -c 'import torch, onnx, onnxruntime' 2>/dev/null; then
    echo "training smoke test: PyTorch/onnx/onnxruntime missing; pip install -r training/requirements.txt (.ci/run does)" >&2
    exit 1
fi
./training/smoke-test.sh
