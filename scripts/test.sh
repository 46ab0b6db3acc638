#!/usr/bin/env bash
# Run the test suite in .venv (after scripts/setup.sh). Installs Chromium for the report test when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH="$PWD/.venv/bin:$PATH"  # the venv's cmake for `fmpy compile`
exec .venv/bin/python -m pytest -q "$@"
