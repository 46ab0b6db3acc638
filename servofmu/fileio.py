"""Files: written so that a failed or killed run never leaves a half-written one behind; HDF5 files checked for
their format and schema version in one way.

Every HDF5 file servofmu writes carries the root attributes ``format`` (what kind of file) and
``schema_version`` (an integer).  A reader accepts its own version and older ones it knows how to read,
and refuses newer ones (written by a later servofmu) and foreign files, naming the file.  It also carries
``content_sha256``, a digest of everything in it (servofmu.integrity), which the one reader, :func:`read_hdf5`,
checks — from the input's bytes read once, in a first pass that cannot hang — before it reads the file.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import os
from pathlib import Path
from typing import Callable, Iterable, Iterator

from .claims import (CONTINUE_WORDS, OutputExists, check_output_path, claim_output, claim_outputs, holds_outputs,
                     output_claims, output_mode, partial_path)
from .errors import MAX_MAGNITUDE, UserError
from .integrity import (DIGEST_ATTRIBUTE, READ_ERRORS, InspectionFailed, content_digest, inspect_image,  # noqa: F401
                        read_error_reason)  # the last two defined there (it needs them), named here as before

# (the output rule lives in servofmu.claims; its names are also this module's, as they always were)
__all__ = ["file_sha256", "claim_output", "claim_outputs", "output_claims", "holds_outputs", "OutputExists",
           "output_mode", "CONTINUE_WORDS", "check_output_path", "partial_path", "atomic_write", "all_or_none",
           "staged_folder",
           "write_hdf5", "store_array", "hdf5_attr", "read_hdf5", "read_image", "read_hdf5_image", "READ_ERRORS",
           "read_error_reason", "check_format", "check_values", "HDF5_LIBVER", "NO_ROOM", "write_failures"]

# Lowest HDF5 file-format version written (HDF5 1.10 and later read it): its object headers carry checksums, as
# Fletcher-32 covers the arrays (store_array).  What neither covers (text attributes live in a global heap without
# one) the file's digest does (servofmu.integrity).
HDF5_LIBVER = ("v110", "latest")



# What the system says when a write cannot be done for lack of room: a full disk, a quota, a file-size limit.
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, in hex: what provenance records of every input file."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@contextlib.contextmanager
def write_failures(what: str, error: type[UserError] = UserError) -> Iterator[None]:
    """``with write_failures("the extracted copy of X in DIR")``: a write of the block that fails for lack of room
    (NO_ROOM) ends as ``error("cannot write WHAT: reason")`` — for writes by zipfile, shutil or FMPy, whose errors
    name no file.  Other errors pass unchanged."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in NO_ROOM:
            raise
        raise error(f"cannot write {what}: {exc.strerror}") from exc


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` through ``.NAME.part`` and one rename: every file servofmu writes goes through
    here, so a full disk, a quota or a file-size limit ends as one UserError naming the file (``cannot write
    FILE: reason``), with no partial file left and the previous ``path`` untouched.  Inside :func:`all_or_none`
    the rename waits for the block's end."""
    path = Path(path)
    part = partial_path(path)
    try:
        _write_part(part, memoryview(data.encode() if isinstance(data, str) else data))
        if _staged and os.path.abspath(path) in _staged[0][0]:
            _staged[0][1][os.path.abspath(path)] = part
            return path
        os.replace(part, path)
    except OSError as exc:
        part.unlink(missing_ok=True)
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from exc
    except BaseException:
        part.unlink(missing_ok=True)
        raise
    _sync_folder(path)
    return path


def _sync_folder(path: Path) -> None:
    """Make a rename into ``path``'s folder durable."""
    try:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass


# The open all_or_none() block: its outputs (absolute paths), and those written: target -> its complete .NAME.part.
_staged: list[tuple[set[str], dict[str, Path]]] = []


@contextlib.contextmanager
def all_or_none(outputs: Iterable[str | Path | None]) -> Iterator[None]:
    """``with all_or_none(outputs):`` every one of ``outputs`` that :func:`atomic_write` writes in the block is
    written complete as its ``.NAME.part`` and renamed over its target only when the block ends without an error —
    all of them at once, stop signals deferred until the last rename — so that a run with several outputs (select,
    tune with a report) that fails or is stopped before its end leaves every old output as it was, and one that
    ends has replaced all of them.  Other files (temporary ones) are written at once; a block inside another joins
    it.  An output written in the block is not readable under its name before the block ends."""
    targets = {os.path.abspath(p) for p in outputs if p is not None}
    if _staged:  # the outer block renames
        _staged[0][0].update(targets)
        yield
        return
    staged: dict[str, Path] = {}
    _staged.append((targets, staged))
    try:
        yield
    except BaseException:
        for part in staged.values():
            part.unlink(missing_ok=True)
        raise
    finally:
        _staged.pop()
    from .runtime import signals_deferred

    with signals_deferred():  # a stop now would leave some outputs new and others old
        for i, (target, part) in enumerate(staged.items()):
            try:
                os.replace(part, target)
            except OSError as exc:  # (a folder removed meanwhile): the rest stay as they were
                for rest in list(staged.values())[i:]:
                    rest.unlink(missing_ok=True)
                raise UserError(f"cannot write {target}: {exc.strerror or exc}") from exc
        for target in staged:
            _sync_folder(Path(target))


@contextlib.contextmanager
def staged_folder(folder: str | Path) -> Iterator[Path]:
    """``with staged_folder(FOLDER) as work:`` a run that writes many files into FOLDER, and reads some of them
    back, makes them in ``work`` (``.FOLDER.part`` beside it; one a killed run left is removed first); when the
    block ends without an error they (but hidden ones: locks) are moved into FOLDER all together, stop signals
    deferred until the last — on an error or a stop ``work`` is removed and FOLDER stays as it was.  (The demo's
    folder: all or none.)"""
    import shutil

    from .locks import release, sibling, take
    from .runtime import signals_deferred

    folder = Path(folder)
    work, lock = sibling(folder.absolute(), "part"), sibling(folder.absolute(), "lock")
    try:
        work.parent.mkdir(parents=True, exist_ok=True)
        held = take(lock)  # the staging folder is this run's alone
    except OSError as exc:
        raise UserError(f"cannot write {work}: {exc.strerror or exc}") from exc
    if held is None:
        raise UserError(f"{folder}: another run is writing it now (wait until it ends, or write to another folder)")
    try:
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir()
    except OSError as exc:
        release(held, lock)
        raise UserError(f"cannot write {work}: {exc.strerror or exc}") from exc
    try:
        yield work
        with signals_deferred():  # a stop now would leave some files new and others old
            try:
                folder.mkdir(parents=True, exist_ok=True)
                for item in sorted(work.iterdir()):
                    if item.name.startswith("."):  # servofmu's own: the claims' locks of the run's writers
                        continue
                    if item.is_dir() and (folder / item.name).is_dir():
                        shutil.rmtree(folder / item.name)
                    os.replace(item, folder / item.name)
            except OSError as exc:
                raise UserError(f"cannot write {folder}: {exc.strerror or exc}") from exc
    finally:
        shutil.rmtree(work, ignore_errors=True)
        release(held, lock)


def _write_part(part: Path, data: memoryview) -> None:
    """``data`` into the file ``part``, on the disk (fsync).  Where the system allows (Linux: O_TMPFILE) the file
    is written without a name and linked in as ``part`` once complete, so that a run killed while writing
    leaves nothing behind; elsewhere it is written under its name."""
    fd = None
    if hasattr(os, "O_TMPFILE") and os.path.isdir("/proc/self/fd"):
        try:
            fd = os.open(part.parent, os.O_TMPFILE | os.O_WRONLY, 0o644)
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL):
                raise
    unnamed = fd is not None
    if not unnamed:
        fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        while data:
            data = data[os.write(fd, data):]
        os.fsync(fd)
        if unnamed:
            part.unlink(missing_ok=True)  # a stale one of a killed run
            proc = os.open("/proc/self/fd", os.O_RDONLY)  # linkat(..., AT_SYMLINK_FOLLOW) needs a directory fd
            try:
                os.link(str(fd), part, src_dir_fd=proc, follow_symlinks=True)
            finally:
                os.close(proc)
    finally:
        os.close(fd)


def write_hdf5(path: str | Path, edit: Callable, start_from: str | Path | None = None) -> Path:
    """Write the HDF5 file ``path`` anew: start from a copy of ``start_from`` (or empty), let ``edit(h5py.File)``
    fill it, then write it with :func:`atomic_write`.

    The file is built in memory: HDF5 never writes to the disk itself, so a write that fails (disk full, size
    limit) is a plain OSError of atomic_write, not an error inside the HDF5 library.  The file gets the root
    attribute ``content_sha256`` (servofmu.integrity), the digest :func:`read_hdf5` checks; ``start_from`` must pass
    the same check (and first pass) before it is continued."""
    import h5py
    import numpy as np

    path = Path(path)
    image = None
    if start_from is not None:
        try:
            image = Path(start_from).read_bytes()
        except OSError as exc:
            raise UserError(f"cannot read {start_from}: {exc.strerror or exc}") from exc
        try:  # the file continued must be sound: its damage would otherwise be signed anew with the new digest
            inspect_image(image)
        except InspectionFailed as exc:
            raise UserError(f"{start_from}: damaged, not continued ({exc.reason})") from None
    try:
        f = h5py.File.in_memory(image, libver=HDF5_LIBVER) if image is not None else \
            h5py.File.in_memory(libver=HDF5_LIBVER)
        with f:
            edit(f)
            # last: the digest of everything written (fixed-length text: in the root's checksummed header)
            f.attrs[DIGEST_ATTRIBUTE] = np.bytes_(content_digest(f))
            f.flush()
            image = f.id.get_file_image()
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return atomic_write(path, image)


def store_array(group, name: str, data, **attrs):
    """Store an array as every servofmu file does: with a Fletcher-32 checksum (a flipped bit is found on
    reading), compressed when large; ``attrs`` become its attributes.  Returns the dataset.

    Text is stored as fixed-length UTF-8 (variable-length strings live in a heap no filter covers)."""
    import h5py
    import numpy as np

    data = np.asarray(data)
    if data.dtype.kind in "OUS":
        encoded = [str(x.decode() if isinstance(x, bytes) else x).encode() for x in data.ravel()]
        dtype = h5py.string_dtype("utf-8", max([1, *map(len, encoded)]))
        data = np.array(encoded, dtype=dtype).reshape(data.shape)
    options = {"fletcher32": True} if data.ndim else {}  # HDF5 filters need a chunked (non-scalar) dataset
    if data.size > 256:
        options.update(compression="gzip", shuffle=True)
    ds = group.create_dataset(name, data=data, **options)
    ds.attrs.update(attrs)
    return ds


def hdf5_attr(obj, key: str, default=...):
    """An HDF5 attribute as a plain Python value (str, int, float, ...); KeyError if missing and no default."""
    import numpy as np

    try:  # one lookup: h5py's `in` costs about as much as the read
        value = obj.attrs[key]
    except KeyError:
        if key in obj.attrs:  # there but unreadable (a failed checksum): h5py's own message says so
            raise
        if default is ...:
            raise KeyError(f"attribute {key!r} of {obj.name}") from None
        return default
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, np.generic):
        value = value.item()
    return value


def read_hdf5(path: str | Path, what: str, formats: str | tuple[str, ...], schema_version: int, read: Callable,
              with_sha256: bool = False):
    """Read a servofmu HDF5 file: its bytes once, then a first pass over them that cannot hang and checks the
    digest (servofmu.integrity.inspect_image), then its format and version (:func:`check_format`); returns
    ``read(f, version)``, with ``f`` the file opened on those same bytes in memory — and, with ``with_sha256``,
    ``(that, SHA-256 of the bytes read)``: the hash provenance records is that of the bytes parsed, even if the
    file is replaced meanwhile.  Whatever goes wrong (a missing or malformed item, a failed checksum or digest, a
    file the HDF5 library cannot finish reading) is one UserError naming the file: ``FILE: damaged WHAT
    (reason)``."""
    path = Path(path)
    image = read_image(path, what)

    def checked(f):
        _, version = check_format(f, path, formats, schema_version, what)
        return read(f, version)

    value = read_hdf5_image(image, path, what, checked)
    return (value, hashlib.sha256(image).hexdigest()) if with_sha256 else value


def read_hdf5_image(image: bytes, path: str | Path, what: str, read: Callable):
    """``read(f)`` of the HDF5 file whose bytes are ``image`` (read from ``path``), after the first pass that
    cannot hang (servofmu.integrity.inspect_image: a file with a digest must match it), ``f`` opened on the bytes
    in memory: for servofmu's files (:func:`read_hdf5`) and foreign ones (MAT 7.3 records).  What goes wrong is one
    UserError naming ``path``."""
    import h5py

    try:
        inspect_image(image)
    except InspectionFailed as exc:
        if exc.kind == "open":
            raise UserError(f"{path}: not a readable {what} (not an HDF5 file, or a damaged one: {exc.reason})") \
                from None
        raise UserError(f"{path}: damaged {what} ({exc.reason})") from None
    try:
        with h5py.File.in_memory(image) as f:
            return read(f)
    except UserError:
        raise
    except (*READ_ERRORS, OverflowError) as exc:  # (OverflowError: a huge stored number made an int)
        raise UserError(f"{path}: damaged {what} ({read_error_reason(exc)})") from exc


def read_image(path: str | Path, what: str) -> bytes:
    """The bytes of the input ``path``, read once; a missing or unreadable file is a UserError naming it."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such {what}")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise UserError(f"cannot read {path}: {exc.strerror or exc}") from exc
    except MemoryError:
        raise UserError(f"{path}: too large to read into memory") from None


def check_values(source, name: str, values, shape: tuple | None = None, finite: bool = True,
                 why: str = "a damaged or foreign file"):
    """The one check of stored numbers, used by every reader (and by writers before the first byte): ``values`` as
    an array of ``shape`` (None: any; an entry None: any length along that axis), finite unless ``finite`` is
    False, and never beyond ±:data:`MAX_MAGNITUDE`.  A violation is a UserError naming ``source`` (the file) and
    ``name``, ``why`` in parentheses.  Returns the array."""
    import numpy as np

    try:
        a = np.asarray(values)
        if a.dtype.kind not in "biufc":
            raise TypeError
    except (TypeError, ValueError):
        raise UserError(f"{source}: {name} is not numeric ({why})") from None
    if shape is not None and (a.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, a.shape))):
        expected = "×".join("n" if n is None else str(n) for n in shape) or "a scalar"
        raise UserError(f"{source}: {name} has shape {'×'.join(map(str, a.shape)) or 'scalar'}, expected "
                        f"{expected} ({why})")
    parts = (a.real, a.imag) if a.dtype.kind == "c" else (a,)
    with np.errstate(invalid="ignore"):
        for part in parts:
            if finite and not np.all(np.isfinite(part)):
                raise UserError(f"{source}: {name} holds NaN or Inf ({why})")
            if np.any(np.abs(part[np.isfinite(part)]) > MAX_MAGNITUDE):
                raise UserError(f"{source}: {name} holds a value beyond ±{MAX_MAGNITUDE:g} ({why})")
    return a


def check_format(f, path: str | Path, formats: str | tuple[str, ...], schema_version: int,
                 what: str) -> tuple[str, int]:
    """Check the ``format`` and ``schema_version`` attributes of the open HDF5 file ``f``.

    ``formats``: the accepted format name(s); ``schema_version``: the newest version this servofmu reads (every
    version from 1 up to it is read).  Returns (format, version); a foreign or newer file is a UserError naming
    ``path`` and saying it is not a ``what``.
    """
    accepted = (formats,) if isinstance(formats, str) else tuple(formats)
    try:
        kind, version = hdf5_attr(f, "format", None), hdf5_attr(f, "schema_version", None)
    except READ_ERRORS as exc:
        raise UserError(f"{path}: damaged {what} ({read_error_reason(exc)})") from exc
    if kind not in accepted:
        raise UserError(f"{path}: not a servofmu {what} (format attribute {kind!r}, expected "
                        f"{' or '.join(map(repr, accepted))})")
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= schema_version:
        raise UserError(f"{path}: {what} schema version {version!r} is not supported (this servofmu reads "
                        f"versions 1 to {schema_version}; a newer file needs a newer servofmu)")
    return kind, version
