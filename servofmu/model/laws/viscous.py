"""The viscous term every law has: fv·v, or direction-dependent fv_pos·max(v, 0) + fv_neg·min(v, 0) where the
plant file gives ``fv_pos`` and ``fv_neg`` instead of ``fv`` (docs/friction.md).  Measured axes often move with
viscous coefficients that differ by tens of percent between the directions."""
from __future__ import annotations

from typing import Callable

from .keys import LawKey

__all__ = ["VISCOUS_KEYS", "viscous_keys", "viscous_force", "check_viscous", "viscous_levels", "FIXED_VISCOUS",
           "viscous_note"]

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


def viscous_note(values: dict[str, float], damping: float) -> str:
    """What an identified direction-dependent viscous friction means, in one line ("" for the symmetric form):
    fv_pos is the structure's, the data decided fv_neg − fv_pos, and G holds the common part; ``damping`` is the
    viscous damping a first-order G holds in its pole (N·s/m; 0 for other G)."""
    if "fv_pos" not in values:
        return ""
    pole = f"; G's pole holds {damping:.6g} N.s/m of damping" if damping else ""
    return (f"viscous friction: fv_pos {values['fv_pos']:.6g} N.s/m is the structure's (kept); the data decide "
            f"fv_neg - fv_pos = {values['fv_neg'] - values['fv_pos']:.6g} N.s/m; viscous friction common to both "
            f"directions beyond fv_pos is held by G{pole}")
