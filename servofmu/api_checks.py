"""The public functions' arguments checked against their annotations, so that an obviously wrong one (a number
for a file name, a name for a Plant) is a :class:`~servofmu.errors.UserError` naming the argument, not a
``TypeError`` or ``AttributeError`` from deep inside.

Only annotations made of simple names are checked (``str | Path``, ``Plant``, ``Result | None``, ``float``);
anything else (``np.ndarray``, ``Sequence[str]``, ``dict``) is left to the function, which checks its values.
The API's functions call :func:`check_arguments` first.
"""
from __future__ import annotations

import functools
import inspect
import os
from numbers import Integral, Real

from .errors import UserError

__all__ = ["check_arguments", "argument_problem"]

# annotation name -> (what a value must be, the test)
_SIMPLE = {
    "str": ("a string", lambda v: isinstance(v, str)),
    "Path": ("a file name or Path", lambda v: isinstance(v, (str, os.PathLike))),
    "None": ("None", lambda v: v is None),
    "bool": ("True or False", lambda v: isinstance(v, bool)),
    "int": ("an integer", lambda v: isinstance(v, Integral) and not isinstance(v, bool)),
    "float": ("a number", lambda v: isinstance(v, Real) and not isinstance(v, bool)),
}


def _accepts(token: str, value, names: dict) -> bool | None:
    """Whether ``value`` fits the annotation name ``token`` (a class looked up in ``names``, the function's
    module); None when it is not a name this module checks (a protocol, a generic, an unknown name)."""
    if token in _SIMPLE:
        return _SIMPLE[token][1](value)
    cls = names.get(token) if token.isidentifier() else None
    if isinstance(cls, type) and not getattr(cls, "_is_protocol", False):  # Plant, Result, DataFile, FmuInfo
        return isinstance(value, cls)
    return None


def argument_problem(name: str, annotation, value, names: dict | None = None) -> str | None:
    """Why ``value`` does not fit the parameter ``name`` annotated ``annotation`` (a string; class names looked up
    in ``names``), or None (it fits, or the annotation is not one this module checks)."""
    if not isinstance(annotation, str) or not annotation:
        return None
    tokens = [t.strip() for t in annotation.split("|")]
    verdicts = [_accepts(t, value, names or {}) for t in tokens]
    if None in verdicts or any(verdicts):
        return None
    shown = [t for t in tokens if not (t == "str" and "Path" in tokens)]  # "a file name or Path" says it
    wanted = " or ".join(_SIMPLE[t][0] if t in _SIMPLE else f"a {t}" for t in shown)
    return f"{name} must be {wanted}, not {type(value).__name__} {value!r:.60}"


@functools.lru_cache(maxsize=None)
def _signature(function) -> inspect.Signature:
    return inspect.signature(function)


def check_arguments(function, values: dict) -> None:
    """Refuse, as a UserError naming the argument, a value in ``values`` (``locals()`` at the top of
    ``function``: its arguments) that does not fit ``function``'s annotation (see the module's docstring).  Called
    inside the function, not around it, so that the warnings it attributes to its caller's line stay there."""
    for name, parameter in _signature(function).parameters.items():
        if parameter.kind in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD) or name not in values:
            continue
        problem = argument_problem(name, parameter.annotation, values[name], function.__globals__)
        if problem:
            raise UserError(f"{function.__name__}(): {problem}")
