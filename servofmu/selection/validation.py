"""What a candidate may lose on the validation data before a selection flags it: the χ² margin of its estimation
error (validation_margin) and, for records, its own allowance from the two records' Fisher informations
(validation_allowance) — docs/selection.md, how the candidates are ranked."""
from __future__ import annotations

import math

import numpy as np

from ..identification.restarts import chi2_quantile

__all__ = ["validation_margin", "validation_allowance", "VALIDATION_LEVEL", "VALIDATION_STEP", "SCREEN_RTOL"]

VALIDATION_LEVEL = 0.999  # the χ² quantile of the validation flag's margin (validation_margin)
# The validation allowance's Jacobian: differences of a tenth of each parameter's standard error (a ripple's
# period over a longer travel is far from linear over a whole one: its allowance came out seven times larger),
# simulated at the screening's tolerance, whose error (~1e-7 of the signal) is a two-hundredth of the change such
# a step makes (~2e-5 at 40 dB and 2000 samples): at the polish's 1e-10 its p + 1 simulations added 6 % to a
# selection's time
VALIDATION_STEP = 0.1
# The screening fit's integrator tolerance (the polish's residuals, its Jacobian and the scores; the allowance's
# differences): records' simulations take a quarter of the steps they take at the polish's 1e-10, and the residuals
# err by ~1e-7 of the signal, against noise of 1e-2 (40 dB): the BIC moves by ~0.04, against ln N = 7.6 per
# parameter.
SCREEN_RTOL = 1e-7


def validation_margin(parameters: int) -> float:
    """Validation −2·ln L a candidate of ``parameters`` identified parameters may lose to the best one before it is
    flagged: the VALIDATION_LEVEL quantile of χ²(p).  A right structure's estimate θ̂ predicts new data worse than
    its true values by (θ̂ − θ)ᵀ I (θ̂ − θ), χ²(p) when the validation record informs as the fitted one does — the
    estimation error of all p parameters, not of one (stribeck2 seed 0: the truth's own structure lost 21.9 to
    lugre/2 on validation with a fit as good as the true values' on the fitted record)."""
    return chi2_quantile(VALIDATION_LEVEL, max(parameters, 1))


def validation_allowance(jacobian: np.ndarray, scales: np.ndarray, errors: list[np.ndarray], crit_v,
                         theta: np.ndarray, validated: list[np.ndarray], rtol: float = SCREEN_RTOL) -> float:
    """The VALIDATION_LEVEL quantile of what a right structure's estimation error costs on the validation
    record: (θ̂ − θ)ᵀ F_v (θ̂ − θ) with θ̂ − θ ~ N(0, F⁻¹), F and F_v the Fisher informations of the fitted and
    the validation records (Gauss–Newton, every signal's residuals in units of its noise), a sum Σ λᵢ·χ²(1) over
    the eigenvalues λ of F⁻¹F_v (F_v from differences of VALIDATION_STEP standard errors at ``rtol``), its
    quantile from a χ² of the same mean and variance (Satterthwaite).  Where the
    validation record informs as the fitted one does (every λ = 1) it is validation_margin(p); a ripple's period
    met over a longer travel there raises its λ a hundredfold.  ``jacobian``: the polish's last, of the residuals
    weighted by 1/``scales`` per signal; ``errors`` and ``validated``: every signal's output errors at θ̂ on the
    two records.  NaN where it cannot be computed (stepped-sine data, a simulation that failed)."""
    if not hasattr(crit_v, "errors") or not np.all(np.isfinite(jacobian)) or \
            jacobian.shape[0] != sum(e.size for e in errors):
        return math.nan
    noise = np.concatenate([np.full(e.size, s / np.sqrt(max(e @ e / e.size, 1e-300)))  # weighted → noise units
                            for e, s in zip(errors, scales)])
    fisher = (jacobian * noise[:, None]).T @ (jacobian * noise[:, None])
    covariance = np.linalg.pinv(fisher)
    se = np.sqrt(np.clip(np.diag(covariance), 0, None))
    step = np.where(np.isfinite(se) & (se > 0), VALIDATION_STEP * se, 1e-6 * np.maximum(np.abs(theta), 1e-6))
    rows = np.vstack([theta, theta + np.diag(step)])
    columns = []
    for e, e0 in zip(crit_v.errors(rows, rtol), validated):
        sigma = np.sqrt(max(e0 @ e0 / e0.size, 1e-300))  # the noise: the validation errors at θ̂ (full tolerance)
        columns.append((e[1:] - e[0]) / step[:, None] / sigma)
    jv = np.concatenate(columns, axis=1).T
    if not np.all(np.isfinite(jv)):
        return math.nan
    lam = np.clip(np.linalg.eigvals(covariance @ (jv.T @ jv)).real, 0, None)
    mean, square = float(lam.sum()), float(lam @ lam)
    if not mean > 0:
        return math.nan
    return square / mean * chi2_quantile(VALIDATION_LEVEL, mean ** 2 / square)
