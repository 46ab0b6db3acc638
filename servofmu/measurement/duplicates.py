"""One measurement counted twice: records (or stepped-sine experiments) whose samples are identical, found by a
digest of their arrays.

A real repeat of a measurement differs at least in its noise; identical arrays are a copy (one CSV imported twice,
one data file given twice, a file and its copy).  Fitted twice, a copy narrows every interval by √2 as if it were
new data; validated on, it is no test of prediction.
"""
from __future__ import annotations

import hashlib

import numpy as np

from ..errors import UserError
from .datafile import DataFile, Series

__all__ = ["series_digest", "file_items", "first_repeat", "refuse_repeats", "TWICE"]

TWICE = "one measurement counted twice narrows every interval by √2 as if it were new data"


def series_digest(series: Series, *extra: float) -> str:
    """SHA-256 (hex) of the arrays of ``series`` (each named, with its shape) and of the numbers ``extra``."""
    h = hashlib.sha256()
    for name, values in sorted(series.signals().items()):
        a = np.ascontiguousarray(values, dtype=float)
        h.update(name.encode() + b"\0" + repr(a.shape).encode() + a.tobytes())
    h.update(np.asarray(extra, dtype=float).tobytes())
    return h.hexdigest()


def file_items(ds: DataFile, where: str | None = None) -> list[tuple[str, str]]:
    """(what, digest) of every record or experiment of ``ds``, ``what`` naming it in a message ("record 'a' of
    FILE")."""
    where = ds.path if where is None else where
    if ds.kind == "records":
        return [(f"record {r.name!r} of {where}", series_digest(r.series)) for r in ds.records]
    return [(f"experiment {e.index} of {where}", series_digest(e.window, e.amplitude, e.frequency))
            for e in ds.experiments]


def first_repeat(items: list[tuple[str, str]], start: int = 0) -> tuple[str, str] | None:
    """(the later, the earlier) of the first item from index ``start`` on whose digest an earlier item has, or
    None."""
    seen: dict[str, str] = {}
    for k, (what, digest) in enumerate(items):
        if digest in seen and k >= start:
            return what, seen[digest]
        seen.setdefault(digest, what)
    return None


def refuse_repeats(items: list[tuple[str, str]], advice: str) -> None:
    """A UserError naming the first item that repeats an earlier one, with ``advice`` (what to give instead)."""
    repeat = first_repeat(items)
    if repeat is not None:
        raise UserError(f"{repeat[0]} holds the same samples as {repeat[1]}: {TWICE}; {advice}")
