#!/usr/bin/env bash
# The README's test command: sets everything up (scripts/setup.sh: Debian packages when missing, .venv, servofmu
# with its test tools), then runs the test suite; arguments go to pytest.  Needs only bash on a Debian machine.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# tests/test_report.py opens a report in headless Chromium through Debian's chromium-driver (never a downloaded one)
bash scripts/system_packages.sh browser
export PATH="$PWD/.venv/bin:$PATH"  # the venv's cmake for `fmpy compile`
# one pytest process per core, at most four (each holds its own compiled simulators and fixtures): on 2 cores the
# suite takes about half its time in one process; the slowest 20 tests: where the 15-minute budget goes
workers=$(nproc 2>/dev/null || echo 1)
exec .venv/bin/python -m pytest -q -n "$(( workers < 4 ? workers : 4 ))" --durations=20 "$@"
