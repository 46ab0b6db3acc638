"""Which parameters the identifier estimates, and the prior it draws training plants from.

Identified: the poles, the zeros, the gain (`dc_gain` or `gain`) and the friction levels (`fc_pos`, `fc_neg`,
and `fs_pos`, `fs_neg`, `vs`, `sigma0`, `sigma1` where the model has them).  Fixed at the structure's values:
`v_smooth` (a modelling choice, not a property of the machine) and `fv`: viscous friction adds a constant to
1/G(jω), which a G with free poles and zeros absorbs exactly — G/(1 + fv·G) has as many poles and zeros as G —
so fv cannot be told apart from G by any input-output data and is taken from the structure file.  A spring's rest
position x0 is fixed too when the load also has an offset: k·(x0 − x) = k·x0 − k·x, and the constant k·x0 is an
offset.  A symmetric friction (``symmetric = true``, docs/plant-format.md) has one level per kind: fc_neg and
fs_neg are not estimated but equal fc_pos and fs_pos in every parameter vector (:func:`full_vectors`).

The prior (docs/identification.md): around the structure's nominal plant, every identified quantity is scaled by
an independent log-uniform factor in [1/(1+spread), 1+spread]:
- a real pole or zero: its magnitude (sign kept);
- a complex pair σ ± jω: its natural frequency |σ + jω| and its damping ratio −σ/|σ + jω| (the damping ratio
  capped at 0.95 so that the pair stays complex);
- the gain: its magnitude;
- each friction level; a static level is drawn as fc + (fs − fc)·factor so that fs ≥ fc holds;
- the load's stiffness, ripple amplitude and ripple period (docs/plant-format.md) likewise by a factor — the
  period's only within [1/(1+spread/20), 1+spread/20] (PERIOD_SHARE): the output error is many-valleyed in the
  period (a relative error of period/travel slips the ripple by a whole period over the travel), and a ripple's
  pitch is known from the motor's geometry to far better than the other parameters; its signed
  terms — the offset, the spring's rest position x0 and the ripple's phase — by adding a uniform draw in
  [−spread, spread] times their scale (:func:`additive_scale`): the offset's the larger of its magnitude and the
  friction level, x0's the larger of its magnitude and the distance over which the spring's force changes by the
  friction level, the phase's π (at most ±π).
Real roots are stored in descending order (−1 before −10), so that a parameter vector names one plant only.
"""
from __future__ import annotations

import numpy as np

from ..errors import UserError
from ..model.laws.viscous import FIXED_VISCOUS
from ..model.plant import Plant

__all__ = ["above_levels", "identified_names", "identified_mask", "check_identifiable", "full_vectors", "full_entries",
           "canonical_order",           "sample_identified", "FIXED_PARAMETERS", "fixed_names", "ADDITIVE_PARAMETERS", "additive_scale",
           "PERIOD_SHARE", "log_width"]

# fv (or fv_pos of a direction-dependent viscous friction: only fv_neg − fv_pos is told apart from G) and v_smooth
FIXED_PARAMETERS = FIXED_VISCOUS + ("v_smooth",)
# Signed parameters, drawn and searched on a linear scale around the structure's value (a sign may change).
ADDITIVE_PARAMETERS = ("offset", "x0", "ripple_phase")
# The share of the spread the ripple's period is drawn and searched within (see the module docstring).
PERIOD_SHARE = 0.05


def log_width(name: str, spread: float) -> float:
    """Half-width of the log-uniform factor of a parameter drawn by a factor: log(1 + spread), the ripple
    period's log(1 + PERIOD_SHARE·spread)."""
    return float(np.log1p(spread * (PERIOD_SHARE if name == "ripple_period" else 1.0)))


def additive_scale(structure: Plant, name: str) -> float:
    """The scale of an additive parameter's prior (see the module docstring): N for ``offset``, m for ``x0``,
    rad for ``ripple_phase``."""
    nominal = structure.parameters()
    friction = max(structure.friction.fc_pos, structure.friction.fc_neg, 1e-9)
    if name == "offset":
        return max(abs(nominal["offset"]), friction)
    if name == "x0":
        stiffness = nominal["stiffness"]
        return max(abs(nominal["x0"]), friction / stiffness if stiffness > 0 else 0.0, 1e-9)
    if name == "ripple_phase":
        return float(np.pi)
    raise UserError(f"{name} is not an additive parameter ({', '.join(ADDITIVE_PARAMETERS)})")


def fixed_names(structure: Plant) -> tuple[str, ...]:
    """The structure's parameters a fit keeps at the structure's values: fv and v_smooth (fv_pos of a
    direction-dependent viscous friction), those its friction law fixes (FrictionLaw.fixed), a spring's x0 when
    the load also has an offset (the spring's force k·(x0 − x) holds the constant k·x0, which the offset is), and
    those the structure file's ``fixed`` list names."""
    names = structure.parameter_names()
    implied = FIXED_PARAMETERS + structure.friction.law.fixed + (("x0",) if "offset" in names else ())
    return implied + tuple(n for n in structure.fixed if n not in implied)


def identified_names(structure: Plant) -> list[str]:
    """The names of the parameters a fit identifies: all of the structure's but the fixed ones (fixed_names) and
    a symmetric friction's levels for v < 0 (they equal those for v > 0)."""
    left_out = set(fixed_names(structure)) | set(structure.friction.mirrored())
    return [n for n in structure.parameter_names() if n not in left_out]


def check_identifiable(structure: Plant, option: str = "--structure") -> None:
    """Refuse a structure whose ``fixed`` list leaves no parameter to identify (the search would have no
    dimension), naming its file, the key and ``option``."""
    if not identified_names(structure):
        raise UserError(f"{structure.source}: fixed: lists every parameter a fit could identify "
                        f"({', '.join(structure.fixed)}): nothing is left to identify with this {option}; leave at "
                        "least one out of `fixed`")


def above_levels(structure: Plant) -> dict[str, str]:
    """The identified levels that are at least another identified level (FrictionLaw.at_least: a static level fs±
    above its Coulomb level fc±), each with that level; the prior draws and the swarm searches them as the lower
    level plus a positive gap."""
    names = identified_names(structure)
    return {a: b for a, b in structure.friction.law.at_least() if a in names and b in names}


def identified_mask(structure: Plant) -> np.ndarray:
    """Boolean mask over ``structure.parameter_names()``: True for the identified parameters."""
    identified = set(identified_names(structure))
    return np.array([n in identified for n in structure.parameter_names()])


def full_vectors(structure: Plant, theta: np.ndarray) -> np.ndarray:
    """Complete parameter vectors (all of parameter_names) from identified ones (rows of ``theta``): the fixed
    parameters at the structure's values, a symmetric friction's levels for v < 0 equal to those for v > 0."""
    theta = np.atleast_2d(theta)
    full = np.tile(structure.parameter_vector(), (theta.shape[0], 1))
    full[:, identified_mask(structure)] = theta
    names = structure.parameter_names()
    for neg, pos in structure.friction.mirrored().items():
        full[:, names.index(neg)] = full[:, names.index(pos)]
    return full


def full_entries(structure: Plant, theta) -> list:
    """The entries of a complete parameter vector from an indexable ``theta`` of identified parameters (e.g. a
    CasADi symbol): as :func:`full_vectors`, for one vector of any element type."""
    names, nominal = structure.parameter_names(), structure.parameter_vector()
    index = {n: i for i, n in enumerate(identified_names(structure))}
    mirrored = structure.friction.mirrored()
    return [theta[index[mirrored.get(n, n)]] if mirrored.get(n, n) in index else float(value)
            for n, value in zip(names, nominal)]


def canonical_order(structure: Plant, theta: np.ndarray) -> np.ndarray:
    """Sort runs of real roots (poles, then zeros) in descending order in each row of ``theta``."""
    theta = np.array(np.atleast_2d(theta), dtype=float)
    names = identified_names(structure)
    for prefix in ("pole", "zero"):
        cols = [i for i, n in enumerate(names) if n.startswith(prefix) and "_" not in n]
        if len(cols) > 1:
            theta[:, cols] = -np.sort(-theta[:, cols], axis=1)
    return theta


def sample_identified(structure: Plant, n: int, spread: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` identified-parameter vectors drawn from the prior around ``structure`` (shape n × len(identified))."""
    if not spread > 0:
        raise UserError(f"spread must be positive, not {spread}")
    names, above = identified_names(structure), above_levels(structure)
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    log_f = np.log1p(spread)

    def factor(width=log_f):
        return np.exp(rng.uniform(-width, width, size=n))

    out = np.empty((n, len(names)))
    for i, name in enumerate(names):
        if name.endswith("_im"):
            continue  # drawn with its real part
        if name.endswith("_re"):
            re, im = nominal[name], nominal[name[:-3] + "_im"]
            wn, zeta = np.hypot(re, im) * factor(), min(-re / np.hypot(re, im), 0.95) * factor()
            zeta = np.minimum(zeta, 0.95)
            out[:, i], out[:, i + 1] = -zeta * wn, wn * np.sqrt(1 - zeta**2)
        elif name in above:
            continue  # after its lower level
        elif name in ADDITIVE_PARAMETERS:
            half = spread if name != "ripple_phase" else min(spread, 1.0)
            out[:, i] = nominal[name] + additive_scale(structure, name) * rng.uniform(-half, half, size=n)
        else:
            out[:, i] = nominal[name] * factor(log_width(name, spread))
    for name, lower in above.items():
        gap = nominal[name] - nominal[lower]
        out[:, names.index(name)] = out[:, names.index(lower)] + gap * factor()
    return canonical_order(structure, out)
