"""Stage 3 of an identification: the Levenberg–Marquardt polish of the search's best, in the search's coordinates,
whose last Jacobian gives the intervals (servofmu.identification.identifier)."""
from __future__ import annotations

import numpy as np

from .criterion import JACOBIAN_RTOL, JACOBIAN_STEP, POLISH_RTOL

__all__ = ["polish", "MAX_POLISH_ITERATIONS", "POLISH_MIN_DROP"]

MAX_POLISH_ITERATIONS = 20
# The polish goes on while a step lowers Σr² by a noise variance (Σr²/(m − p)) or more: on a record of 2000
# samples a 1 % smaller residual norm is 40 such variances, and a fit stopped there can lose a selection's ranking
# (ln N = 7.6 a parameter) to a structure whose own polish went further.
POLISH_MIN_DROP = 1.0
# A step taken at this damping or less is the Gauss–Newton step to a few parts in a thousand.
NEARLY_UNDAMPED = 1e-3


def polish(crit, to_theta, y0: np.ndarray, iterations: int = MAX_POLISH_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg–Marquardt on ``crit``'s residuals from ``y0`` (search coordinates; ``to_theta`` maps rows of them
    to parameters); returns the optimum and the Jacobian there (in search coordinates).

    Stops when a step changes no coordinate by more than 1e-10 (relative) or, nearly undamped (a Gauss–Newton
    step), by more than its standard error (a smaller move is one the data cannot tell from noise, and at the
    features' noise floor further steps only wander; a damped step is short where the damping is high, and a
    parameter seen through a flat stretch of its effect stopped there a third of the way to its optimum), or when
    the best step lowers the residual norm by less than 1 % and Σr² by less than POLISH_MIN_DROP noise variances.
    The forward-difference Jacobian is one batch call; a perturbed candidate without steady state is stepped the
    other way, and a column that fails both ways ends the polish (NaN intervals rather than false ones), as does a
    start without a steady state (its derivatives would be taken between runs that ran to their time limit: a
    noise-free stribeck_servo selection spent a tenth of its time on them)."""

    def residual(y):
        r = crit.residuals(to_theta(y[None]), POLISH_RTOL)[0]
        return np.where(np.isfinite(r), r, 1e3)  # a candidate without steady state: far from the data

    def jacobian(y, r):
        h = JACOBIAN_STEP * np.maximum(np.abs(y), 1.0)
        cols = crit.residuals(to_theta(y + np.diag(h)), JACOBIAN_RTOL)
        failed = ~np.all(np.isfinite(cols), axis=1)
        if failed.any():
            h[failed] = -h[failed]
            cols[failed] = crit.residuals(to_theta(y + np.diag(h)[failed]), JACOBIAN_RTOL)
        return ((cols - r) / h[:, None]).T

    y, r = y0.copy(), crit.residuals(to_theta(y0[None]), POLISH_RTOL)[0]
    if not np.all(np.isfinite(r)):  # no steady state at the start: no derivative to descend along
        return y, np.full((r.size, y.size), np.nan)
    jac, damping, scale = jacobian(y, r), 1e-6, np.zeros(y.size)
    for _ in range(iterations):
        if not np.all(np.isfinite(jac)):
            break
        a, g = jac.T @ jac, jac.T @ r
        # the damping's scale: each coordinate's largest curvature so far (MINPACK's), so that a coordinate whose
        # effect has faded (a Stribeck velocity once its bump collapsed) is damped as it was where it had one, and
        # a damped step does not throw it to where another limit holds (vs from 0.002 to 7e5 m/s)
        scale = np.maximum(scale, np.diag(a))
        step = _lowering_step(residual, y, r, jac, a, g, damping, scale)
        if step is None:
            break  # no step lowers the residuals (enough to try): converged
        step, r_new, damping = step
        improvement = 1 - np.sqrt((r_new @ r_new) / (r @ r))
        drop = (r @ r - r_new @ r_new) / max(r_new @ r_new, 1e-300) * max(r.size - y.size, 1)  # noise variances
        standard_errors = np.sqrt(np.clip(np.diag(np.linalg.pinv(a)), 0, None) * (r_new @ r_new)
                                  / max(r.size - y.size, 1))
        # a damped step is short because of its damping, not because the data cannot tell
        small = np.max(np.abs(step) / np.maximum(np.abs(y + step), 1e-3)) < 1e-10 or \
            damping <= NEARLY_UNDAMPED and np.all(np.abs(step) <= standard_errors)
        y, r, damping = y + step, r_new, max(damping / 10, 1e-9)
        jac = jacobian(y, r)
        if small or improvement < 0.01 and drop < POLISH_MIN_DROP:
            break
    return y, jac


def _lowering_step(residual, y, r, jac, a, g, damping, scale):
    """(step, its residuals, its damping): the least damped Levenberg–Marquardt step from ``y`` that lowers the
    residual norm, raising the damping tenfold per failed try; None when none does.  A failed step that not even
    the linear model r + J·step expected to lower Σr² by POLISH_MIN_DROP noise variances ends the tries: the
    residuals are at their noise floor, where more damping only costs evaluations.  (A drop of 1 % of the norm, the
    rule before, is 2 % of Σr²: 40 noise variances on 2000 samples, thousands on a long log — a fit whose weakly
    determined direction still held such a drop stopped where it started: the Stribeck shape exponent from δ = 3,
    20 above the Gaussian's −2·ln L, never moved.)"""
    while damping < 1e8:
        step = np.linalg.solve(a + damping * np.diag(scale + 1e-30), -g)
        r_new = residual(y + step)
        if r_new @ r_new < r @ r:
            return step, r_new, damping
        predicted = r @ r - np.sum((r + jac @ step) ** 2)
        if predicted < POLISH_MIN_DROP * (r @ r) / max(r.size - y.size, 1):
            return None
        damping *= 10
    return None
