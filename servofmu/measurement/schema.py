"""Stored dataclasses: each field of a dataclass that a data file keeps declares how it is stored in the HDF5
group of its instance (:class:`Stored`, given with :func:`stored`), and :func:`write_fields`, :func:`read_fields`
and :func:`check_fields` follow those declarations (servofmu.measurement.datafile: experiments and records).
"""
from __future__ import annotations

import json
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

from ..fileio import check_values, hdf5_attr, store_array

__all__ = ["Stored", "stored", "ATTRIBUTE", "DATASET", "SIGNALS", "NESTED", "FINITE", "BOUNDED", "STORED",
           "set_attrs", "write_fields", "read_fields", "check_fields"]

ATTRIBUTE, DATASET, SIGNALS, NESTED = "attribute", "dataset", "signals", "nested"
FINITE, BOUNDED = "finite", "bounded"  # how a number is checked on reading (fileio.check_values)
STORED = "servofmu.stored"  # the key of a field's Stored in its metadata


@dataclass(frozen=True)
class Stored:
    """How a field of ExperimentResult, RecordAnalysis or Record is kept in its HDF5 group: the one declaration
    that the writer, the reader and the checks of a data file follow.

    ``kind``: ATTRIBUTE (an attribute of the group), DATASET (an array in the group, with ``description`` as its
    attribute if given), SIGNALS (a Series: its signals in a subgroup named after the field, or with ``inline``
    in the group itself) or NESTED (the dataclass ``nested``, stored in the same group; the bool attribute
    ``flag`` says whether it is there).  ``dtype``: the value's type, also of a dataset's elements: int (stored
    as int64), float, complex (complex128), bool, str, or dict (JSON text).  ``check``: FINITE (finite, within
    ±MAX_MAGNITUDE), BOUNDED (within ±MAX_MAGNITUDE; NaN and inf allowed) or None (not checked); an attribute is
    a scalar, a dataset one-dimensional.  ``optional``: a file may lack it, and then it reads as the field's
    default; a None value is not written.  ``choices``: the values a file may hold.  ``since``: the schema version
    that added it; older files read ``before``.
    """

    kind: str = ATTRIBUTE
    dtype: type = float
    check: str | None = None
    optional: bool = False
    description: str | None = None
    inline: bool = False
    nested: type | None = None
    flag: str | None = None
    choices: tuple | None = None
    since: int = 1
    before: object = None


def stored(default=MISSING, optional: bool | None = None, **how):
    """A dataclass field stored as ``how`` says (the arguments of :class:`Stored`); with a ``default``, optional
    in a file unless ``optional`` says otherwise."""
    optional = default is not MISSING if optional is None else optional
    return field(default=default, metadata={STORED: Stored(optional=optional, **how)})


def set_attrs(obj, values: dict) -> None:
    """Set the attributes ``values`` of an HDF5 object, leaving out None; dicts, lists and tuples as JSON text."""
    for key, value in values.items():
        if value is None:
            continue
        if isinstance(value, (dict, list, tuple)):
            value = json.dumps(value)
        obj.attrs[key] = value


# What a value of each dtype is written as (None: not written); dicts become JSON text in _set_attrs.
_ENCODE = {int: np.int64, complex: np.complex128, bool: bool, float: None, str: None, dict: None}


def _how(f) -> Stored:
    return f.metadata[STORED]


def write_fields(g: h5py.Group, item, write_series: Callable, units: dict | None = None, **values) -> None:
    """Store the dataclass ``item`` in the group ``g`` as its fields declare (``values`` replace some of them):
    its attributes in the order of the fields (a NESTED field as its flag), then ``units`` as an attribute,
    then the NESTED dataclasses, then the datasets and signals in the order of the fields; a SIGNALS field with
    ``write_series(group, series)``."""
    attrs, nested, arrays = {}, [], []
    for f in fields(item):
        how, value = _how(f), values.get(f.name, getattr(item, f.name))
        if how.kind == ATTRIBUTE:
            encode = _ENCODE[how.dtype]
            attrs[f.name] = value if value is None or encode is None else encode(value)
        elif how.kind == NESTED:
            attrs[how.flag] = value is not None
            if value is not None:
                nested.append(value)
        else:
            arrays.append((f.name, how, value))
    set_attrs(g, {**attrs, "units": units})
    for value in nested:
        write_fields(g, value, write_series)
    for name, how, value in arrays:
        if how.kind == DATASET:
            description = {} if how.description is None else {"description": how.description}
            store_array(g, name, np.asarray(value, dtype=how.dtype), **description)
        else:
            write_series(g if how.inline else g.create_group(name), value)


# How an attribute read back becomes a value of its dtype.
_DECODE = {int: int, float: float, complex: complex, bool: bool, str: str, dict: json.loads}


def read_fields(cls, g: h5py.Group, version: int, read_series: Callable):
    """The dataclass ``cls`` read from the group ``g`` of a file of schema ``version``, as its fields declare; a
    SIGNALS field with ``read_series(group)``.  A missing item is a KeyError, a value not among the field's
    ``choices`` a ValueError."""
    values = {}
    for f in fields(cls):
        how = _how(f)
        if version < how.since:
            values[f.name] = how.before
        elif how.kind == ATTRIBUTE:
            value = hdf5_attr(g, f.name, None) if how.optional else hdf5_attr(g, f.name)
            if value is None:
                value = None if f.default is MISSING else f.default
            else:
                value = _DECODE[how.dtype](value)
            if how.choices is not None and value not in how.choices:
                raise ValueError(f"{f.name} {value!r}")
            values[f.name] = value
        elif how.kind == DATASET:
            values[f.name] = np.asarray(g[f.name][()])
        elif how.kind == SIGNALS:
            values[f.name] = read_series(g if how.inline else g[f.name])
        else:
            values[f.name] = read_fields(how.nested, g, version, read_series) if bool(hdf5_attr(g, how.flag)) \
                else None
    return cls(**values)


def check_fields(path: Path, where: str, item, why: str = "a damaged or foreign file") -> None:
    """Check the numbers of the dataclass ``item`` read from the group ``where`` of the file ``path`` as its
    fields declare (fileio.check_values: a UserError naming the file and the item, ``why`` in parentheses); a
    writer checks what it is about to write the same way."""
    for f in fields(item):
        how, value = _how(f), getattr(item, f.name)
        if value is None:
            continue
        if how.kind == SIGNALS:
            where_signals = where if how.inline else f"{where}/{f.name}"
            for name, signal in value.signals().items():
                check_values(path, f"{where_signals}/{name}", signal, (value.time.size,), why=why)
        elif how.kind == NESTED:
            check_fields(path, where, value, why)
        elif how.check is not None:
            check_values(path, f"{where}/{f.name}", value, () if how.kind == ATTRIBUTE else (None,),
                         finite=how.check == FINITE, why=why)
