#!/usr/bin/env bash
# The Debian packages the README's two commands (scripts/demo.sh, scripts/test.sh) need beyond bash and Python's
# own packages, installed with apt-get only when what they provide is missing (a second run only checks).
#   scripts/system_packages.sh build     a C and a C++ compiler (CMake's default project languages, which
#                                        `fmpy compile` uses), Python 3 with venv
#   scripts/system_packages.sh browser   Chromium and its driver (the HTML report test)
set -euo pipefail
PYTHON=${PYTHON:-python3}
missing=()
need() {  # need PROGRAM PACKAGE
    command -v "$1" >/dev/null 2>&1 || missing+=("$2")
}
case "${1:-build}" in
    build)
        need cc gcc
        need c++ g++
        if ! command -v "$PYTHON" >/dev/null 2>&1; then
            missing+=(python3 python3-venv)
        elif ! "$PYTHON" -c "import ensurepip, venv" 2>/dev/null; then
            missing+=(python3-venv)
        fi
        ;;
    browser)
        [ -x /usr/bin/chromium ] || missing+=(chromium)
        [ -x /usr/bin/chromedriver ] || missing+=(chromium-driver)
        ;;
    *)
        echo "usage: $0 build|browser" >&2
        exit 2
        ;;
esac
if [ ${#missing[@]} -gt 0 ]; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    $SUDO apt-get update
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y "${missing[@]}"
fi
