"""Editing a servofmu HDF5 file as another writer would (a bug, another tool, an older servofmu): the content changed
and the file given the digest of its new content, so that what meets the edit is the readers' own checks (of values,
shapes, versions), not the digest that a changed file otherwise fails (docs/hdf5.md, Integrity)."""
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

from servofmu.integrity import DIGEST_ATTRIBUTE, content_digest


def edit_hdf5(path: str | Path, edit: Callable, digest: bool = True) -> Path:
    """``edit(h5py.File)`` on ``path`` in place, then its digest renewed (``digest``) or removed (False: a file
    written before files had one)."""
    with h5py.File(path, "r+") as f:
        edit(f)
        if DIGEST_ATTRIBUTE in f.attrs:
            del f.attrs[DIGEST_ATTRIBUTE]
        if digest:
            f.attrs[DIGEST_ATTRIBUTE] = np.bytes_(content_digest(f))
    return Path(path)
