"""Dahl friction: presliding without a Stribeck curve, a deflection z with dz/dt = v − σ0·|v|·z/fc(v) (fc(v) = fc+ for
v ≥ 0, else fc−), F = σ0·z + viscous — Dahl's model (1968, 1976) with exponent 1, the force's slope in the position
σ0 at rest and falling to 0 as F reaches ±fc (docs/friction.md)."""
from __future__ import annotations

from .base import FrictionLaw
from .coulomb import LEVEL_KEYS
from .keys import LawKey, LawState, power_of_two

__all__ = ["Dahl", "DAHL"]


class Dahl(FrictionLaw):
    """Dahl friction: one state, the presliding hysteresis that Coulomb friction lacks."""

    name = "dahl"
    title = "Dahl: presliding of rest stiffness sigma0 approaching the Coulomb levels fc± (one state)"
    keys = LEVEL_KEYS + (LawKey("sigma0", "N/m", "rest stiffness of the Dahl model (dF/dx at F = 0)", positive=True,
                                label="σ0"),)
    states = (LawState("z", "m", "presliding deflection of the Dahl model (F = sigma0*z)"),)
    smoothing = False
    nested = "coulomb"  # a stiff rest stiffness
    cost = 2
    equations = "dz/dt = v - sigma0*|v|*z/fc(v) (fc = fc+ for v >= 0, else fc-);  F = sigma0*z + viscous"

    def low_open(self, name):
        """sigma0 and the Coulomb levels are positive (fc divides)."""
        return super().low_open(name) or name.startswith("fc_")

    def check(self, values, fail):
        """fc± > 0."""
        for key in ("fc_pos", "fc_neg"):
            if values[key] <= 0:
                fail(f"friction.{key}", "the Dahl model needs positive Coulomb friction on both sides")

    def force(self, par, v, states):
        """F (without the viscous term) and dz/dt."""
        import casadi as ca

        (z,) = states
        fc = ca.if_else(v >= 0, par["fc_pos"], par["fc_neg"])
        return par["sigma0"] * z, [v - par["sigma0"] * ca.fabs(v) * z / fc]

    def state_nominals(self, values):
        """The deflection at sliding, min(fc)/sigma0, to a power of two."""
        value = min(values["fc_pos"], values["fc_neg"]) / values["sigma0"]
        return (power_of_two(value) if value > 0 and value != float("inf") else 1.0,)

    def start_values(self, fc_pos, fc_neg, v_rms, mass):
        """A rest stiffness that deflects by a thousandth of the RMS velocity's second at the mean level."""
        return {"sigma0": 0.5 * (fc_pos + fc_neg) / (1e-3 * v_rms)}


DAHL = Dahl()
