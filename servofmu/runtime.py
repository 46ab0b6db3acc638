"""What every stage takes from the machine it runs on: cores, memory, the clock, a C compiler, a cache folder,
temporary folders, and the one progress protocol of long-running library calls."""
from __future__ import annotations

import atexit
import contextlib
import datetime as _dt
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Callable, Iterator, Protocol, Sequence

from .errors import UserError

__all__ = ["Progress", "available_cores", "utc_now", "find_compiler", "compile_shared", "cache_dir",
           "CompileError", "compiler_signature", "CFLAGS", "make_temporary_folder", "temporary_folder",
           "remove_temporary_folders", "sweep_temporary_folders", "check_memory", "TEMPORARY_PREFIX",
           "signals_deferred", "unblock_signals", "optional_import", "show_warnings"]

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


# What a compiler says when it cannot write its output or temporary files, and the OS's reason.
_WRITE_FAILURES = {"File size limit exceeded": "File too large", "File too large": "File too large",
                   "No space left on device": "No space left on device"}


def compile_shared(sources: Sequence[Path], target: Path, include: Sequence[Path] = (),
                   extra_flags: Sequence[str] = (), what: str = "") -> None:
    """Compile C ``sources`` into the shared library ``target`` (flags :data:`CFLAGS` plus ``extra_flags``)."""
    cc = find_compiler()
    cmd = [*cc.split(), *CFLAGS, *extra_flags, *[f"-I{d}" for d in include], *map(str, sources),
           "-o", str(target), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    for symptom, reason in _WRITE_FAILURES.items():  # the compiler could not write: the disk's fault, not the code's
        if proc.returncode != 0 and symptom in proc.stderr:
            raise CompileError(f"cannot write {target} ({what or 'compiled code'}): {reason}")
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


# ---------------------------------------------------------------------------
# Temporary folders
# ---------------------------------------------------------------------------
# Every temporary folder servofmu makes is named servofmu-PID-PURPOSE-XXXXXXXX in the system's temporary
# directory and registered here: removed when the work is done, when the process exits (also by SIGTERM or
# Ctrl-C, which the command line turns into exceptions), by a worker's signal handler, and — for a process that
# was killed with SIGKILL and could not clean up — by the next servofmu command (sweep_temporary_folders).
TEMPORARY_PREFIX = "servofmu-"
_folders: set[str] = set()


def _temporary_root() -> str | None:
    """$TMPDIR as given (None: tempfile's choice, which probes by writing a file and, when the disk is full,
    names no reason)."""
    return tempfile.tempdir or os.environ.get("TMPDIR") or None


def make_temporary_folder(purpose: str) -> Path:
    """A new temporary folder, removed at the latest when this process exits (see :func:`temporary_folder`)."""
    root = _temporary_root()
    try:
        path = tempfile.mkdtemp(prefix=f"{TEMPORARY_PREFIX}{os.getpid()}-{purpose}-", dir=root)
    except OSError as exc:
        raise UserError(f"cannot make a temporary folder in {root or 'the temporary directory'}: "
                        f"{exc.strerror or exc}") from exc
    _folders.add(path)
    return Path(path)


def remove_temporary_folders(*paths: str | Path) -> None:
    """Remove the given temporary folders (default: every one this process made and has not removed yet)."""
    for path in [str(p) for p in paths] if paths else list(_folders):
        shutil.rmtree(path, ignore_errors=True)
        _folders.discard(path)


@contextlib.contextmanager
def temporary_folder(purpose: str) -> Iterator[Path]:
    """``with temporary_folder("build") as path``: a temporary folder for the block, removed however it ends."""
    path = make_temporary_folder(purpose)
    try:
        yield path
    finally:
        remove_temporary_folders(path)


atexit.register(remove_temporary_folders)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def sweep_temporary_folders() -> None:
    """Remove the temporary folders of servofmu processes that no longer run (killed with SIGKILL)."""
    root = Path(_temporary_root() or tempfile.gettempdir())
    try:
        entries = list(root.iterdir())
    except OSError:
        return
    for entry in entries:
        parts = entry.name.split("-")
        if entry.name.startswith(TEMPORARY_PREFIX) and len(parts) > 2 and parts[1].isdigit() \
                and int(parts[1]) != os.getpid() and not _alive(int(parts[1])) and entry.is_dir():
            shutil.rmtree(entry, ignore_errors=True)


# ---------------------------------------------------------------------------
# Signals
# ---------------------------------------------------------------------------
@contextlib.contextmanager
def signals_deferred(signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)) -> Iterator[None]:
    """A block that a stop signal must not cut in half: starting worker processes (one stopped halfway through
    reading its start-up data prints a traceback).  Python-level handlers of ``signals`` run when the block ends,
    as if the signal had come then; outside the main thread, or where a signal is not handled by Python, nothing
    changes.  The signals are also blocked in this thread, and so in the processes and threads it starts: a
    worker unblocks them once its own handlers are set (see :func:`unblock_signals`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[tuple[int, object]] = []
    previous = {s: h for s in signals if callable(h := signal.getsignal(s))}
    for s in previous:
        signal.signal(s, lambda signum, frame: caught.append((signum, frame)))
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        for s, handler in previous.items():
            signal.signal(s, handler)
        if caught:
            signum, frame = caught[0]
            previous[signum](signum, frame)


def unblock_signals(signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)) -> None:
    """In a process started inside :func:`signals_deferred`: take the stop signals again (set handlers first)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, signals)


# ---------------------------------------------------------------------------
# Memory
# ---------------------------------------------------------------------------
def _memory_bytes() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(what: str, needed: float, how: str) -> None:
    """Refuse up front work whose memory estimate ``needed`` (bytes) exceeds half of this machine's memory:
    one line with the estimate, instead of a MemoryError (or the kernel's OOM killer) partway through.  ``how``
    says how to make the work smaller."""
    total = _memory_bytes()
    if total is not None and needed > total / 2:
        raise UserError(f"{what} needs about {_bytes(needed)} of memory, more than half of this machine's "
                        f"{_bytes(total)}; {how}")


def _bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"


# ---------------------------------------------------------------------------
# Optional dependencies and warnings
# ---------------------------------------------------------------------------
def optional_import(module: str, what: str, extra: str, package: str | None = None):
    """``module`` imported, or a UserError naming what needs it and the extra of servofmu that installs it:
    ``a Dask scheduler needs dask: pip install 'servofmu[dask]'``.  ``package``: the distribution's name where it
    differs from the extra's (python-control)."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise UserError(f"{what} needs {package or extra}: pip install 'servofmu[{extra}]'") from exc


@contextlib.contextmanager
def show_warnings(warn: Callable[[str], None] | None = None) -> Iterator[None]:
    """The command line's display of warnings (the library's, ``warnings.warn`` with ServofmuWarning, and those of
    the libraries it calls): within the block each is one line, its message's first line, without the category,
    file and source line of Python's default display.  ``warn(text)`` shows it (a progress bar's, which keeps the
    bar below); default ``warning: TEXT`` on stderr.  Which warnings show is left to the filters (a warning
    repeated at the same place shows once)."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = (str(message).strip().splitlines() or [category.__name__])[0]
        if warn is not None:
            warn(text)
        else:
            print(f"warning: {text}", file=file or sys.stderr)

    previous, warnings.showwarning = warnings.showwarning, show
    try:
        yield
    finally:
        warnings.showwarning = previous
