"""What every stage takes from the machine it runs on: cores, the clock, a C compiler, a cache folder, and the
one progress protocol of long-running library calls."""
from __future__ import annotations

import datetime as _dt
import os
import shutil
import subprocess
from pathlib import Path
from typing import Protocol, Sequence

from .errors import UserError

__all__ = ["Progress", "available_cores", "utc_now", "find_compiler", "compile_shared", "cache_dir",
           "CompileError", "compiler_signature", "CFLAGS"]

# Flags of every shared library servofmu compiles (FMU binaries and the batch simulator).
CFLAGS = ("-shared", "-fPIC", "-O2", "-std=c99")


class Progress(Protocol):
    """``progress(done, total)``: called by long-running library functions as work finishes.

    ``done`` and ``total`` count the function's own units (experiments, plants, epochs, iterations);
    ``total`` may grow while the work runs.  The command line draws a progress bar from it; the library
    never prints.
    """

    def __call__(self, done: int, total: int, /) -> None: ...


class CompileError(UserError):
    """The C compiler is missing or failed."""


def available_cores() -> int:
    """The number of CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def utc_now() -> str:
    """The current time for provenance: ISO 8601, UTC, to the second (``2026-01-31T12:00:00Z``)."""
    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0)
    return now.isoformat().replace("+00:00", "Z")


def find_compiler() -> str:
    """The C compiler command: $CC, else cc, gcc or clang on the PATH."""
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if not cc or not shutil.which(cc.split()[0]):
        raise CompileError(f"no C compiler found ({'CC=' + cc if cc else 'looked for cc, gcc and clang'}); "
                           "install gcc or set CC")
    return cc


def compile_shared(sources: Sequence[Path], target: Path, include: Sequence[Path] = (),
                   extra_flags: Sequence[str] = (), what: str = "") -> None:
    """Compile C ``sources`` into the shared library ``target`` (flags :data:`CFLAGS` plus ``extra_flags``)."""
    cc = find_compiler()
    cmd = [*cc.split(), *CFLAGS, *extra_flags, *[f"-I{d}" for d in include], *map(str, sources),
           "-o", str(target), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        first = next((line for line in proc.stderr.splitlines() if "error" in line), proc.stderr.strip()[:300])
        raise CompileError(f"C compiler {cc} failed{' on ' + what if what else ''}: {first}")


def compiler_signature(extra_flags: Sequence[str] = ()) -> str:
    """The compiler command and flags, and the size and date of the compiler's program, for cache keys of compiled
    code (an upgraded compiler builds anew)."""
    cc = find_compiler()
    program = os.path.realpath(shutil.which(cc.split()[0]))
    stat = os.stat(program)
    return " ".join([cc, *CFLAGS, *extra_flags, f"({program} {stat.st_size} {stat.st_mtime_ns})"])


def cache_dir() -> Path:
    """Where compiled libraries are kept: $SERVOFMU_CACHE, else $XDG_CACHE_HOME/servofmu (~/.cache/servofmu)."""
    if os.environ.get("SERVOFMU_CACHE"):
        return Path(os.environ["SERVOFMU_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "servofmu"
