"""The viscous term every law has: fv·v, or direction-dependent fv_pos·max(v, 0) + fv_neg·min(v, 0) where the
plant file gives ``fv_pos`` and ``fv_neg`` instead of ``fv`` (docs/friction.md).  Measured axes often move with
viscous coefficients that differ by tens of percent between the directions."""
from __future__ import annotations

from typing import Callable

from .keys import LawKey

__all__ = ["VISCOUS_KEYS", "viscous_keys", "viscous_force", "check_viscous", "viscous_levels", "FIXED_VISCOUS"]

VISCOUS_KEYS = (
    LawKey("fv", "N.s/m", "viscous friction coefficient", default=0.0),
    LawKey("fv_pos", "N.s/m", "viscous friction coefficient for v > 0 (direction-dependent form)", optional=True),
    LawKey("fv_neg", "N.s/m", "viscous friction coefficient for v < 0 (direction-dependent form)", optional=True),
)
# Viscous friction common to both directions adds a constant to 1/G(jω), which a G with free poles and zeros
# absorbs exactly: a fit keeps fv (or fv_pos) at the structure's value and identifies the difference fv_neg − fv_pos.
FIXED_VISCOUS = ("fv", "fv_pos")


def viscous_keys(has: Callable[[str], bool]) -> tuple[str, ...]:
    """The viscous parameter names of a friction: ("fv_pos", "fv_neg") where it has the direction-dependent form
    (``has("fv_pos")``), else ("fv",)."""
    return ("fv_pos", "fv_neg") if has("fv_pos") else ("fv",)


def viscous_force(par: dict, v):
    """The viscous force (N) as a CasADi expression of the velocity ``v`` (m/s)."""
    if "fv_pos" in par:
        import casadi as ca

        return par["fv_pos"] * ca.fmax(v, 0) + par["fv_neg"] * ca.fmin(v, 0)
    return par["fv"] * v


def check_viscous(table: dict, fail) -> None:
    """Refuse a plant file's mixed or half-given viscous keys (``fail(key, why)`` raises)."""
    if "fv_neg" in table and "fv_pos" not in table:
        fail("friction.fv_neg", "direction-dependent viscous friction needs fv_pos too (or give fv alone)")
    if "fv_pos" in table and "fv_neg" not in table:
        fail("friction.fv_pos", "direction-dependent viscous friction needs fv_neg too (or give fv alone)")
    if "fv_pos" in table and "fv" in table:
        fail("friction.fv", "give either fv or fv_pos and fv_neg, not both")


def viscous_levels(values: dict[str, float]) -> tuple[float, float]:
    """(coefficient for v > 0, coefficient for v < 0) in N·s/m of a friction's values."""
    if "fv_pos" in values:
        return values["fv_pos"], values["fv_neg"]
    return values["fv"], values["fv"]
