"""The one exception type for errors a user can cause, and the small checks that raise it.

A :class:`UserError` is a ``ValueError`` (as python-control's exceptions subclass built-ins): code that catches
``ValueError`` around a servofmu call keeps working.  Its message names the culprit (file, variable, argument)
and fits on one line; the command line prints it and exits with status 2.  Anything else is a bug.
"""
from __future__ import annotations

import math
from numbers import Integral, Real

__all__ = ["UserError", "ServofmuWarning", "is_real", "check_int", "check_range", "check_positive",
           "check_optional_real", "name_problem", "MAX_NAME_LENGTH", "MAX_MAGNITUDE", "MAX_INT"]

# No number servofmu reads (a plant's parameter, a stored value) comes near this; anything beyond is a mistake, damage
# or a foreign file (and its square would overflow).
MAX_MAGNITUDE = 1e100

# Model names become C identifiers and file names (NAME.so inside an FMU, NAME.fmu): short enough for any file
# system and compiler.
MAX_NAME_LENGTH = 64


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


class ServofmuWarning(UserWarning):
    """A result that is stored but deserves a look (an experiment that reached no steady state), or a fallback
    taken (FMPy for a missing libcosim): issued with ``warnings.warn``, so that ``warnings.simplefilter("error",
    ServofmuWarning)`` makes it an error and ``"ignore"`` silences it."""


def is_real(x) -> bool:
    """Whether ``x`` is a finite real number (not a bool)."""
    return isinstance(x, Real) and not isinstance(x, bool) and math.isfinite(x)


MAX_INT = 2 ** 63 - 1  # the largest integer HDF5's int64 attributes, numpy's and torch's seeds all hold


def check_int(what: str, value, minimum: int, maximum: int = MAX_INT) -> None:
    """Refuse ``value`` unless it is an integer (not a bool) in [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, Integral) or not minimum <= value <= maximum:
        bound = f">= {minimum}" if maximum == MAX_INT else f"in [{minimum}, {maximum}]"
        raise UserError(f"{what} must be an integer {bound}, not {int(value) if isinstance(value, Integral) else value!r}")


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


def name_problem(name) -> str | None:
    """Why ``name`` cannot name a model (a plant, a controller: an FMU's model identifier, a C identifier and a
    file name), or None when it can."""
    if not isinstance(name, str) or not name.isascii() or not name.replace("_", "").isalnum() \
            or not name[:1].isalpha():
        return "must be an identifier (letters, digits, underscores; starts with a letter)"
    if len(name) > MAX_NAME_LENGTH:
        return f"must be at most {MAX_NAME_LENGTH} characters long, not {len(name)}"
    return None
