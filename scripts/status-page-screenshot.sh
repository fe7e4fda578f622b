#!/usr/bin/env bash
# docs/figures/status-page.png: the daemon's status page as headless chromium
# renders it in the status page test (hil-tests/tests/status_page.rs: three
# test-set breasts through the daemon with the shipped model, one cut stream).
# Needs Debian's chromium and dcmtk (scripts/install-test-deps.sh installs them).
set -euo pipefail
cd "$(dirname "$0")/.."
DBTOR_STATUS_SCREENSHOT="$PWD/docs/figures/status-page.png" \
    cargo test --locked -q -p hil-tests --test hil status_page::
echo "wrote docs/figures/status-page.png"
