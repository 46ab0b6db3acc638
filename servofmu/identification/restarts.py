"""When to search again: a fit that stopped above the noise floor, and where the next search looks.

A swarm can end in the basin of a local minimum (a plant far outside the network's training range puts its
estimate, and the box around it, in the wrong place); the polish then converges there, to a fit whose residuals
are larger than the measurement noise can explain.  The identifier tests every fit against the noise floor
(:func:`floor_test`) and, while the best fit found fails it, searches again (:func:`restart_search`) — a new seed,
a wider box, the network's estimate corrected by its own error at the best plant so far — until a fit reaches the
floor, two fits agree (:func:`fits_agree`: the same minimum found twice, which is then taken to be the data's) or
the budget of restarts is spent.

The floor: for stepped-sine data, white noise of known standard deviation (the measurement records it; noise-free
data has only the simulator's error, ``numerical_floor``) gives every residual a known variance s², so that at the
right minimum Σ r²/s² is χ² with m − p degrees of freedom; a fit above the ``level`` quantile of that is above the
floor.  Time-domain data brings no noise level the criterion could trust (its weights are estimated from the fit
itself), so it is not tested and never restarted.
"""
from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from ..errors import UserError, check_int, is_real
from .criterion import SineData

__all__ = ["RestartOptions", "FloorTest", "floor_test", "fits_agree", "noise_half_widths", "restart_box", "restart_seed", "chi2_quantile"]


@dataclass(frozen=True)
class RestartOptions:
    """When the identifier searches again (servofmu.identification.restarts).

    ``restarts``: most searches after the first (0: never restart); ``level``: the χ² quantile a fit's residuals
    must stay under to be at the noise floor; ``numerical_floor``: the RMS relative error of noise-free data's
    right fit (the simulator's, far below it: ~1e-9); ``agree_rtol``: two fits whose parameters differ by no more
    than this (relative) or their 95 % intervals are one minimum found twice.
    """

    restarts: int = 6
    level: float = 0.999
    numerical_floor: float = 1e-6
    agree_rtol: float = 1e-6

    def __post_init__(self):
        check_int("restarts", self.restarts, 0)
        if not (is_real(self.level) and 0.5 < self.level < 1):
            raise UserError(f"restart option level must be in (0.5, 1), not {self.level!r}")
        for name in ("numerical_floor", "agree_rtol"):
            if not (is_real(getattr(self, name)) and getattr(self, name) > 0):
                raise UserError(f"restart option {name} must be positive, not {getattr(self, name)!r}")


@dataclass(frozen=True)
class FloorTest:
    """A fit against the noise floor: ``statistic`` Σ r²/s², its ``limit`` (the χ² quantile), and ``ratio``, the
    fit's RMS residual over what the noise alone leaves at the right minimum (about 1 there)."""

    statistic: float
    limit: float
    ratio: float

    @property
    def at_floor(self) -> bool:
        """True when the residuals are no larger than the noise explains."""
        return bool(self.statistic <= self.limit)


def chi2_quantile(level: float, dof: int) -> float:
    """The ``level`` quantile of χ² with ``dof`` degrees of freedom (Wilson–Hilferty: within 2 % for dof ≥ 3, 1 % for dof ≥ 10, at the
    levels used here)."""
    z = NormalDist().inv_cdf(level)
    c = 2.0 / (9.0 * dof)
    return float(dof * (1 - c + z * np.sqrt(c)) ** 3)


def floor_test(data, r: np.ndarray, p: int, options: RestartOptions) -> FloorTest | None:
    """The test of residuals ``r`` (one fit, shape (m,)) of ``p`` parameters against the floor of ``data``; None for
    data without a known noise level (time-domain records) or with no more residuals than parameters."""
    if not isinstance(data, SineData) or r.size <= p:
        return None
    noise = np.zeros(data.amplitudes.size) if data.noise is None else np.asarray(data.noise, dtype=float)
    s2 = np.tile(noise, r.size // noise.size) ** 2 + options.numerical_floor ** 2  # Re, Im and mean per experiment
    dof = r.size - p
    if not np.all(np.isfinite(r)):
        return FloorTest(statistic=np.inf, limit=chi2_quantile(options.level, dof), ratio=np.inf)
    statistic = float(np.sum(r ** 2 / s2))
    return FloorTest(statistic=statistic, limit=chi2_quantile(options.level, dof), ratio=float(np.sqrt(statistic / dof)))


def noise_half_widths(intervals: np.ndarray, test: FloorTest | None) -> np.ndarray:
    """(p,) half-widths of a fit's 95 % intervals as the noise alone would make them: a fit above the floor has
    intervals scaled by its misfit (s² from its own residuals), which would let two different minima "agree", so
    they are shrunk by its ratio to the noise."""
    half = np.abs(np.diff(intervals, axis=1)[:, 0]) / 2
    half = np.where(np.isnan(half), 0.0, half)
    if test is not None and test.ratio > 1:
        half = half / test.ratio
    return half


def fits_agree(theta_a, half_a, theta_b, half_b, rtol: float) -> bool:
    """Whether two fits are one minimum: every parameter within the wider of their half-widths
    (:func:`noise_half_widths`; an undetermined parameter, unbounded, always agrees) or within ``rtol``
    relative."""
    gap = np.abs(np.asarray(theta_a) - np.asarray(theta_b))
    return bool(np.all(gap <= np.fmax(half_a, half_b) + rtol * np.maximum(np.abs(theta_a), np.abs(theta_b))))


def restart_box(k: int, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box of restart ``k`` (1, 2, ...): the first search's box, then twice and from the third on four times
    as wide about its centre (in the search's log coordinates: a relative widening, positivity kept)."""
    centre, half = (lower + upper) / 2, (upper - lower) / 2
    factor = 2.0 ** min(k - 1, 2)
    return centre - factor * half, centre + factor * half


def restart_seed(seed: int, k: int) -> np.random.Generator:
    """The swarm's generator for restart ``k`` of a fit seeded with ``seed``: its own stream, reproducible."""
    return np.random.default_rng([seed, k])
