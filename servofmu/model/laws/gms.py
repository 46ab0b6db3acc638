"""The generalised Maxwell-slip (GMS) model: N elements in parallel, each a spring of stiffness k_i whose deflection
z_i sticks and slips at its share of the Stribeck curve s(v) (Al-Bender, Lampaert and Swevers 2005), written as an
ODE without modes: with r_i = k_i·z_i/(α_i·s(v)) the element's load on its slip level,

    dz_i/dt = v − v·C·max(0, sign(v)·r_i − 1 + 1/C),   F = Σ k_i·z_i + viscous,   i = 1..N

an element sticks (dz_i/dt = v, a spring) while its force is below (1 − 1/C) of its level α_i·s(v) or moves away
from it, and slips beyond, held at its level within a deflection of about α_i·s/(C·k_i).  Equal shares α_i = 1/N
and stiffnesses k_i = sigma0/(i·H_N) (H_N = 1 + 1/2 + … + 1/N): the rest stiffness is sigma0 for every N and the
breakaway deflections α_i·s/k_i spread linearly.  C is the key ``attraction`` (default 50, kept by fits).
docs/friction.md has the equations and why this form."""
from __future__ import annotations

from .base import FrictionLaw
from .keys import LawKey, LawState, power_of_two
from .stribeck import DELTA_KEY, STRIBECK, STRIBECK_KEYS, StribeckDivides, stribeck_level

__all__ = ["GMS", "GMS_LAW", "MAX_ELEMENTS", "element_stiffness", "ATTRACTION"]

# More elements add states (each a stiff ODE) without adding a parameter to identify: beyond 16 the loops are as
# smooth as data can tell, and every simulation and fit grows with N.
MAX_ELEMENTS = 16
ELEMENTS_KEY = LawKey("elements", "1", "number N of Maxwell-slip elements (a structure choice, 1 to 16)",
                      whole=(1, MAX_ELEMENTS), label="N")
# The slip's attraction C: an element holds its level within 1/C of it, and a closed minor loop returns onto the
# outer branch within a fraction of 1/C of the slip level (docs/friction.md); larger C is stiffer to integrate.
ATTRACTION = 50.0
ATTRACTION_KEY = LawKey("attraction", "1", "how sharply an element slips at its level: within 1/attraction of it "
                        "(>= 1; default 50; kept by fits)", default=ATTRACTION, positive=True, label="C")


def element_stiffness(sigma0, n: int) -> list:
    """The stiffnesses k_i = sigma0/(i·H_N) of the N elements (N/m; numbers or CasADi expressions): they add up to
    sigma0 and, with equal shares 1/N of the slip level, break away at deflections i·H_N·s/(N·sigma0)."""
    harmonic = sum(1.0 / i for i in range(1, n + 1))
    return [sigma0 / (i * harmonic) for i in range(1, n + 1)]


class GMS(StribeckDivides, FrictionLaw):
    """Generalised Maxwell-slip friction: N presliding elements on the Stribeck curve (N states)."""

    name = "gms"
    title = ("generalised Maxwell-slip: N elements (key elements) of total rest stiffness sigma0 slipping on the "
             "Stribeck curve (N states)")
    keys = STRIBECK_KEYS + (LawKey("sigma0", "N/m", "rest stiffness of the Maxwell-slip elements together (dF/dx at "
                                   "F = 0)", positive=True, label="σ0"), ATTRACTION_KEY, DELTA_KEY)
    structure = (ELEMENTS_KEY,)
    smoothing = False
    nested = "stribeck"  # stiff elements
    # N states, the stiffest slipping element ~100 times LuGre's bristle at the example's values: stepped sines take
    # 2.5 times LuGre's time with N = 4, 20 times with N = 16; not tried by a default selection (docs/friction.md)
    cost = 3
    fixed = ("attraction",)  # a property of the element's form, not of the axis: data barely tell it
    equations = ("k_i = sigma0/(i*H_N), H_N = sum_{j=1..N} 1/j;  s(v) = s+ for v >= 0, else s- (the Stribeck "
                 "curve fc + (fs - fc)*exp(-|v/vs|^delta));\nr_i = k_i*z_i*N/s(v);  dz_i/dt = v - v*C*max(0, "
                 "sign(v)*r_i - 1 + 1/C) (i = 1..N, C = attraction);  F = sum_i k_i*z_i + viscous")

    def states_for(self, values):
        """z1 … zN, N = ``values["elements"]``."""
        n = int(values["elements"])
        return tuple(LawState(f"z{i}", "m", f"deflection of Maxwell-slip element {i} of {n} (its force k{i}*z{i})")
                     for i in range(1, n + 1))

    def check(self, values, fail):
        """fs± ≥ fc± > 0, attraction ≥ 1."""
        STRIBECK.check(values, fail)
        if values["attraction"] < 1:
            fail("friction.attraction", f"must be at least 1, not {values['attraction']!r}")
        for key in ("fc_pos", "fc_neg"):
            if values[key] <= 0:
                fail(f"friction.{key}", "the Maxwell-slip model needs positive Coulomb friction on both sides")

    def force(self, par, v, states):
        """F (without the viscous term) and dz_i/dt of the N = len(states) elements."""
        import casadi as ca

        n, c = len(states), par["attraction"]
        level = ca.if_else(v >= 0, stribeck_level(par, "pos", v), stribeck_level(par, "neg", v)) / n
        forces = [k * z for k, z in zip(element_stiffness(par["sigma0"], n), states)]
        # v·max(…) is 0 at v = 0 from either side: the right-hand side is continuous (Lipschitz) in v and z
        return sum(forces[1:], forces[0]), [v - v * c * ca.fmax(0, ca.sign(v) * f / level - 1 + 1 / c)
                                            for f in forces]

    def steady_states(self, par, v, states, derivatives):
        """Each element at its level in steady sliding: z_i = sign(v)·s(v)/(N·k_i)."""
        import casadi as ca

        n = len(states)
        level = ca.if_else(v >= 0, stribeck_level(par, "pos", v), stribeck_level(par, "neg", v)) / n
        return [ca.sign(v) * level / k for k in element_stiffness(par["sigma0"], n)]

    def state_nominals(self, values):
        """Each element's deflection at sliding, i·H_N·min(fc)/(N·sigma0), to a power of two."""
        n = int(values["elements"])
        level = min(values["fc_pos"], values["fc_neg"]) / n
        out = []
        for k in element_stiffness(values["sigma0"], n):
            value = level / k if k > 0 else 0.0
            out.append(power_of_two(value) if 0 < value < float("inf") else 1.0)
        return tuple(out)

    def start_values(self, fc_pos, fc_neg, v_rms, mass):
        """Four elements, the Stribeck values of the Stribeck law's start, and elements deflecting by a thousandth
        of the RMS velocity's second at rest (LuGre's start)."""
        return {"elements": 4, "fs_pos": 1.5 * fc_pos, "fs_neg": 1.5 * fc_neg, "vs": 0.2 * v_rms,
                "sigma0": 0.5 * (fc_pos + fc_neg) / (1e-3 * v_rms)}


GMS_LAW = GMS()
