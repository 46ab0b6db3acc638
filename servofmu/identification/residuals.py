"""The residual analysis of an output-error model, as MATLAB's ``resid`` does it: the autocorrelation of the
residuals e (lags 1..LAGS) and their cross-correlation with the input u (lags −LAGS..LAGS), with bounds that a
right model (e white and independent of u) stays within at the probability LEVEL, jointly over the lags tested
(servofmu.validation.replay explains the bounds; the selection of structures ranks candidates by them too)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ResidualTest", "residual_test", "LAGS", "LEVEL", "EXACT"]

LAGS = 25      # lags of the correlation functions (MATLAB's resid default)
LEVEL = 0.99   # confidence of the bounds
EXACT = 1e-7   # residuals below this fraction of the signal's spread: the model reproduces noise-free data


@dataclass(frozen=True)
class ResidualTest:
    """Correlations of the residuals e and the input u, with their bounds under "e white and independent of u".

    ``autocorrelation`` r_e(k), k = 0..LAGS (r_e(0) = 1); ``cross_lags`` −LAGS..LAGS and ``cross_correlation``
    r_eu(k) = corr(e(t + k), u(t)); ``auto_sigma``, ``cross_sigma``: their standard deviations under the
    hypothesis; ``z``: the joint 99 % quantile (Bonferroni over all lags of one function); ``z_per_lag``: the
    per-lag one (MATLAB's); ``exact``: the residuals are below EXACT times the signal's spread.
    """

    samples: int
    exact: bool
    autocorrelation: np.ndarray
    cross_lags: np.ndarray
    cross_correlation: np.ndarray
    auto_sigma: float
    cross_sigma: float
    z: float
    z_per_lag: float

    @property
    def white(self) -> bool:
        """The autocorrelation stays within the bounds at every lag 1..LAGS."""
        return self.exact or bool(np.all(np.abs(self.autocorrelation[1:]) <= self.z * self.auto_sigma))

    @property
    def independent(self) -> bool:
        """The cross-correlation with the input stays within the bounds at every lag."""
        return self.exact or bool(np.all(np.abs(self.cross_correlation) <= self.z * self.cross_sigma))

    @property
    def passed(self) -> bool:
        """White and independent of the input."""
        return self.white and self.independent

    def outside_per_lag(self) -> tuple[int, int]:
        """Lags outside MATLAB's per-lag 99 % bounds: (autocorrelation, cross-correlation)."""
        return (int(np.sum(np.abs(self.autocorrelation[1:]) > self.z_per_lag * self.auto_sigma)),
                int(np.sum(np.abs(self.cross_correlation) > self.z_per_lag * self.cross_sigma)))


def _correlation(a: np.ndarray, b: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """(1/N)·Σ_t a(t + k)·b(t) / (σ_a·σ_b) for every lag k (means removed)."""
    a, b = a - a.mean(), b - b.mean()
    n, scale = a.size, math.sqrt(float(a @ a) * float(b @ b)) / a.size
    out = np.empty(lags.size)
    for i, k in enumerate(lags):
        out[i] = (a[k:] @ b[:n - k] if k >= 0 else a[:n + k] @ b[-k:]) / n
    return out / scale if scale > 0 else np.full(lags.size, np.nan)


def residual_test(e: np.ndarray, u: np.ndarray, y: np.ndarray, lags: int = LAGS,
                  level: float = LEVEL, functions: int = 1) -> ResidualTest:
    """The residual analysis of ``e`` against the input ``u`` (equal lengths, uniform sampling) for a measured
    output ``y``.

    The bounds hold with probability ``level`` jointly over the lags of ``functions`` correlation functions
    (Bonferroni: each lag at 1 − (1 − level)/(lags·functions)); servofmu.validation.replay passes the number of
    functions it tests over the whole data file.
    """
    from scipy.stats import norm

    e, u = np.asarray(e, dtype=float), np.asarray(u, dtype=float)
    n = e.size
    lags = min(lags, n // 4)
    auto = _correlation(e, e, np.arange(lags + 1))
    cross_lags = np.arange(-lags, lags + 1)
    cross = _correlation(e, u, cross_lags)
    r_u = _correlation(u, u, cross_lags)
    r_e = np.concatenate([auto[:0:-1], auto])
    # Bartlett's variance of the cross-correlation, Σ_k r_e(k)·r_u(k), with Bartlett weights over the lags: an
    # unweighted sum truncated at ±lags can all but cancel when r_e oscillates (a closed loop's force residual),
    # leaving a bound far too tight; the weighted sum is never negative and does not depend much on the cut.
    weights = 1 - np.abs(cross_lags) / (lags + 1)
    cross_var = max(float(np.sum(weights * r_e * r_u)), 1.0 / n) if np.all(np.isfinite(r_u)) else 1.0
    exact = bool(np.sqrt(np.mean(e**2)) <= EXACT * np.std(y))
    return ResidualTest(samples=n, exact=exact, autocorrelation=auto, cross_lags=cross_lags, cross_correlation=cross,
                        auto_sigma=1 / math.sqrt(n), cross_sigma=math.sqrt(cross_var / n),
                        z=float(norm.ppf(1 - (1 - level) / 2 / max(lags, 1) / max(functions, 1))),
                        z_per_lag=float(norm.ppf(1 - (1 - level) / 2)))
