"""The two maps the ANN works in (shared by the training set, training and the identifier).

- features of one data set: per experiment log|H|, cos∠H, sin∠H and dc/(|H|·m) — scale-free and continuous;
- targets: each identified parameter in a transformed scale (log of a magnitude where the structure's value is
  not zero, log of the damping ratio and natural frequency for a complex pair, log(fs − fc) for static friction (a level above another, FrictionLaw.at_least);
  the load's signed terms — offset, x0, ripple_phase — as they are).
  The swarm searches in these coordinates too: a box in them is relative, and positivity is kept.
"""
from __future__ import annotations

import numpy as np

from ..model.plant import Plant
from .prior import ADDITIVE_PARAMETERS, above_levels, additive_scale, identified_mask, identified_names, log_width

__all__ = ["feature_names", "ann_features", "to_targets", "from_targets", "target_jacobian", "prior_box"]


# ---------------------------------------------------------------------------
def feature_names(n_exp: int) -> list[str]:
    """The names of the 4·n_exp ANN features, in :func:`ann_features` order (per experiment log|H|, cos∠H, sin∠H
    and the mean velocity relative to the amplitude)."""
    return [f"{q}[{k}]" for k in range(n_exp) for q in ("log_abs_H", "cos_arg_H", "sin_arg_H", "dc_ratio")]


def ann_features(H: np.ndarray, dc: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
    """(N, 4·n_exp) features from H and dc of shape (N, n_exp)."""
    H, dc = np.atleast_2d(H), np.atleast_2d(dc)
    mag = np.abs(H)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.stack([np.log(mag), H.real / mag, H.imag / mag, dc / (mag * amplitudes)], axis=-1)
    return f.reshape(H.shape[0], -1)


def to_targets(structure: Plant, theta: np.ndarray) -> np.ndarray:
    """Identified parameters (N, p) → targets (N, p): the coordinates the ANN estimates and the swarm searches."""
    names, out = identified_names(structure), np.array(np.atleast_2d(theta), dtype=float)
    above = above_levels(structure)
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    y = out.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, n in enumerate(names):
            if n.endswith("_re"):
                wn = np.hypot(out[:, i], out[:, i + 1])
                y[:, i], y[:, i + 1] = np.log(-out[:, i] / wn), np.log(wn)
            elif n.endswith("_im"):
                continue
            elif n in above:
                y[:, i] = np.log(out[:, i] - out[:, names.index(above[n])])
            elif nominal[n] != 0 and n not in ADDITIVE_PARAMETERS:
                y[:, i] = np.log(np.abs(out[:, i]))
    return y


def from_targets(structure: Plant, y: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_targets`.  A coordinate too large for exp gives an infinite parameter (a
    Levenberg–Marquardt trial step along a flat log(fs − fc)): a candidate the simulation rejects, not an error."""
    names, y = identified_names(structure), np.atleast_2d(np.asarray(y, dtype=float))
    above = above_levels(structure)
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    out = y.copy()
    with np.errstate(over="ignore"):
        for i, n in enumerate(names):
            if n.endswith("_re"):
                zeta, wn = np.clip(np.exp(y[:, i]), 0.0, 0.999), np.exp(y[:, i + 1])
                out[:, i], out[:, i + 1] = -zeta * wn, wn * np.sqrt(1 - zeta**2)
            elif n.endswith("_im") or n in above:
                continue
            elif nominal[n] != 0 and n not in ADDITIVE_PARAMETERS:
                out[:, i] = np.sign(nominal[n]) * np.exp(y[:, i])
        for i, n in enumerate(names):
            if n in above:
                out[:, i] = out[:, names.index(above[n])] + np.exp(y[:, i])
    return out


def target_jacobian(structure: Plant, y: np.ndarray) -> np.ndarray:
    """d y / d theta at the parameters of ``y`` (the coordinate change only; no simulation).  Not finite where a
    parameter is at the edge of its domain (fs = fc: log(fs − fc) has no derivative there);
    criterion.with_finite_columns makes the residuals' derivatives there from the parameters themselves."""
    theta = from_targets(structure, y[None])[0]
    h = 1e-7 * np.maximum(np.abs(theta), 1e-6)
    up = to_targets(structure, theta + np.diag(h))
    down = to_targets(structure, theta - np.diag(h))
    with np.errstate(invalid="ignore"):
        out = (up - down) / (2 * h[:, None])
    # a target at ±∞ that a step leaves there (a collapsed Stribeck bump's log(fs − fc) under another parameter's
    # step) does not change: its derivative is 0, not ∞ − ∞
    out[up == down] = 0.0
    return out.T


def prior_box(structure: Plant, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """The prior's box (servofmu.identification.prior) in target coordinates.  A static level equal to its
    Coulomb level (no Stribeck bump; a fit may end there) is centred on a bump of a thousandth of that level:
    the gap's logarithm would be −∞."""
    centre = to_targets(structure, structure.parameter_vector()[None, identified_mask(structure)])[0]
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    above = above_levels(structure)
    for i, n in enumerate(identified_names(structure)):
        if n in above and not np.isfinite(centre[i]):
            centre[i] = np.log(max(1e-3 * nominal[above[n]], 1e-300))

    def half_width(n):
        if n in ADDITIVE_PARAMETERS:
            return additive_scale(structure, n) * (min(spread, 1.0) if n == "ripple_phase" else spread)
        return log_width(n, spread) if (nominal[n] != 0 or n.endswith(("_re", "_im")) or n in above) else spread

    half = np.array([half_width(n) for n in identified_names(structure)])
    return centre - half, centre + half
