#!/usr/bin/env bash
# What the tests need beyond the Rust toolchain, installed where missing:
# `scripts/test-all.sh` runs this beside the workspace's build (it needs
# the network and the disk, hardly the cores), so that the README's test
# command installs what it needs itself and a fresh machine's installs cost
# no time of their own (issue #52 point 7). Run alone it is idempotent: a
# machine that has everything only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
# DICOM validators of the report tests (dicom3tools: dciodvfy; dcmtk: dsrdump)
# and the peers of the hardware-in-the-loop tests (orthanc as the PACS, mbpoll
# as a third-party Modbus client, socat for pseudo-terminal pairs), and
# Debian's chromium: the headless browser of the status page test; PixelMed
# (libpixelmed-java, with a Java runtime): an SR validator independent of
# ours, for the dose SR's templates, run with Saxon-HE (libsaxonhe-java) as
# its XSLT processor, as PixelMed's own scripts do (faster than Xalan).
debian=(dicom3tools dcmtk orthanc mbpoll socat chromium libpixelmed-java libsaxonhe-java default-jre-headless)
if ! command -v dciodvfy >/dev/null 2>&1 || ! command -v dsrdump >/dev/null 2>&1 \
    || ! [ -x /usr/sbin/Orthanc ] || ! command -v mbpoll >/dev/null 2>&1 \
    || ! command -v socat >/dev/null 2>&1 || ! command -v chromium >/dev/null 2>&1 \
    || ! [ -f /usr/share/java/pixelmed.jar ] || ! [ -f /usr/share/java/Saxon-HE.jar ] \
    || ! command -v java >/dev/null 2>&1; then
    SUDO=""
    if [ "$(id -u)" != "0" ]; then
        if ! command -v sudo >/dev/null 2>&1; then
            echo "install-test-deps: Debian packages missing and neither root nor sudo: apt-get install ${debian[*]}" >&2
            exit 1
        fi
        # no password prompt: this runs beside the build, without a terminal
        SUDO="sudo -n"
    fi
    echo "install-test-deps: apt-get install ${debian[*]}"
    $SUDO apt-get update -qq
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${debian[@]}" >/dev/null
fi
pip_install() {
    python3 -m pip install --quiet --no-cache-dir --disable-pip-version-check -r "$1"
}
# Python peers of the interop tests (scikit-image metrics); pinned.
pip_install eval/peers/requirements.txt
# pymodbus: a third-party Modbus server for the firmware client's interop test;
# pydicom: the dose-registry walk of the dose SR (hil-tests/tests/openrem.rs).
pip_install hil-tests/peers/requirements.txt
# The trainer's smoke test (PyTorch from PyPI: the CUDA build, runs on CPU;
# about 5 GB installed).
pip_install training/requirements.txt
# What the smoke test imports, checked here so that a broken install is
# named now and not by the test an hour later.
if ! python3 -c 'import torch, onnx, onnxruntime' 2>/dev/null; then
    echo "install-test-deps: PyTorch/onnx/onnxruntime do not import after pip install -r training/requirements.txt" >&2
    exit 1
fi
