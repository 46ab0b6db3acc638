#!/usr/bin/env bash
# The README's demo command: sets everything up (scripts/setup.sh), then `servofmu demo` (arguments go to it).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/servofmu demo "$@"
