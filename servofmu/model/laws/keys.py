"""The pieces a friction law is declared with: its plant-file keys and its internal states."""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["LawKey", "LawState", "SMOOTHING_KEY", "power_of_two"]


@dataclass(frozen=True)
class LawKey:
    """One key of a plant file's ``[friction]`` section: its ``name`` (also the parameter's, the FMU variable's
    and the JSON field's), ``unit`` (ASCII, an FMU unit name; "1" for none), ``description``, ``default`` (the
    value where the file leaves the key out; None: required), ``positive`` (> 0, else ≥ 0), ``mirror`` (a level
    for v < 0: the level for v > 0 a symmetric friction copies), ``optional`` (a parameter only where the file
    gives it: without it the law has its default form, e.g. Stribeck's exponent 2), ``label`` (the result
    table's row label) and ``whole`` ((low, high): a structure choice, a whole number from low to high, e.g. the
    number of Maxwell-slip elements — no parameter: it sets the model's states, no fit changes it)."""

    name: str
    unit: str
    description: str
    default: float | None = None
    positive: bool = False
    mirror: str | None = None
    optional: bool = False
    label: str | None = None
    whole: tuple[int, int] | None = None


@dataclass(frozen=True)
class LawState:
    """An internal state of a friction law (a bristle deflection): name, unit and description, as the FMU
    declares it; it starts at 0."""

    name: str
    unit: str
    description: str


SMOOTHING_KEY = LawKey("v_smooth", "m/s", "velocity scale of the tanh smoothing of sign(v)", default=1e-3,
                       positive=True)


def power_of_two(value: float) -> float:
    """The power of two nearest ``value`` (> 0) in log: scaling by it is exact in floating point."""
    return float(2.0 ** round(math.log2(value)))
