#!/usr/bin/env bash
# Continue the current training run (training/runs/CURRENT) on this machine:
# regenerate its datasets into the cache if missing (building host-sim if
# needed), restore its state from the repository, train to the time limit
# (SIGTERM/SIGINT stop it cleanly), write the state back and append the
# ledger line (training/LEDGER.md). Then commit training/runs/<name>/ and
# training/LEDGER.md. See training/README.md, "Runs kept in the repository".
#
#   ./scripts/train-continue.sh [--minutes M | --until HH:MM] [--threads T] [--device auto|cpu|cuda]
#                               [--cache DIR] [--host-sim BINARY] [--note TEXT] [--run NAME]
#   e.g. nice -n 19 ./scripts/train-continue.sh --minutes 120 --threads 1 --note "nice 19, beside builds"
#
# Needs training/requirements.txt installed (python3 -m pip install -r training/requirements.txt).
set -euo pipefail
cd "$(dirname "$0")/../training"
exec "${PYTHON:-python3}" -m dbtor.continue_run "$@"
