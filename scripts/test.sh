#!/usr/bin/env bash
# The README's test command: sets everything up (scripts/setup.sh: Debian packages when missing, .venv, servofmu
# with its test tools), then runs the test suite; arguments go to pytest.  Needs only bash on a Debian machine.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# tests/test_report.py opens a report in headless Chromium through Debian's chromium-driver (never a downloaded one)
bash scripts/system_packages.sh browser
export PATH="$PWD/.venv/bin:$PATH"  # the venv's cmake for `fmpy compile`
exec .venv/bin/python -m pytest -q --durations=20 "$@"  # the slowest 20: where the 15-minute budget goes
