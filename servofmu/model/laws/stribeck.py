"""Stribeck friction: levels falling from the static fs± to the Coulomb fc± as the speed grows,
g±(v) = fc± + (fs± − fc±)·exp(−|v/vs|^δ) (δ = 2 without the key ``delta``), F = g+·max(t, 0) + g−·min(t, 0)
+ viscous, t = tanh(v/v_smooth) (docs/friction.md)."""
from __future__ import annotations

from .base import FrictionLaw
from .coulomb import LEVEL_KEYS
from .keys import LawKey

__all__ = ["Stribeck", "StribeckDivides", "STRIBECK_KEYS", "DELTA_KEY", "stribeck_level", "STRIBECK"]

STRIBECK_KEYS = LEVEL_KEYS + (
    LawKey("fs_pos", "N", "static (breakaway) friction for v > 0", label="Fs+"),
    LawKey("fs_neg", "N", "static (breakaway) friction for v < 0 (magnitude)", mirror="fs_pos", label="Fs−"),
    LawKey("vs", "m/s", "Stribeck velocity", positive=True),
)
# The shape exponent: optional, so that a plant without it has exactly the Gaussian curve (and code) of before.
DELTA_KEY = LawKey("delta", "1", "shape exponent of the Stribeck curve exp(-|v/vs|^delta) (2 without the key)",
                   positive=True, optional=True, label="δ")


def stribeck_level(par: dict, side: str, v):
    """g(v) of one side ("pos" or "neg") as a CasADi expression: fc + (fs − fc)·exp(−|v/vs|^δ), with the
    Gaussian (v/vs)² where ``par`` has no ``delta``."""
    import casadi as ca

    fc = par[f"fc_{side}"]
    if "delta" not in par:
        return fc + (par[f"fs_{side}"] - fc) * ca.exp(-(v / par["vs"]) ** 2)
    r = ca.fabs(v / par["vs"])
    # |r|^δ has an infinite slope at 0 for δ < 1: the guard keeps the derivative at v = 0 finite (0·inf)
    bump = ca.if_else(r > 0, ca.exp(-ca.if_else(r > 0, r, 1) ** par["delta"]), 1)
    return fc + (par[f"fs_{side}"] - fc) * bump


class StribeckDivides:
    """The value rules of a law whose state equation divides by its Stribeck curve (LuGre, Maxwell-slip): mix it in
    before FrictionLaw."""

    def low_open(self, name):
        """sigma0, vs and the Coulomb levels are positive (the curve divides)."""
        return super().low_open(name) or name.startswith("fc_")

    def at_least(self):
        """Static friction is not below Coulomb friction."""
        return (("fs_pos", "fc_pos"), ("fs_neg", "fc_neg"))


class Stribeck(FrictionLaw):
    """Stribeck friction with a smoothed sign."""

    name = "stribeck"
    title = "Stribeck curve fc± + (fs± − fc±)·exp(−|v/vs|^δ), δ = 2 by default; viscous; tanh sign"
    keys = STRIBECK_KEYS + (DELTA_KEY,)
    nested = "coulomb"  # fs = fc
    cost = 1
    default_candidate = True
    equations = ("t_s = tanh(v/v_smooth),  g+-(v) = fc+- + (fs+- - fc+-)*exp(-|v/vs|^delta)  (delta = 2 by default)\n"
                 "F = g+(v)*max(t_s, 0) + g-(v)*min(t_s, 0) + viscous")

    def at_least(self):
        """Static friction is not below Coulomb friction."""
        return (("fs_pos", "fc_pos"), ("fs_neg", "fc_neg"))

    def check(self, values, fail):
        """fs± ≥ fc±."""
        for side in ("pos", "neg"):
            if values[f"fs_{side}"] < values[f"fc_{side}"]:
                fail(f"friction.fs_{side}", f"static friction must not be below Coulomb friction fc_{side}")

    def force(self, par, v, states):
        """F (without the viscous term) and no state derivatives."""
        import casadi as ca

        th = ca.tanh(v / par["v_smooth"])
        return stribeck_level(par, "pos", v) * ca.fmax(th, 0) + stribeck_level(par, "neg", v) * ca.fmin(th, 0), []

    def start_values(self, fc_pos, fc_neg, v_rms, mass):
        """Static friction 1.5·fc, Stribeck velocity a fifth of the RMS velocity."""
        return {"fs_pos": 1.5 * fc_pos, "fs_neg": 1.5 * fc_neg, "vs": 0.2 * v_rms}


STRIBECK = Stribeck()
