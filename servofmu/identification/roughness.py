"""Whether a fit's cost is what its intervals assume: locally quadratic, or chaotic in the parameters.

The 95 % intervals (and the Cramér–Rao bound) describe a cost that is a paraboloid within a few standard errors of
the fit: one standard error along a parameter's profile direction, ±C·e_k/√C_kk (C the covariance; the other
parameters following as they are correlated with it), raises −2·ln L by 1.  A record on which the response loses
its way — a mass moved by a force through a position ripple's wells (a driven pendulum, with a second-order G) —
is chaotic in the parameters: a ten-thousandth of a pole moves the simulated position by periods of the ripple,
the cost is rough at every scale, and a polish ends in whichever spike of it it reaches (docs/selection.md,
chaotic records).  There −2·ln L rises by thousands at a standard error: :func:`response_roughness` measures the largest
rise, ROUGH_RISE marks it.  Stepped-sine data (steady states, no trajectory to lose) is not checked.
"""
from __future__ import annotations

import math

import numpy as np

from .criterion import JACOBIAN_STEP, POLISH_RTOL

__all__ = ["ROUGH_RISE", "neg2loglik", "curvature", "curvature_at", "response_roughness", "rough_line", "finite_covariance"]

# The rise of −2·ln L at one standard error that marks a fit's response as chaotic in its parameters: a quadratic
# cost rises by 1; the fits of bench_select's plants without a second-order ripple by a median of 1.15 (198 of 200
# below 10; a first-order ripple axis's records 518 once, and 31 along one test record's ripple phase); the forced
# pendulum of docs/selection.md by 280–3500
ROUGH_RISE = 200.0


def neg2loglik(errors: list[np.ndarray]) -> tuple[float, int]:
    """−2·ln L of Gaussian residuals with every signal's variance estimated (its mean square), and N."""
    total, n = 0.0, 0
    for e in errors:
        rss = float(e @ e)
        if not np.isfinite(rss):
            return math.inf, n
        total += e.size * (math.log(2 * math.pi * max(rss / e.size, 1e-300)) + 1)
        n += e.size
    return total, n


def finite_covariance(covariance, intervals) -> np.ndarray:
    """``covariance`` with the rows and columns of the parameters whose intervals are unbounded set to NaN: a step
    of an undetermined parameter's standard error goes anywhere (its variance was set, not measured)."""
    out = np.array(covariance, dtype=float)
    unbounded = ~np.all(np.isfinite(np.asarray(intervals, dtype=float)), axis=1)
    out[unbounded, :] = np.nan
    out[:, unbounded] = np.nan
    return out


def curvature(jacobian: np.ndarray, blocks: list[slice], residuals: np.ndarray) -> np.ndarray | None:
    """The Gauss–Newton curvature of −2·ln L (every signal's variance estimated) at a fit: Σ_k N_k/RSS_k·J_kᵀJ_k
    over the signals k (``blocks`` of the weighted ``residuals`` and of the rows of their ``jacobian``), so that a
    step s raises −2·ln L by sᵀFs where the cost is quadratic; None where it is not finite."""
    jacobian, residuals = np.asarray(jacobian, dtype=float), np.asarray(residuals, dtype=float)
    if jacobian.ndim != 2 or jacobian.shape[0] != residuals.size or not blocks:
        return None
    info = np.zeros((jacobian.shape[1],) * 2)
    for b in blocks:
        rss = float(residuals[b] @ residuals[b])
        info += residuals[b].size / max(rss, 1e-300) * (jacobian[b].T @ jacobian[b])
    return info if np.all(np.isfinite(info)) else None


def curvature_at(crit, theta: np.ndarray, rtol: float = POLISH_RTOL) -> np.ndarray | None:
    """:func:`curvature` of ``crit`` at ``theta`` from its own forward-difference Jacobian in the parameters (one
    batch of p + 1 simulations): the curvature of another criterion than the polish's (a long record's at its
    reduced rate)."""
    theta = np.asarray(theta, dtype=float)
    h = JACOBIAN_STEP * np.where(theta != 0, np.abs(theta), 1.0)
    with np.errstate(all="ignore"):
        rows = crit.residuals(np.vstack([theta, theta + np.diag(h)]), rtol)
    jacobian = ((rows[1:] - rows[0]) / h[:, None]).T
    return curvature(jacobian, crit.blocks, rows[0]) if np.all(np.isfinite(jacobian)) else None


def response_roughness(crit, theta: np.ndarray, covariance, rtol: float = POLISH_RTOL,
                       information: np.ndarray | None = None, centred: bool = False) -> float:
    """The largest rise of −2·ln L (every signal's variance estimated) of ``crit``'s data from ``theta`` over
    steps of one standard error along each parameter's profile direction, ±C·e_k/√C_kk — about 1 for a locally
    quadratic cost, at least 1 where parameters of NaN variance are left out.  With the cost's Gauss–Newton
    ``information`` (:func:`curvature`) each step is scaled to where the quadratic rises by exactly 1: the
    Newey–West covariance of coloured residuals (a real axis's model error, correlated over hundreds of samples)
    is wider than the curvature says, and its standard error alone raised a regular fit of a drive's log by 550.
    ``centred``: ``theta`` is not ``crit``'s own minimum (a long record's fit scored on its reduced rate), so the
    rises at ±step differ by the gradient's term 2·gᵀs: their mean, the quadratic's part, is taken per parameter.
    NaN for stepped-sine criteria (no trajectory), a covariance that is missing or not finite, or steps that
    cannot be simulated."""
    if covariance is None or getattr(crit, "blocks", None) is None:
        return math.nan
    covariance = np.asarray(covariance, dtype=float)
    with np.errstate(invalid="ignore"):
        sd = np.sqrt(np.diag(covariance))
    live = np.flatnonzero(np.isfinite(sd) & (sd > 0))
    steps = np.zeros((live.size, theta.size))
    steps[:, live] = (covariance[np.ix_(live, live)] / sd[live]).T
    if not live.size or not np.all(np.isfinite(steps)):
        return math.nan
    if information is not None:
        predicted = np.einsum("ij,jk,ik->i", steps, np.asarray(information, dtype=float), steps)
        scale = np.where(np.isfinite(predicted) & (predicted > 0), 1 / np.sqrt(np.abs(predicted)), 1.0)
        steps *= scale[:, None]
    rows = np.vstack([theta, theta + steps, theta - steps])
    with np.errstate(all="ignore"):
        errors = crit.simulate_errors(rows, rtol)
    values = np.array([neg2loglik([e[i] for e in errors])[0] for i in range(rows.shape[0])])
    rises = values[1:] - values[0]
    if centred:
        rises = (rises[:live.size] + rises[live.size:]) / 2
    rises = rises[np.isfinite(rises)]
    return float(np.max(rises)) if rises.size and np.isfinite(values[0]) else math.nan


def rough_line(roughness: float | None) -> str | None:
    """The warning a rough fit's table ends with (None for a regular one, or one not checked)."""
    if roughness is None or not roughness > ROUGH_RISE:
        return None
    return (f"warning: the response is chaotic in the parameters on these records — one standard error from the "
            f"fit −2·ln L rises by {roughness:.3g}, not about 1: the intervals do not hold, and the fit is one of "
            "many spikes of a rough cost (shorter records are predictable over more of their length; "
            "docs/selection.md, chaotic records)")
