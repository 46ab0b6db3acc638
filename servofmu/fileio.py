"""Files: written so that a failed or killed run never leaves a half-written one behind; HDF5 files checked for
their format and schema version in one way.

Every HDF5 file servofmu writes carries the root attributes ``format`` (what kind of file) and
``schema_version`` (an integer).  A reader accepts its own version and older ones it knows how to read,
and refuses newer ones (written by a later servofmu) and foreign files, naming the file.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

from .errors import UserError

__all__ = ["check_output_path", "partial_path", "atomic_write", "write_hdf5", "hdf5_attr", "open_hdf5", "check_format"]


def check_output_path(path: str | Path, overwrite: bool = True) -> Path:
    """An output path whose folder exists (and, unless ``overwrite``, that does not exist yet)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise UserError(f"{path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise UserError(f"{path}: is a folder, not a file")
    if not overwrite and path.exists():
        raise UserError(f"{path}: exists already (choose another name or remove it)")
    return path


def partial_path(path: Path) -> Path:
    """Where ``path`` is written before it replaces the target in one rename."""
    return path.with_name(f".{path.name}.part")


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    path = check_output_path(path)
    tmp = partial_path(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise UserError(f"{path}: cannot write ({exc.strerror})") from exc
    return path


def write_hdf5(path: str | Path, edit: Callable, start_from: str | Path | None = None) -> Path:
    """Write the HDF5 file ``path`` anew: copy ``start_from`` (or start empty), let ``edit(h5py.File)`` fill it,
    then rename it into place, so that a killed or failed run leaves the previous file or a complete new one."""
    import h5py

    path = Path(path)
    part = partial_path(path)
    try:
        if start_from is not None:
            shutil.copyfile(start_from, part)
        with h5py.File(part, "r+" if start_from is not None else "w") as f:
            edit(f)
        with open(part, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(part, path)
    except OSError as exc:
        part.unlink(missing_ok=True)
        raise UserError(f"{path}: cannot write ({exc.strerror or exc})") from exc
    except BaseException:
        part.unlink(missing_ok=True)
        raise
    try:  # make the rename itself durable
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass
    return path


def hdf5_attr(obj, key: str, default=...):
    """An HDF5 attribute as a plain Python value (str, int, float, ...); KeyError if missing and no default."""
    import numpy as np

    if key in obj.attrs:
        value = obj.attrs[key]
        if isinstance(value, bytes):
            value = value.decode()
        if isinstance(value, np.generic):
            value = value.item()
        return value
    if default is ...:
        raise KeyError(f"attribute {key!r} of {obj.name}")
    return default


def open_hdf5(path: str | Path, what: str):
    """The HDF5 file ``path`` open for reading (an h5py.File, a context manager); a missing or unreadable file is
    a UserError naming it and saying it should be a ``what``."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such {what}")
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        why = str(exc).split("(")[-1].rstrip(")") if "(" in str(exc) else str(exc)
        raise UserError(f"{path}: not a readable {what} (not an HDF5 file, or a damaged one: {why})") from exc


def check_format(f, path: str | Path, formats: str | tuple[str, ...], schema_version: int,
                 what: str) -> tuple[str, int]:
    """Check the ``format`` and ``schema_version`` attributes of the open HDF5 file ``f``.

    ``formats``: the accepted format name(s); ``schema_version``: the newest version this servofmu reads (every
    version from 1 up to it is read).  Returns (format, version); a foreign or newer file is a UserError naming
    ``path`` and saying it is not a ``what``.
    """
    accepted = (formats,) if isinstance(formats, str) else tuple(formats)
    kind = hdf5_attr(f, "format", None)
    if kind not in accepted:
        raise UserError(f"{path}: not a servofmu {what} (format attribute {kind!r}, expected "
                        f"{' or '.join(map(repr, accepted))})")
    version = hdf5_attr(f, "schema_version", None)
    if isinstance(version, bool) or not isinstance(version, int) or not 1 <= version <= schema_version:
        raise UserError(f"{path}: {what} schema version {version!r} is not supported (this servofmu reads "
                        f"versions 1 to {schema_version}; a newer file needs a newer servofmu)")
    return kind, version
