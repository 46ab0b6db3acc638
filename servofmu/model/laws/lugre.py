"""LuGre friction: a bristle deflection z with dz/dt = v − σ0·|v|·z/g(v) (g the Stribeck curve of the side of v),
F = σ0·z + σ1·dz/dt + viscous (Canudas de Wit et al. 1995; docs/friction.md)."""
from __future__ import annotations

import math

from .base import FrictionLaw
from .keys import LawKey, LawState, power_of_two
from .stribeck import DELTA_KEY, STRIBECK, STRIBECK_KEYS, StribeckDivides, stribeck_level

__all__ = ["LuGre", "LUGRE"]


class LuGre(StribeckDivides, FrictionLaw):
    """LuGre friction: presliding and the Stribeck curve, one state."""

    name = "lugre"
    title = "LuGre: bristles of stiffness sigma0 and damping sigma1 on the Stribeck curve (one state)"
    keys = STRIBECK_KEYS + (LawKey("sigma0", "N/m", "LuGre bristle stiffness", positive=True, label="σ0"),
                            LawKey("sigma1", "N.s/m", "LuGre bristle damping", label="σ1"), DELTA_KEY)
    states = (LawState("z", "m", "bristle deflection of the LuGre model"),)
    smoothing = False  # no tanh: no v_smooth
    nested = "stribeck"  # stiff bristles
    cost = 2
    default_candidate = True
    equations = ("dz/dt = v - sigma0*|v|*z/g(v) (g = g+ for v >= 0, else g-; g+- the Stribeck curve);  "
                 "F = sigma0*z + sigma1*dz/dt + viscous")

    def check(self, values, fail):
        """fs± ≥ fc± > 0."""
        STRIBECK.check(values, fail)
        if values["fc_pos"] <= 0 or values["fc_neg"] <= 0:
            fail("friction.fc_pos", "LuGre needs positive Coulomb friction on both sides")

    def force(self, par, v, states):
        """F (without the viscous term) and dz/dt."""
        import casadi as ca

        (z,) = states
        g_v = ca.if_else(v >= 0, stribeck_level(par, "pos", v), stribeck_level(par, "neg", v))
        dz = v - par["sigma0"] * ca.fabs(v) * z / g_v
        return par["sigma0"] * z + par["sigma1"] * dz, [dz]

    def state_nominals(self, values):
        """The deflection at sliding, min(fc)/sigma0, to a power of two (1 where that is not positive)."""
        if not values.get("sigma0"):
            return (1.0,)
        value = min(values["fc_pos"], values["fc_neg"]) / values["sigma0"]
        return (power_of_two(value) if value > 0 and value != float("inf") else 1.0,)

    def start_values(self, fc_pos, fc_neg, v_rms, mass):
        """The Stribeck values, and bristles deflecting by a thousandth of the RMS velocity's second at rest,
        critically damped on G's high-frequency mass."""
        sigma0 = 0.5 * (fc_pos + fc_neg) / (1e-3 * v_rms)
        return {"fs_pos": 1.5 * fc_pos, "fs_neg": 1.5 * fc_neg, "vs": 0.2 * v_rms, "sigma0": sigma0,
                "sigma1": 2.0 * math.sqrt(sigma0 * mass)}


LUGRE = LuGre()
