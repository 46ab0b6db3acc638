"""Run many independent tasks on local worker processes or on a Dask cluster, behind one interface.

    with Workers(scheduler=None, workers=None) as pool:
        for index, result in pool.imap(task, items, resource=WorkerResource(key, factory)):
            ...

``task(obj, item)`` is called once per item, in some worker; ``obj`` is what ``resource.factory()`` returned,
made once per worker (per worker thread) and reused by every task that runs there: the way to extract and
instantiate an FMU once and reset it between runs.  Results come back in completion order, with the
item's index.  Tasks, items, the factory and results must be picklable (module-level functions and
dataclasses); on a Dask cluster, servofmu must be installed on the workers.

- ``scheduler=None`` (default): ``workers`` local processes (default: one per CPU core);
  ``workers=0`` runs everything in this process, one task after the other.
- ``scheduler="tcp://HOST:PORT"``: the tasks run on the Dask distributed cluster behind that scheduler;
  the resource is sent to the workers once (scatter with broadcast).

A task may call :func:`report` to say how far it is (``Workers(on_report=...)`` receives it).  When the run
fails or is interrupted (Ctrl-C, SIGTERM), local workers are stopped at once, not waited for, and remove
their temporary folders.
"""
from __future__ import annotations

import ast
import linecache
import multiprocessing
import os
import signal
import sys
import threading
import time
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from ..errors import UserError
from ..runtime import (available_cores, optional_import, remove_temporary_folders, signals_deferred,
                       sweep_temporary_folders, unblock_signals)

__all__ = ["Workers", "WorkerResource", "report", "check_main_guard", "unguarded_main_line"]

REPORT_INTERVAL = 0.25  # s: how often the main process delivers what workers report()
STOP_TIMEOUT = 5.0  # s a worker gets to end on SIGTERM before it is killed


@dataclass(frozen=True)
class WorkerResource:
    """Something expensive every task in a worker needs (an instantiated FMU): made by ``factory()`` once
    per worker thread and cached under ``key``."""

    key: str
    factory: Callable[[], Any]


_local = threading.local()
# Where report() delivers: the main process's queue in a local worker, the Workers' callback when the tasks run in
# the process that made the Workers, nothing on a Dask cluster.
_report_to: Callable | None = None


def report(*message) -> None:
    """Tell the process that runs the tasks how far this task is: delivered as ``on_report(*message)`` of the
    :class:`Workers` (local processes and this process; a no-op on a Dask cluster).  Messages must be picklable
    and should be rare (a few per second)."""
    if _report_to is not None:
        _report_to(message)


def _resource(resource: WorkerResource | None):
    if resource is None:
        return None
    cache = getattr(_local, "objects", None)
    if cache is None:
        cache = _local.objects = {}
    if resource.key not in cache:
        cache[resource.key] = resource.factory()
    return cache[resource.key]


def _call(task, resource, item):
    return task(_resource(resource), item)


def _call_relaying_warnings(task, resource, item):
    """_call in a worker process: (result, the warnings it issued as (text, category)), for the main process to
    issue again — there the command line shows each as one line, where a worker would print Python's own
    two-line form (file, line and source) straight to the terminal."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        result = _call(task, resource, item)
    return result, [(str(w.message), w.category) for w in caught]


def _issue(relayed: list[tuple[str, type]]) -> None:
    for text, category in relayed:
        warnings.warn(text, category, stacklevel=2)


def _worker_setup(parent: int, reports) -> None:
    """How a local worker process ends: Ctrl-C is the main process's to handle (it stops the workers); SIGTERM
    (sent by the main process, or by anyone) and the death of the main process (killed with -9) end it at once,
    its temporary folders (extracted FMUs) removed first."""
    def leave(*_):
        remove_temporary_folders()
        os._exit(1)

    def watch():
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                leave()

    global _report_to
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, leave)
    unblock_signals()  # blocked while the main process started this one
    _report_to = reports.put if reports is not None else None
    threading.Thread(target=watch, daemon=True).start()


class Workers:
    """Local processes (default), this process (``workers=0``) or a Dask cluster (``scheduler``)."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 on_report: Callable | None = None):
        if workers is not None and workers < 0:
            raise UserError(f"workers must be 0 or more, not {workers}")
        self.scheduler = scheduler
        self.workers = available_cores() if workers is None else workers
        self.on_report = on_report  # receives what tasks send with report()
        self._reports = None
        self._client = None
        self._pool = None

    @property
    def description(self) -> str:
        """Where the work runs, in words (for progress lines)."""
        if self.scheduler:
            return f"Dask scheduler {self.scheduler}"
        return "this process" if self.workers == 0 else f"{self.workers} local worker processes"

    def __enter__(self) -> "Workers":
        if self.scheduler:
            self._client = _connect(self.scheduler)
        return self

    def __exit__(self, kind, *_) -> None:
        if kind is not None and self._pool is not None:  # failed or interrupted: no waiting for running tasks
            self._stop_local()
        self.close()

    def _stop_local(self) -> None:
        """End the local worker processes now: SIGTERM (they remove their temporary folders), and SIGKILL for one
        stuck in a long call into an FMU, whose folders are then removed here."""
        pool, self._pool = self._pool, None
        processes = list((pool._processes or {}).values())  # before Python 3.14 the executor's only handle on them
        results, manager = pool._result_queue, pool._executor_manager_thread  # (shutdown forgets them)
        # Tasks not yet sent to a worker may fill the pipe to workers that are about to die: the thread that sends
        # them is not waited for (neither by the pool's shutdown nor at the interpreter's exit).
        pool._call_queue.cancel_join_thread()
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join(timeout=STOP_TIMEOUT)
            if process.is_alive():
                process.kill()
                process.join()
        # A worker stopped while sending its result leaves the executor's manager thread waiting for the rest of
        # the message, and the interpreter's exit waiting for that thread.  With every worker gone, closing this
        # process's end of the result pipe turns the wait into an end of file: the pool counts as broken and ends.
        if results is not None:
            results._writer.close()
        if manager is not None:  # ended before the interpreter's exit wakes it (which fails on a closing pool)
            manager.join(timeout=STOP_TIMEOUT)
        sweep_temporary_folders()

    def close(self) -> None:
        """Shut the local pool down (waiting for running tasks, cancelling the rest) or leave the Dask cluster."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._client is not None:
            self._client.close()
            self._client = None

    def imap(self, task: Callable, items: Sequence, resource: WorkerResource | None = None
             ) -> Iterator[tuple[int, Any]]:
        """(index, task(resource object, items[index])) for every item, as the tasks finish."""
        items = list(items)
        if not items:
            return iter(())
        if self.scheduler:
            return self._imap_dask(task, items, resource)
        if self.workers == 0:
            return self._imap_here(task, items, resource)
        return self._imap_local(task, items, resource)

    def _imap_here(self, task, items, resource):
        global _report_to
        for i, item in enumerate(items):
            _report_to = (lambda message: self.on_report(*message)) if self.on_report else None
            try:
                result = _call(task, resource, item)
            finally:
                _report_to = None
            yield i, result

    def _deliver_reports(self) -> None:
        while self._reports is not None and not self._reports.empty():
            self.on_report(*self._reports.get())

    def _imap_local(self, task, items, resource):
        if self._pool is None:
            check_main_guard()
            context = multiprocessing.get_context("spawn")
            self._reports = context.SimpleQueue() if self.on_report else None
            self._pool = ProcessPoolExecutor(max_workers=min(self.workers, len(items)), mp_context=context,
                                             initializer=_worker_setup, initargs=(os.getpid(), self._reports))
        with signals_deferred():  # submit() starts the worker processes
            futures = {self._pool.submit(_call_relaying_warnings, task, resource, item): i
                       for i, item in enumerate(items)}
        # Tasks left when the caller stops early are cancelled by the pool's shutdown (__exit__), which also
        # forgets them; cancelled here, they would stay in the pool's books and break its end.
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED,
                                 timeout=REPORT_INTERVAL if self._reports is not None else None)
            self._deliver_reports()
            for fut in sorted(done, key=futures.get):
                try:
                    result, relayed = fut.result()
                except BrokenProcessPool as exc:
                    raise UserError("a local worker process died (killed, or out of memory?)") from exc
                _issue(relayed)
                yield futures[fut], result

    def _imap_dask(self, task, items, resource):
        from distributed import as_completed

        client = self._client
        res = client.scatter(resource, broadcast=True, hash=False) if resource is not None else None
        futures = [client.submit(_call_relaying_warnings, task, res, item, pure=False) for item in items]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                try:
                    result, relayed = fut.result()
                except ImportError as exc:  # a worker without servofmu (or without one of its dependencies)
                    raise UserError(f"Dask scheduler {self.scheduler}: a worker cannot import what the task needs "
                                    f"({exc}); install servofmu on the workers") from exc
                _issue(relayed)
                yield index[fut.key], result
        finally:
            client.cancel(futures)


def _is_main_test(node: ast.expr) -> bool:
    """``__name__ == "__main__"`` (either way round)."""
    if not (isinstance(node, ast.Compare) and len(node.ops) == 1 and isinstance(node.ops[0], ast.Eq)):
        return False
    sides = [node.left, node.comparators[0]]
    return any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides) and \
        any(isinstance(s, ast.Constant) and s.value == "__main__" for s in sides)


def unguarded_main_line() -> tuple[str, int] | None:
    """(file, line) of the main script's statement that is running now, when it stands outside every
    ``if __name__ == "__main__":`` block; None when it is guarded, or when there is no script file (``python -c``,
    an interactive session, a notebook) or its source cannot be read."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if not path or getattr(main, "__name__", None) != "__main__":
        return None
    # what multiprocessing's spawn runs again in a worker: neither a package's __main__ (python -m package) nor
    # IPython's launcher
    name = getattr(getattr(main, "__spec__", None), "name", None)
    if name is not None and (name == "__main__" or name.endswith(".__main__")) or Path(path).stem == "ipython":
        return None
    frame = sys._getframe(1)
    while frame is not None and not (frame.f_code.co_name == "<module>" and frame.f_globals is vars(main)):
        frame = frame.f_back
    if frame is None:  # the script has finished its top level (a thread, an atexit handler)
        return None
    line = frame.f_lineno
    try:
        tree = ast.parse("".join(linecache.getlines(path)) or Path(path).read_text(), path)
    except (OSError, SyntaxError, ValueError):
        return None
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_main_test(node.test) and node.body and \
                node.body[0].lineno <= line <= (node.body[-1].end_lineno or node.body[-1].lineno):
            return None
    return path, line


def check_main_guard() -> None:
    """Refuse to start worker processes from the top level of a script without ``if __name__ == "__main__":``.

    A worker process is started afresh (multiprocessing's spawn, as on Windows and macOS) and imports the main
    script to find the task's functions: unguarded, the script's work runs again in every worker, which tries to
    start workers of its own and dies (multiprocessing's "bootstrapping phase" error), and the run would end with
    every worker dead and no word of why."""
    where = unguarded_main_line()
    if where is not None:
        path, line = where
        raise UserError(f"{path}, line {line}: starts worker processes outside `if __name__ == \"__main__\":`; "
                        f"each worker imports the script again and would run it too: put the script's work under "
                        f"that guard (or pass workers=0 to run in this process)")


def _connect(address: str):
    Client = optional_import("distributed", "a Dask scheduler", "dask").Client
    if "://" not in address:
        raise UserError(f"Dask scheduler {address!r} is not a scheduler address like tcp://HOST:PORT")
    try:
        return Client(address, timeout=10)
    except (OSError, TimeoutError) as exc:
        raise UserError(f"Dask scheduler {address}: cannot connect ({str(exc).splitlines()[0]})") from exc
