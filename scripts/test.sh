#!/usr/bin/env bash
# Run the test suite in .venv (after scripts/setup.sh). Installs Chromium for the report test when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
# tests/test_report.py opens a report in headless Chromium through Debian's chromium-driver (never a downloaded one)
bash scripts/system_packages.sh browser
export PATH="$PWD/.venv/bin:$PATH"  # the venv's cmake for `fmpy compile`
exec .venv/bin/python -m pytest -q "$@"
