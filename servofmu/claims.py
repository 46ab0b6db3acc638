"""The one output rule (docs/reliability.md "One overwrite rule"): every output of a run claimed before any work —
its folder writable, none of the run's inputs, not servofmu's own package data, not existing unless the run may
replace or continue it, held against other runs until the run ends — and a run's outputs claimed together, so that
no output of a run is another one (:func:`claim_outputs`)."""
from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Callable, Iterator

from .errors import UserError
from .locks import release, sibling, take

__all__ = ["OutputExists", "CONTINUE_WORDS", "output_mode", "claim_output", "claim_outputs", "output_claims",
           "holds_outputs", "check_output_path", "partial_path", "same_file", "file_identity", "package_folders",
           "refuse_package_data"]


def partial_path(path: Path) -> Path:
    """Where ``path`` is written before it replaces the target in one rename (``.NAME.part``; a hashed name for a
    name too long to take the dot and suffix)."""
    return sibling(Path(path), "part")


class OutputExists(UserError):
    """An output that exists already and that the run was not told to replace (or to continue).

    One rule, one set of words: ``str()`` names the library's keywords (``overwrite=True``, ``resume=True``),
    :meth:`command_line_text` the command line's options (``--force``, ``--resume``)."""

    def __init__(self, path: Path, can_continue: str | None = None):
        self.path, self.can_continue = path, can_continue
        super().__init__(self._text("{}=True", "overwrite"))

    def _text(self, spelling: str, replace: str) -> str:
        how = f"give {spelling.format(replace)} to replace it"
        if self.can_continue:
            how += f", or {spelling.format(self.can_continue)} to {CONTINUE_WORDS[self.can_continue]} it"
        return f"{self.path}: exists already ({how})"

    def command_line_text(self) -> str:
        """The same refusal in the command line's words."""
        return self._text("--{}", "force")


# How an existing output is continued, by the name of the keyword (and option) that asks for it.
CONTINUE_WORDS = {"resume": "continue", "append": "add to"}
OUTPUT_MODES = ("new", "replace", "continue")


def output_mode(overwrite: bool = False, resume: bool = False) -> str:
    """The mode of :func:`claim_output` for a writer's ``overwrite`` and ``resume`` (or ``append``) arguments."""
    return "continue" if resume else "replace" if overwrite else "new"


def claim_output(path: str | Path, mode: str = "new", inputs=(), can_continue: str | None = None) -> Path:
    """The one output rule (docs/reliability.md), checked before any work by the command line and by every writer
    of the library: so that a run never computes to the end to find it cannot (or may not) save.

    ``path``'s folder must exist and be writable; ``path`` must not be one of the run's ``inputs`` (the same file,
    under any name) nor inside servofmu's own package (:func:`refuse_package_data`); and an existing ``path`` is refused (:class:`OutputExists`) unless ``mode`` is "replace"
    (``overwrite=True``, ``--force``) or "continue" (``resume``/``append``: the writer extends it).
    ``can_continue`` names the writer's keyword for continuing ("resume" or "append"), for the error's words.
    Returns ``path`` as a Path."""
    if mode not in OUTPUT_MODES:
        raise ValueError(f"mode must be one of {OUTPUT_MODES}, not {mode!r}")
    path = Path(path)
    refuse_package_data(path)
    for source in inputs:
        if source is not None and same_file(path, Path(source)):
            raise UserError(f"{path}: is also an input of this run (write the output to another file)")
    if not path.parent.is_dir():
        raise UserError(f"{path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise UserError(f"{path}: is a folder, not a file")
    if mode == "new" and path.exists():
        raise OutputExists(path, can_continue)
    probe = partial_path(path)  # the file every write starts with: can it be made?
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT, 0o644)
        os.close(fd)
        probe.unlink()
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from exc
    except BaseException:  # a stop signal between making and removing it: the probe must not stay behind
        probe.unlink(missing_ok=True)
        raise
    _hold(path)
    return path


# The outputs claimed inside each open output_claims() block (innermost last): resolved path -> (lock, its fd).
_claims: list[dict[str, tuple[Path, int]]] = []


@contextlib.contextmanager
def output_claims() -> Iterator[None]:
    """``with output_claims():`` every output :func:`claim_output` passes inside the block is claimed for this
    process until the block ends (a lock beside it, servofmu.locks): another run that claims the same output
    meanwhile is refused, so two runs can never both write one file — both would pass the existence rule when
    started together.  The command line runs every command in such a block, and so do the library's long runs."""
    _claims.append({})
    try:
        yield
    finally:
        for lock, fd in _claims.pop().values():
            release(fd, lock)


def holds_outputs(function: Callable) -> Callable:
    """Run ``function`` inside :func:`output_claims` (for the library's long runs)."""
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        with output_claims():
            return function(*args, **kwargs)
    return wrapper


def _hold(path: Path) -> None:
    """Claim ``path`` for the innermost :func:`output_claims` block (nothing outside one; a path this process
    holds already stays held)."""
    key = str(path.resolve())
    if not _claims or any(key in scope for scope in _claims):
        return
    lock = sibling(path, "lock")
    try:
        fd = take(lock)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from exc
    if fd is None:
        raise UserError(f"{path}: another run is writing it now (wait until it ends, or write to another file)")
    _claims[-1][key] = (lock, fd)


def check_output_path(path: str | Path, overwrite: bool = True) -> Path:
    """:func:`claim_output` with ``overwrite`` (True: "replace", False: "new"), for writers whose caller has
    applied the rule already (a fleet's results, a report's figures in its own temporary folder)."""
    return claim_output(path, "replace" if overwrite else "new")


def file_identity(path: str | Path) -> tuple:
    """What makes two names one file: the device and inode of an existing file (a hard link, a symbolic link, a
    bind mount: one file), the path with every link resolved of one that does not exist yet."""
    try:
        st = os.stat(path)
        return ("inode", st.st_dev, st.st_ino)
    except OSError:
        return ("path", os.path.realpath(path))


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether the names ``a`` and ``b`` are one file (:func:`file_identity`)."""
    return file_identity(a) == file_identity(b)


@functools.lru_cache(maxsize=1)
def package_folders() -> tuple[Path, ...]:
    """servofmu's own folders: the package (its C sources, its annotations) and its example files
    (``servofmu.fmu_models``, which an installation may keep elsewhere), every link resolved."""
    import importlib.util

    folders = {Path(__file__).resolve().parent}
    spec = importlib.util.find_spec("servofmu.fmu_models")
    folders.update(Path(p).resolve() for p in (spec.submodule_search_locations or ()) if spec is not None)
    return tuple(sorted(folders))


def refuse_package_data(path: str | Path) -> None:
    """An output inside servofmu's own folders (an example file named by its path) is refused: the files servofmu
    ships are inputs only."""
    where = Path(os.path.realpath(path))
    if any(where.is_relative_to(folder) for folder in package_folders()):
        raise UserError(f"{path}: is inside servofmu's own package (its examples and sources are never "
                        "outputs; write to another file)")


def claim_outputs(outputs: Mapping[str, str | Path | None], mode: str = "new", inputs: Iterable = (),
                  can_continue: str | None = None) -> dict[str, Path]:
    """All outputs of a run claimed together, before any work: ``outputs`` maps each output's name in the
    messages (an option: ``-o``, ``--report``) to its path (None: not written).  No two of them may be one file
    (:func:`same_file`: by inode, or by resolved path before they exist) — one would destroy the other — and each
    must pass :func:`claim_output` against every one of ``inputs``.  Returns the name -> Path of those given."""
    inputs = [source for source in inputs if source is not None]
    seen: dict[tuple, str] = {}
    claimed = {}
    for name, path in outputs.items():
        if path is None:
            continue
        identity = file_identity(path)
        if identity in seen:
            raise UserError(f"{path}: is the output of both {seen[identity]} and {name} (give each output its own "
                            "file)")
        seen[identity] = name
        claimed[name] = Path(path)
    for path in claimed.values():
        claim_output(path, mode, inputs, can_continue)
    return claimed
