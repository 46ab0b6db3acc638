"""The public functions' arguments checked against their annotations, so that an obviously wrong one (a number
for a file name, a name for a Plant) is a :class:`~servofmu.errors.UserError` naming the argument, not a
``TypeError`` or ``AttributeError`` from deep inside.

Only annotations made of simple names are checked (``str | Path``, ``Plant``, ``Result | None``, ``float``);
anything else (``np.ndarray``, ``Sequence[str]``, ``dict``) is left to the function, which checks its values.
The package's ``__getattr__`` wraps the API's functions with :func:`checked`; the library's own calls go to the
unwrapped functions.
"""
from __future__ import annotations

import functools
import inspect
import os
from numbers import Integral, Real

from .errors import UserError

__all__ = ["checked", "argument_problem"]

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


def checked(func):
    """``func`` with its arguments checked against its annotations first (see the module's docstring)."""
    if not inspect.isfunction(func):
        return func
    signature = inspect.signature(func)
    plain = {n for n, p in signature.parameters.items() if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)}

    @functools.wraps(func)
    def call(*args, **kwargs):
        try:
            bound = signature.bind(*args, **kwargs)
        except TypeError:  # a missing or unknown argument: Python's own TypeError, raised by the call itself
            return func(*args, **kwargs)
        for name, value in bound.arguments.items():
            problem = name in plain and argument_problem(name, signature.parameters[name].annotation, value,
                                                         func.__globals__)
            if problem:
                raise UserError(f"{func.__name__}(): {problem}")
        return func(*args, **kwargs)

    return call
