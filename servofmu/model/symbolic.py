"""The servo plant as one CasADi symbolic model.

This is the single source of the equations (docs/model.md): the FMU's C code,
the batch simulator and the least-squares fits are all generated from the
expressions built here.

States, in order: the realisation of G(s) (``xi1..xin``), ``position``, and the
friction law's own (servofmu.model.laws: LuGre's and Dahl's deflection ``z``).  G is driven by w = u + excitation − F(v) +
the load's force (offset, spring and ripple, functions of the position).  G is realised in observable canonical form
with a constant diagonal scaling: with den(s) = sⁿ + a₍ₙ₋₁₎sⁿ⁻¹ + … + a₀ and
num(s) = b₍ₙ₋₁₎sⁿ⁻¹ + … + b₀ the unscaled form is

    x1' = −a₍ₙ₋₁₎x1 + x2 + b₍ₙ₋₁₎w,  …,  xn' = −a₀x1 + b₀w,   v = x1,

and ``xi_k = x_k / c^(k-1)``, c being the geometric mean of the nominal pole
magnitudes rounded to a power of two (plant.state_scale), so that every state is
of the order of v (good for absolute tolerances).  c is a constant of the model,
not a parameter: changing a pole keeps the realisation exact.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from .laws.viscous import viscous_force
from .plant import Plant, parameter_info, state_scale

__all__ = ["SymbolicModel", "build_model", "friction_force", "load_force", "EXCITATION_PARAMETERS", "OUTPUT_NAMES",
           "OUTPUT_INFO", "INPUT_INFO"]

EXCITATION_PARAMETERS = ("excitation_amplitude", "excitation_frequency")
OUTPUT_NAMES = ("v", "position", "friction_force")
OUTPUT_INFO = {
    "v": ("m/s", "velocity, the output of G(s)"),
    "position": ("m", "position, the integral of v"),
    "friction_force": ("N", "friction force F(v) opposing the motion"),
}
INPUT_INFO = ("N", "force input u; the plant is driven by u + excitation_amplitude*sin(2*pi*excitation_frequency*t)")


@dataclass(frozen=True)
class SymbolicModel:
    """Symbols and expressions of one plant structure.

    Attributes: ``t`` (1), ``x`` (nx states), ``u`` (1 input), ``p`` (np
    parameters: the plant's ``parameter_names()`` then the two excitation
    parameters), ``xdot`` (nx), ``y`` (3 outputs: v, position, friction_force).
    """

    plant: Plant
    t: ca.SX
    x: ca.SX
    u: ca.SX
    p: ca.SX
    xdot: ca.SX
    y: ca.SX
    state_names: tuple[str, ...]
    state_scale: float

    @property
    def parameter_names(self) -> list[str]:
        """The names of ``p``: the plant's parameters, then excitation_amplitude and excitation_frequency."""
        return self.plant.parameter_names() + list(EXCITATION_PARAMETERS)

    def parameter_start(self, excitation_amplitude: float = 0.0, excitation_frequency: float = 1.0) -> np.ndarray:
        """Values of ``p``: the plant's, then the excitation's amplitude (N) and frequency (Hz)."""
        return np.concatenate([self.plant.parameter_vector(), [excitation_amplitude, excitation_frequency]])

    def parameter_info(self, name: str) -> tuple[str, str]:
        """(unit, description) of a parameter of this model (servofmu.model.plant.parameter_info)."""
        return parameter_info(name, self.plant)

    @property
    def nx(self) -> int:
        """Number of states."""
        return self.x.numel()

    @property
    def np(self) -> int:
        """Number of parameters (with the two excitation parameters)."""
        return self.p.numel()

    def _fn(self, name, outputs, out_names):
        return ca.Function(name, [self.t, self.x, self.u, self.p], outputs, ["t", "x", "u", "p"], out_names)

    @cached_property
    def ode(self) -> ca.Function:
        """ode(t, x, u, p) -> xdot"""
        return self._fn("ode", [self.xdot], ["xdot"])

    @cached_property
    def outputs(self) -> ca.Function:
        """outputs(t, x, u, p) -> y = [v, position, friction_force]"""
        return self._fn("outputs", [self.y], ["y"])

    @cached_property
    def ode_jacobian(self) -> ca.Function:
        """ode_jacobian(t, x, u, p) -> (dxdot/dx, dxdot/dt): what a Rosenbrock step needs."""
        return self._fn("ode_jacobian", [ca.jacobian(self.xdot, self.x), ca.jacobian(self.xdot, self.t)],
                        ["J", "ft"])

    @cached_property
    def io_jacobian(self) -> ca.Function:
        """io_jacobian(t, x, u, p) -> d[xdot; y]/d[x; u], for FMI directional derivatives."""
        return self._fn("io_jacobian", [ca.jacobian(ca.vertcat(self.xdot, self.y), ca.vertcat(self.x, self.u))],
                        ["J"])

    def rhs(self, t, x, u, p) -> np.ndarray:
        """dx/dt at time t (s), states x, input force u (N) and parameters p, as a flat array."""
        return np.asarray(self.ode(t, x, u, p)).ravel()


def _poly_mul(a: list, b: list) -> list:
    out = [0] * (len(a) + len(b) - 1)
    for i, ai in enumerate(a):
        for j, bj in enumerate(b):
            out[i + j] = out[i + j] + ai * bj
    return out


def _root_factors(symbols, template) -> tuple[list, list]:
    """Polynomial (highest power first) of the roots given by ``symbols`` following ``template``'s pattern."""
    poly, it = [1], iter(symbols)
    for r in template:
        if r.imag != 0:
            re, im = next(it), next(it)
            poly = _poly_mul(poly, [1, -2 * re, re * re + im * im])
        else:
            poly = _poly_mul(poly, [1, -next(it)])
    return poly, list(it)


def friction_force(plant: Plant, par: dict, v, states=()):
    """F(v) and the derivatives of the friction law's states (a list, empty for a law without states) as CasADi
    expressions: the law's force (servofmu.model.laws) plus the viscous term; ``par`` maps friction keys to
    expressions, ``states`` holds the law's state symbols."""
    force, dstates = plant.friction.law.force(par, v, list(states))
    return force + viscous_force(par, v), list(dstates)


def load_force(plant: Plant, par: dict, position):
    """The force on the load besides friction (plant.load), adding to u, as a CasADi expression; None without a
    load.  ``par`` maps load keys to expressions; terms the plant does not have are left out, so a plant without
    a load has the equations (and the generated code) it had before loads existed."""
    load, terms = plant.load, []
    if load.offset is not None:
        terms.append(par["offset"])
    if load.stiffness is not None:
        terms.append(-par["stiffness"] * (position - par["x0"]))
    if load.ripple_amplitude is not None:
        terms.append(par["ripple_amplitude"] * ca.sin(2 * np.pi * position / par["ripple_period"]
                                                      + par["ripple_phase"]))
    return sum(terms[1:], terms[0]) if terms else None


def build_model(plant: Plant) -> SymbolicModel:
    """The CasADi model of ``plant``'s structure: states, the ODE right-hand side and the outputs (v, position,
    friction_force) as expressions of symbolic parameters (its values are only the start values)."""
    names = plant.parameter_names() + list(EXCITATION_PARAMETERS)
    p = ca.SX.sym("p", len(names))
    par = {name: p[i] for i, name in enumerate(names)}
    n_pole = len([n for n in names if n.startswith("pole")])
    n_zero = len([n for n in names if n.startswith("zero")])
    den, _ = _root_factors([p[i] for i in range(n_pole)], plant.poles)
    zpoly, _ = _root_factors([p[n_pole + i] for i in range(n_zero)], plant.zeros)
    n = len(den) - 1
    if plant.dc_gain is not None:
        k = par["dc_gain"] * den[-1] / zpoly[-1]
    else:
        k = par["gain"]
    num = [0] * (n - len(zpoly)) + [k * c for c in zpoly]  # length n, highest power s^(n-1) first

    c = state_scale(plant)

    t, u = ca.SX.sym("t"), ca.SX.sym("u")
    xi = ca.SX.sym("xi", n)
    position = ca.SX.sym("position")
    states = [xi, position]
    state_names = [f"xi{i + 1}" for i in range(n)] + ["position"]
    law_states = [ca.SX.sym(state.name) for state in plant.friction.states()]
    states += law_states
    state_names += [state.name for state in plant.friction.states()]
    x = ca.vertcat(*states)

    v = xi[0]
    force, dstates = friction_force(plant, par, v, law_states)
    u_total = u + par["excitation_amplitude"] * ca.sin(2 * np.pi * par["excitation_frequency"] * t)
    w = u_total - force
    external = load_force(plant, par, position)
    if external is not None:
        w = w + external
    # den[j] is the coefficient of s^(n-j): a_(n-k) = den[k]; num[j] likewise b_(n-1-j).
    dxi = []
    for k_ in range(1, n + 1):
        scale = c ** (k_ - 1)
        expr = (-den[k_] * v + num[k_ - 1] * w) / scale
        if k_ < n:
            expr = expr + c * xi[k_]
        dxi.append(expr)
    xdot = ca.vertcat(*dxi, v, *dstates)
    y = ca.vertcat(v, position, force)
    return SymbolicModel(plant=plant, t=t, x=x, u=u, p=p, xdot=xdot, y=y,
                         state_names=tuple(state_names), state_scale=c)
