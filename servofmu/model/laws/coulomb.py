"""Coulomb friction: the levels fc± with a tanh sign, F = fc+·max(t, 0) + fc−·min(t, 0) + viscous, t = tanh(v/v_smooth)
(docs/friction.md)."""
from __future__ import annotations

from .base import FrictionLaw
from .keys import LawKey

__all__ = ["Coulomb", "LEVEL_KEYS", "COULOMB"]

LEVEL_KEYS = (
    LawKey("fc_pos", "N", "Coulomb friction for v > 0", label="Fc+"),
    LawKey("fc_neg", "N", "Coulomb friction for v < 0 (magnitude)", mirror="fc_pos", label="Fc−"),
)


class Coulomb(FrictionLaw):
    """Coulomb friction with a smoothed sign (the simplest law: every other contains it)."""

    name = "coulomb"
    title = "Coulomb levels fc± and viscous friction, sign(v) smoothed by tanh(v/v_smooth)"
    keys = LEVEL_KEYS
    cost = 0
    default_candidate = True
    equations = "t_s = tanh(v/v_smooth);  F = fc+*max(t_s, 0) + fc-*min(t_s, 0) + viscous"

    def force(self, par, v, states):
        """F (without the viscous term) and no state derivatives."""
        import casadi as ca

        th = ca.tanh(v / par["v_smooth"])
        return par["fc_pos"] * ca.fmax(th, 0) + par["fc_neg"] * ca.fmin(th, 0), []

    def levels_from(self, source, mean_level):
        """The Coulomb levels that are the mean of the richer law's steady curve (less its viscous term) over the
        data's speeds on either side (a Stribeck fit may hold the axis's level in fs with a Stribeck velocity
        above the speeds, and fc far below it); its own levels where a side has no speeds."""
        out = {"fc_pos": source["fc_pos"], "fc_neg": source["fc_neg"]}
        for key, sign in (("fc_pos", 1.0), ("fc_neg", -1.0)):
            level = mean_level(sign)
            if level is not None:
                out[key] = level
        return out


COULOMB = Coulomb()
