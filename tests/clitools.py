"""Running `servofmu` in a fresh process, as a user does, and checking its one-line errors."""
import os
import subprocess
import sys


def run(*args, cwd=None, env=None) -> subprocess.CompletedProcess:
    """``python -m servofmu ARGS`` with stdout and stderr captured."""
    return subprocess.run([sys.executable, "-m", "servofmu", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, **(env or {})})


def assert_one_line_error(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    """The command failed as a user error should: exit status 2, one stderr line holding every fragment, no
    traceback."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
