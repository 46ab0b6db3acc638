"""The one exception type for errors a user can cause, and the small checks that raise it.

A :class:`UserError` is a ``ValueError`` (as python-control's exceptions subclass built-ins): code that catches
``ValueError`` around a servofmu call keeps working.  Its message names the culprit (file, variable, argument)
and fits on one line; the command line prints it and exits with status 2.  Anything else is a bug.
"""
from __future__ import annotations

import math
from numbers import Integral, Real

__all__ = ["UserError", "is_real", "check_int", "check_range", "check_positive", "check_optional_real"]


class UserError(ValueError):
    """An error caused by input: a bad file, option, variable name or data.

    Parameters
    ----------
    message : str
        What is wrong, naming the culprit, on one line.

    Examples
    --------
    >>> from servofmu import UserError, load_plant
    >>> try:
    ...     load_plant("no-such-plant")
    ... except UserError as exc:
    ...     print(str(exc).split(":")[0])
    no-such-plant
    """


def is_real(x) -> bool:
    """Whether ``x`` is a finite real number (not a bool)."""
    return isinstance(x, Real) and not isinstance(x, bool) and math.isfinite(x)


def check_int(what: str, value, minimum: int) -> None:
    """Refuse ``value`` unless it is an integer (not a bool) of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < minimum:
        raise UserError(f"{what} must be an integer >= {minimum}, not {value!r}")


def check_range(what: str, value, lo: float, hi: float) -> None:
    """Refuse ``value`` unless it is a finite real number in [lo, hi]."""
    if not (is_real(value) and lo <= value <= hi):
        raise UserError(f"{what} must be in [{lo:g}, {hi:g}], not {value!r}")


def check_positive(what: str, value) -> None:
    """Refuse ``value`` unless it is a finite real number above 0."""
    if not (is_real(value) and value > 0):
        raise UserError(f"{what} must be a positive number, not {value!r}")


def check_optional_real(what: str, value) -> None:
    """Refuse ``value`` unless it is None or a finite real number."""
    if value is not None and not is_real(value):
        raise UserError(f"{what} must be a finite number or None, not {value!r}")
