"""What every stage takes from the machine it runs on: cores, memory, the clock, a C compiler, a cache folder,
temporary folders, the one progress protocol and the one options object of long-running library calls, and the
life of a command: stop signals, exit statuses, the quick exit."""
from __future__ import annotations

import atexit
import contextlib
import datetime as _dt
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Protocol, Sequence

from .errors import UserError
from .locks import is_abandoned, take

__all__ = ["Progress", "available_cores", "utc_now", "find_compiler", "compile_shared", "cache_dir",
           "CompileError", "compiler_signature", "CFLAGS", "make_temporary_folder", "temporary_folder",
           "remove_temporary_folders", "sweep_temporary_folders", "check_memory", "check_work", "check_work_limit", "WORK_LIMIT_HOURS", "TEMPORARY_PREFIX",
           "signals_deferred", "unblock_signals", "RunOptions", "EXIT_USER_ERROR", "STOP_SIGNALS", "Terminated",
           "stop_if_asked", "CommandRun", "run_command", "finish",
           "optional_import", "show_warnings"]

# Flags of every shared library servofmu compiles (FMU binaries and the batch simulator).
CFLAGS = ("-shared", "-fPIC", "-O2", "-std=c99")


class Progress(Protocol):
    """``progress(done, total)``: called by long-running library functions as work finishes.

    ``done`` and ``total`` count the function's own units (experiments, plants, epochs, iterations);
    ``total`` may grow while the work runs.  The command line draws a progress bar from it; the library
    never prints.
    """

    def __call__(self, done: int, total: int, /) -> None: ...


@dataclass(frozen=True)
class RunOptions:
    """How a long library call runs, as opposed to what it computes: one object for every such call (measure,
    make_training_set, train_from_file, identify_files, import_records, ...).

    ``workers``: local worker processes (None: one per core; 0: this process); ``scheduler``: a Dask scheduler
    address (tcp://HOST:PORT) instead; ``resume``: continue an existing output where an interrupted run stopped;
    ``overwrite``: replace an existing output (without either, an existing output is refused: fileio.claim_output);
    ``progress``: the :class:`Progress` callback; ``command``: the command line, recorded as provenance."""

    workers: int | None = None
    scheduler: str | None = None
    resume: bool = False
    overwrite: bool = False
    progress: Progress | None = None
    command: str = ""

    def report(self, done: int, total: int) -> None:
        """Call ``progress`` when there is one."""
        if self.progress is not None:
            self.progress(done, total)


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
# directory, holds its owner's claim (OWNER_LOCK, servofmu.locks) and is registered here: removed when the work is
# done, when the process exits (also by SIGTERM or Ctrl-C, which the command line turns into exceptions), by a
# worker's signal handler, and — for a process that was killed with SIGKILL and could not clean up — by the next
# servofmu command (sweep_temporary_folders), which removes a folder only when nobody holds its claim: a process
# ID cannot tell that, since another container may share the temporary directory but not the process table.
TEMPORARY_PREFIX = "servofmu-"
OWNER_LOCK = ".owner.lock"
LOCKLESS_AGE = 3600.0  # s: a folder without a claim (made by an older servofmu) is swept only after this
_folders: dict[str, int] = {}  # path -> the file descriptor that holds its claim


def _temporary_root() -> str | None:
    """$TMPDIR as given (None: tempfile's choice, which probes by writing a file and, when the disk is full,
    names no reason)."""
    return tempfile.tempdir or os.environ.get("TMPDIR") or None


def make_temporary_folder(purpose: str) -> Path:
    """A new temporary folder, removed at the latest when this process exits (see :func:`temporary_folder`)."""
    root = _temporary_root()
    try:
        # made under a hidden name, claimed, then shown by one rename: a sweep never sees it unclaimed
        hidden = Path(tempfile.mkdtemp(prefix=f".{TEMPORARY_PREFIX}{os.getpid()}-{purpose}-", dir=root))
        fd = take(hidden / OWNER_LOCK)
        path = str(hidden.with_name(hidden.name[1:]))
        os.rename(hidden, path)
    except OSError as exc:
        raise UserError(f"cannot make a temporary folder in {root or 'the temporary directory'}: "
                        f"{exc.strerror or exc}") from exc
    _folders[path] = fd
    return Path(path)


def remove_temporary_folders(*paths: str | Path) -> None:
    """Remove the given temporary folders (default: every one this process made and has not removed yet)."""
    for path in [str(p) for p in paths] if paths else list(_folders):
        shutil.rmtree(path, ignore_errors=True)
        fd = _folders.pop(path, None)
        if fd is not None:
            os.close(fd)  # the claim last: nobody sweeps a folder while its owner still removes it


@contextlib.contextmanager
def temporary_folder(purpose: str) -> Iterator[Path]:
    """``with temporary_folder("build") as path``: a temporary folder for the block, removed however it ends."""
    path = make_temporary_folder(purpose)
    try:
        yield path
    finally:
        remove_temporary_folders(path)


atexit.register(remove_temporary_folders)


def _abandoned(folder: Path) -> bool:
    """Whether a temporary folder of servofmu's is provably abandoned: its claim is held by nobody, or (made by an
    older servofmu, without a claim) its process is gone and it has not changed for LOCKLESS_AGE."""
    lock = folder / OWNER_LOCK
    if lock.exists():
        return is_abandoned(lock)
    pid = folder.name.split("-")[1]
    try:
        age = time.time() - folder.stat().st_mtime
    except OSError:
        return False
    return pid.isdigit() and not _alive(int(pid)) and age > LOCKLESS_AGE


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def sweep_temporary_folders() -> None:
    """Remove the temporary folders of servofmu processes that ended without removing them (killed with
    SIGKILL)."""
    root = Path(_temporary_root() or tempfile.gettempdir())
    try:
        entries = list(root.iterdir())
    except OSError:
        return
    for entry in entries:
        if entry.name.startswith(TEMPORARY_PREFIX) and str(entry) not in _folders and entry.name.count("-") > 2 \
                and entry.is_dir() and _abandoned(entry):
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


# The hours of computing a command's searches may be estimated at before it is refused (--work-limit raises it): a
# night's run; the defaults of every command estimate at minutes
WORK_LIMIT_HOURS = 8.0


def check_work(what: str, seconds: float, limit_hours: float, how: str) -> None:
    """Refuse up front a search whose time estimate ``seconds`` (its evaluations times the measured time of one)
    exceeds ``limit_hours``: one line with the estimate and how to make it smaller, instead of a run of days."""
    check_work_limit(limit_hours)
    if seconds > 3600 * limit_hours:
        raise UserError(f"{what} would take about {_duration(seconds)} on this machine, beyond --work-limit "
                        f"{limit_hours:g} h: {how}, or raise --work-limit")


def check_work_limit(hours: float) -> None:
    """Refuse a work limit that is not a positive number of hours."""
    if not (isinstance(hours, (int, float)) and not isinstance(hours, bool) and 0 < hours < math.inf):
        raise UserError(f"--work-limit must be a positive number of hours, not {hours!r}")


def _duration(seconds: float) -> str:
    for unit, size in (("years", 3.15e7), ("days", 86400.0), ("hours", 3600.0), ("minutes", 60.0)):
        if seconds >= size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


def _bytes(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"


# ---------------------------------------------------------------------------
# The life of a command
# ---------------------------------------------------------------------------
# A UserError (or an OSError) ends a command with one line and exit status 2; no traceback.  Ctrl-C (exit 130) and
# SIGTERM or SIGHUP (exit 128 + the signal's number) end it the same way, after the same clean-up: temporary
# folders removed, worker processes stopped, no partial output left.
EXIT_USER_ERROR = 2
STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)  # what `timeout`, systemd, batch schedulers and a closed terminal send


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP: unwinds like Ctrl-C, so that the same clean-up runs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


_stop_signals: list[int] = []  # the signal that asked to stop, kept: see stop_if_asked


def _terminate(signum, frame) -> None:
    for s in STOP_SIGNALS:  # once: the clean-up is not interrupted by a second signal
        signal.signal(s, signal.SIG_IGN)
    _stop_signals.append(signum)
    raise Terminated(signum)


def _interrupt(signum, frame) -> None:
    """Ctrl-C, as Python's own handler, but kept for stop_if_asked."""
    _stop_signals.append(signum)
    raise KeyboardInterrupt


def stop_if_asked(*_) -> None:
    """Raise again if a stop signal came: the handler's exception is lost when the signal arrives while Python runs
    a finaliser or a weakref callback (garbage collection), which swallow exceptions.  Progress callbacks call it."""
    if _stop_signals:
        raise KeyboardInterrupt if _stop_signals[0] == signal.SIGINT else Terminated(_stop_signals[0])


def _raise_soon(unraisable) -> None:
    """``sys.unraisablehook`` while a command runs.  A stop signal's exception raised inside a finaliser is dropped
    by Python (with a traceback on stderr): raise it again a millisecond later, in ordinary code (SIGALRM runs
    :func:`stop_if_asked`), instead."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and _stop_signals:
        signal.setitimer(signal.ITIMER_REAL, 0.001)
    else:
        sys.__unraisablehook__(unraisable)


@dataclass
class CommandRun:
    """One command being run: ``who`` names it in its error line (``servofmu measure``), ``quick_exit`` says that
    the process may skip the interpreter's teardown once it succeeded (see :func:`finish`), ``message`` is the
    line to print on stderr when it ended otherwise than by success."""

    who: str
    quick_exit: bool = False
    message: str = ""


def run_command(run: CommandRun, work: Callable[[CommandRun], None]) -> int:
    """``work(run)`` with the stop signals turned into exceptions, and its end turned into an exit status: 0, or
    :data:`EXIT_USER_ERROR` for a UserError, OSError or MemoryError, 130 for Ctrl-C, 128 + n for signal n; ``run.message`` then
    holds the one line to print.  ``work`` may rename ``run.who`` once it knows the command."""
    from .claims import OutputExists

    _stop_signals.clear()  # the handlers first: Ctrl-C while the modules load is one line too
    handlers = {s: signal.signal(s, _terminate) for s in STOP_SIGNALS}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not where Ctrl-C is ignored
        handlers[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupt)
    handlers[signal.SIGALRM] = signal.signal(signal.SIGALRM, stop_if_asked)
    unraisablehook, sys.unraisablehook = sys.unraisablehook, _raise_soon
    try:
        work(run)
        stop_if_asked()
    except UserError as exc:
        text = exc.command_line_text() if isinstance(exc, OutputExists) else str(exc)
        run.message, run.quick_exit = f"{run.who}: error: {text}", False
        return EXIT_USER_ERROR
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        run.message, run.quick_exit = f"{run.who}: error: {where}{exc.strerror or exc}", False
        return EXIT_USER_ERROR
    except MemoryError:  # a limit the up-front estimates (check_memory) did not foresee: the machine's, not a bug
        run.message, run.quick_exit = (f"{run.who}: error: out of memory (a memory limit of this process or "
                                       "machine): ask for less work, or run it where more memory is free"), False
        return EXIT_USER_ERROR
    except BaseException as exc:  # a stop signal, or what it caused (a module interrupted while it loaded)
        if not isinstance(exc, KeyboardInterrupt) and not (_stop_signals and isinstance(exc, Exception)):
            raise
        run.quick_exit = False
        return _stopped(run, exc)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        sys.unraisablehook = unraisablehook
        for s, handler in handlers.items():
            signal.signal(s, handler)
    return 0


def _stopped(run: CommandRun, exc: BaseException) -> int:
    signum = exc.signum if isinstance(exc, Terminated) else _stop_signals[0] if _stop_signals else signal.SIGINT
    if signum == signal.SIGINT:
        # Ctrl-C inside code that exec() runs from a string (dataclasses makes methods so while modules load)
        # marks the interpreter as ended by Ctrl-C, and it would kill itself with SIGINT at its exit instead
        # of returning 130; the next exec() of a string that ends normally clears the mark.
        exec("")
        run.message = f"{run.who}: interrupted"
        return 130
    run.message = f"{run.who}: terminated ({signal.Signals(signum).name})"
    return 128 + signum


def finish(code: int, quick_exit: bool = False) -> None:
    """End the process with ``code``.  With ``quick_exit`` (a command that succeeded and asked for it), the
    interpreter's teardown (tens of milliseconds spent freeing numpy, h5py and the compiled libraries, a tenth of
    a quick identify) is skipped when nothing is left to finish: every file servofmu writes is complete and closed
    when the command returns (servofmu.fileio), and no other thread or process runs."""
    multiprocessing = sys.modules.get("multiprocessing")
    if code == 0 and quick_exit and threading.active_count() == 1 and not (
            multiprocessing and multiprocessing.active_children()):
        try:
            remove_temporary_folders()
            sys.stdout.flush()
            sys.stderr.flush()
        except OSError:  # (a closed pipe): the ordinary exit reports it
            sys.exit(code)
        os._exit(code)
    sys.exit(code)


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
