#!/usr/bin/env bash
# Create .venv and install servofmu with its test tools. Idempotent: a second run only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
PYTHON="$PYTHON" bash scripts/system_packages.sh build  # C/C++ compilers, venv (apt-get when missing)
if [ ! -x .venv/bin/python ]; then
    "$PYTHON" -m venv .venv
fi
# The CPU build of torch first: an unpinned torch would pull several GB of CUDA packages.
if ! .venv/bin/python -c "import torch" 2>/dev/null; then
    .venv/bin/pip install --quiet "torch==2.13.0"
fi
.venv/bin/pip install --quiet -e ".[test]"
