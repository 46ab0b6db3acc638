"""Writing files so that a failed or killed run never leaves a half-written one behind."""
from __future__ import annotations

import os
from pathlib import Path

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
