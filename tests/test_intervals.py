"""The 95 % intervals of a fit (servofmu.identification.criterion.intervals_from_jacobian) against an independent
estimate of what they should be: the spread of the estimates themselves over many noise draws.

On a linear least-squares problem y = X·θ + noise the Gauss–Newton covariance is exact, so over a few hundred
seeds the intervals must cover the truth about 95 % of the time *and* their half-widths must match 1.96 times the
observed standard deviation of the estimates: intervals that only cover (as any wide enough interval does) are
not enough, the docstrings promise narrow ones.
"""
from __future__ import annotations

import numpy as np
import pytest

from servofmu.identification.criterion import bartlett_lags, intervals_from_jacobian

THETA = np.array([2.0, -0.5, 0.1])
SEEDS = 400


def regressors(n: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)
    return np.column_stack([np.ones(n), t, np.sin(2 * np.pi * t)])


def ar1(rng: np.random.Generator, n: int, rho: float, sigma: float) -> np.ndarray:
    """Stationary AR(1) noise with innovation standard deviation ``sigma``."""
    e = sigma * rng.standard_normal(n)
    out = np.empty(n)
    out[0] = e[0] / np.sqrt(1 - rho**2)
    for k in range(1, n):
        out[k] = rho * out[k - 1] + e[k]
    return out


def fits(noise, X: np.ndarray, blocks=None):
    """Estimates (SEEDS, p) and their intervals (SEEDS, p, 2) over SEEDS noise draws."""
    estimates, intervals = [], []
    for seed in range(SEEDS):
        y = X @ THETA + noise(np.random.default_rng(seed))
        theta, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = X @ theta - y  # residuals, model minus data, as the criteria return them
        estimates.append(theta)
        intervals.append(intervals_from_jacobian(theta, r, X, blocks=blocks))
    return np.array(estimates), np.array(intervals)


def check(estimates, intervals, width_band, coverage_band):
    half = (intervals[:, :, 1] - intervals[:, :, 0]) / 2
    spread = 1.96 * estimates.std(axis=0)  # the independent estimate of the 95 % half-width
    ratio = half.mean(axis=0) / spread
    covered = np.mean((intervals[:, :, 0] <= THETA) & (THETA <= intervals[:, :, 1]), axis=0)
    assert np.all((width_band[0] < ratio) & (ratio < width_band[1])), ratio
    assert np.all((coverage_band[0] < covered) & (covered < coverage_band[1])), covered


def test_white_noise_intervals_are_as_wide_as_the_estimates_scatter():
    X = regressors(40)
    estimates, intervals = fits(lambda rng: 0.05 * rng.standard_normal(40), X)
    check(estimates, intervals, (0.9, 1.15), (0.92, 0.98))
    # and each one is the Cramér–Rao width of this problem (known noise), up to the spread of s
    cramer_rao = 2.026 * 0.05 * np.sqrt(np.diag(np.linalg.inv(X.T @ X)))  # t(0.975, 37 degrees of freedom)
    half = (intervals[:, :, 1] - intervals[:, :, 0]) / 2
    np.testing.assert_allclose(np.median(half, axis=0), cramer_rao, rtol=0.05)


def test_correlated_residuals_newey_west_intervals_follow_the_scatter():
    """Residuals correlated in time (AR(1), ρ = 0.6) in two records: the Newey–West intervals widen with the
    correlation (plain s²(JᵀJ)⁻¹ would be about twice too narrow) but not beyond the estimates' scatter."""
    n = 300
    X = np.vstack([regressors(n), regressors(n)])
    blocks = [slice(0, n), slice(n, 2 * n)]
    noise = lambda rng: np.concatenate([ar1(rng, n, 0.6, 0.05), ar1(rng, n, 0.6, 0.05)])  # noqa: E731
    estimates, intervals = fits(noise, X, blocks)
    check(estimates, intervals, (0.75, 1.15), (0.85, 0.98))
    _, white = fits(noise, X)
    assert np.all(np.mean(white[:, :, 1] - white[:, :, 0], axis=0)
                  < 0.7 * np.mean(intervals[:, :, 1] - intervals[:, :, 0], axis=0))


def bartlett_reference(r: np.ndarray, X: np.ndarray, lags: int) -> np.ndarray:
    """Plain Newey–West on the fit's own residuals, written out here: (XᵀX)⁻¹ Ω (XᵀX)⁻¹ with Bartlett weights."""
    g = X * r[:, None]
    omega = g.T @ g
    for lag in range(1, lags + 1):
        gamma = g[lag:].T @ g[:-lag]
        omega += (1 - lag / (lags + 1)) * (gamma + gamma.T)
    bread = np.linalg.inv(X.T @ X)
    return bread @ omega @ bread


def test_noise_the_parameters_absorb_is_given_back():
    """Strongly coloured residuals (AR(1), ρ = 0.95) on smooth regressors: the noise has few degrees of freedom
    where its power is, the fit takes up much of it, and its own residuals look far quieter than the noise.  Both
    s²(JᵀJ)⁻¹ and plain Newey–West on those residuals are then about half as wide as the estimates' scatter; the
    intervals (leave-one-segment-out residuals, the long-run covariance's degrees of freedom) follow it."""
    n = 300
    X = regressors(n)
    noise = lambda rng: ar1(rng, n, 0.95, 0.05)  # noqa: E731
    estimates, intervals = fits(noise, X, [slice(0, n)])
    check(estimates, intervals, (0.85, 1.4), (0.85, 0.99))
    spread = 1.96 * estimates.std(axis=0)
    _, white = fits(noise, X)
    assert np.all(np.mean(white[:, :, 1] - white[:, :, 0], axis=0) / 2 < 0.35 * spread)
    plain = []
    for seed in range(SEEDS):
        y = X @ THETA + noise(np.random.default_rng(seed))
        theta, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = X @ theta - y
        lags = bartlett_lags(r)
        plain.append(1.968 * np.sqrt(np.diag(bartlett_reference(r, X, lags)) * n / (n - 3)))
    assert np.all(np.mean(plain, axis=0) < 0.7 * spread)


@pytest.mark.parametrize("level", [0.68, 0.99])
def test_other_levels_scale_with_the_t_quantile(level):
    X = regressors(40)
    r = 0.05 * np.random.default_rng(0).standard_normal(40)
    base = intervals_from_jacobian(THETA, r, X)
    other = intervals_from_jacobian(THETA, r, X, level=level)
    z = {0.68: 0.49749, 0.99: 1.34015}[level]  # t(0.84, 37) / t(0.975, 37) and t(0.995, 37) / t(0.975, 37), scipy
    np.testing.assert_allclose((other[:, 1] - other[:, 0]) / (base[:, 1] - base[:, 0]), z, rtol=2e-3)


def test_parameters_the_data_does_not_determine_get_unbounded_intervals():
    """A column of zeros (a parameter with no effect) and two equal columns (only their sum is determined): the
    pseudo-inverse would give them zero variance, i.e. exact values; their intervals must be unbounded, the others'
    unchanged."""
    rng = np.random.default_rng(3)
    jac = rng.normal(size=(200, 2))
    r = rng.normal(size=200)
    theta = np.array([1.0, 2.0])
    determined = intervals_from_jacobian(theta, r, jac)
    with_dead = intervals_from_jacobian(np.append(theta, 3.0), r, np.column_stack([jac, np.zeros(200)]))
    np.testing.assert_allclose(with_dead[:2], determined, rtol=1e-3)  # (one degree of freedom less)
    assert with_dead[2, 0] == -np.inf and with_dead[2, 1] == np.inf
    twins = intervals_from_jacobian(np.append(theta, 3.0), r, np.column_stack([jac, jac[:, 1]]))
    assert np.isfinite(twins[0]).all() and np.isinf(twins[1:]).all()
