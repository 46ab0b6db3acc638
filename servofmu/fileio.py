"""Writing files so that a failed or killed run never leaves a half-written one behind."""
from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

from .errors import UserError


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
        raise UserError(f"{path}: cannot write ({exc.strerror})") from None
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
        raise UserError(f"{path}: cannot write ({exc.strerror or exc})") from None
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
