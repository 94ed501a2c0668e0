#!/usr/bin/env bash
# Set up zipon on a fresh machine: system packages, a venv in .venv, the project with its test, bench and docs extras.
# Usage: ./setup.sh            (then: .venv/bin/zipon demo)
set -euo pipefail
cd "$(dirname "$0")"

if command -v apt-get >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  # libusb: open3d imports fail without it; libgomp: opencv/open3d runtime;
  # chromium: renders the evaluation report to PNG (tests and `zipon eval` checks).
  if ! dpkg -s libusb-1.0-0 libgomp1 chromium >/dev/null 2>&1; then
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
      libusb-1.0-0 libgomp1 chromium >/dev/null
  fi
fi

PY=${PYTHON:-python3}
# build tools (meson for scikit-fmm) are looked up on PATH
export PATH="$PWD/.venv/bin:$PATH"
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip setuptools wheel
# scikit-fmm builds from source and does not declare its numpy build dependency.
.venv/bin/python -m pip install -q "numpy>=1.26,<3" meson-python meson ninja
.venv/bin/python -m pip install -q --no-build-isolation scikit-fmm
.venv/bin/python -m pip install -q -e ".[test,bench,docs]"
# DVC: never phone home.
export DVC_NO_ANALYTICS=1
echo "zipon installed in .venv — try: .venv/bin/zipon --help"
