#!/usr/bin/env bash
# CI (.ci/run, after the test suite): servofmu as a user installs it.  Builds the wheel from this checkout, installs
# it with no extras in a fresh virtual environment outside the checkout (torch's CPU build first, as the README's
# "pip install" section says), and in an empty folder runs `servofmu demo` to its end and the README's tour, then
# checks what a default install must and must not bring: no dask, no python-control, no torch behind
# `servofmu --help`, the extras named by the features that need them, py.typed shipped.
#
# PYTHON picks the interpreter (default python3); KEEP=1 keeps the work folder (its path is printed).
# Arguments go to `servofmu demo` (e.g. --out).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
PYTHON=${PYTHON:-python3}
TORCH=${TORCH:-torch==2.13.0}  # the build scripts/setup.sh installs: CPU-only where the index serves it
WORK=$(mktemp -d "${TMPDIR:-/tmp}/servofmu-install-check.XXXXXX")
if [ "${KEEP:-}" = 1 ]; then echo "work folder: $WORK"; else trap 'rm -rf "$WORK"' EXIT; fi

step() { printf '\n== %s\n' "$*"; }
fail() { echo "check_install: FAILED: $*" >&2; exit 1; }

step "wheel"
"$PYTHON" -m venv "$WORK/venv"
PY="$WORK/venv/bin/python"
"$PY" -m pip install --quiet --upgrade pip
# an isolated build, as pip builds any source tree (its log shown only when it fails)
"$PY" -m pip wheel --quiet --no-deps -w "$WORK/dist" "$ROOT" > "$WORK/wheel.log" 2>&1 \
    || { cat "$WORK/wheel.log"; fail "wheel"; }
WHEEL=$(ls "$WORK"/dist/servofmu-*.whl)
echo "$(basename "$WHEEL")"

step "pip install $TORCH, then the wheel (no extras)"
"$PY" -m pip install --quiet "$TORCH"
"$PY" -m pip install --quiet "$WHEEL"
"$PY" -m pip check
export PATH="$WORK/venv/bin:$PATH"
unset PYTHONPATH VIRTUAL_ENV
mkdir "$WORK/run"
cd "$WORK/run"  # nothing of the checkout in sight
"$PY" - <<'EOF'
import importlib.resources, importlib.util, sys
import servofmu
assert "site-packages" in servofmu.__file__, servofmu.__file__
assert importlib.resources.files("servofmu").joinpath("py.typed").is_file(), "py.typed missing"
for extra in ("dask", "distributed", "control"):
    assert importlib.util.find_spec(extra) is None, f"{extra} came with the default install"
print(f"servofmu {servofmu.__version__} from {servofmu.__file__}; no dask, no python-control")
EOF

step "servofmu --help and identify --help load no torch"
servofmu --help > /dev/null
for argv in "--help" "identify --help" "validate --help" "export --help"; do
    # shellcheck disable=SC2086
    if "$PY" -X importtime -m servofmu $argv 2>&1 >/dev/null | grep -qE '\| +(torch|dask|distributed|control)$'; then
        fail "servofmu $argv imports torch, dask or python-control"
    fi
done
echo "ok"

step "servofmu demo $*"
start=$(date +%s)
servofmu demo "$@" || fail "servofmu demo exited with $?"
echo "demo: $(( $(date +%s) - start )) s"

step "the README's tour"
"$PY" - "$ROOT/README.md" <<'EOF'
import shlex, subprocess, sys, time
text = open(sys.argv[1]).read()
tour = text.split("## A five-minute tour", 1)[1].split("```console", 1)[1].split("```", 1)[0]
commands = [shlex.split(line[2:]) for line in tour.splitlines() if line.startswith("$ servofmu ")]
assert len(commands) >= 8, commands
for argv in commands:
    start = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True)
    print(f"{time.perf_counter() - start:6.1f} s  {shlex.join(argv)}")
    if proc.returncode != 0:
        sys.exit(f"check_install: FAILED: {shlex.join(argv)} exited with {proc.returncode}:\n{proc.stderr}")
EOF

step "the extras are named by what needs them"
out=$(servofmu measure g1.fmu --amplitudes 2 --frequencies 1 --scheduler tcp://127.0.0.1:9 -o dask.h5 2>&1) \
    && fail "measure --scheduler ran without dask"
echo "$out"
grep -q "needs dask: pip install 'servofmu\[dask\]'" <<<"$out" || fail "measure --scheduler does not name [dask]"
servofmu export g1-result.h5 --format control -o g1-control.json > /dev/null
out=$("$PY" -c "from servofmu.output.export import load_control; load_control('g1-control.json')" 2>&1) \
    && fail "load_control ran without python-control"
echo "$out" | tail -n 1
grep -q "pip install 'servofmu\[control\]'" <<<"$out" || fail "load_control does not name [control]"

step "installed"
du -sh "$WORK/venv" | cut -f1 | sed 's/^/virtual environment: /'
echo "check_install: all passed"
