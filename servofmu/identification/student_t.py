"""Quantiles of Student's t distribution for the identifier's intervals, without scipy.

``scipy.stats`` is the maintained implementation, but importing it costs about 0.3 s (more than a whole g1
identification; docs/bench-identify.md), and an interval's degrees of freedom (residuals minus parameters) are
always a whole number, for which the distribution function is a finite sum of elementary terms (Abramowitz &
Stegun 26.7.3–4).  Its inverse follows by Newton's method; for many degrees of freedom (records) an expansion in
1/dof serves instead.  tests/test_identify.py checks both against ``scipy.stats.t.ppf``.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["t_quantile"]

LARGE_DOF = 1000  # above: an expansion in 1/dof (the exact sum has dof/2 terms)
# Hill's g1..g4: coefficients of z, z³, z⁵, z⁷, z⁹ (rows), the terms of 1/dof, 1/dof², 1/dof³, 1/dof⁴
HILL = np.array([[1, 1, 0, 0, 0], [3, 16, 5, 0, 0], [-15, 17, 19, 3, 0], [-945, -1920, 1482, 776, 79]]) \
    / np.array([[4.0], [96.0], [384.0], [92160.0]])


def _central_probability(t: float, dof: int) -> float:
    """P(|T| ≤ t) for T with ``dof`` (a positive whole number) degrees of freedom and t ≥ 0."""
    theta = math.atan(t / math.sqrt(dof))
    c2, s = math.cos(theta) ** 2, math.sin(theta)
    if dof % 2:  # 2/π·(θ + sinθ·cosθ·(1 + 2/3·cos²θ + 2·4/(3·5)·cos⁴θ + ...)), dof − 2 powers
        k = np.arange(1, (dof - 1) // 2)
        series = 1.0 + np.sum(np.cumprod(2 * k / (2 * k + 1) * c2)) if k.size else 1.0
        return 2 / math.pi * (theta + (s * math.cos(theta) * series if dof > 1 else 0.0))
    k = np.arange(1, dof // 2)  # sinθ·(1 + 1/2·cos²θ + 1·3/(2·4)·cos⁴θ + ...), dof − 2 powers
    return s * (1.0 + (np.sum(np.cumprod((2 * k - 1) / (2 * k) * c2)) if k.size else 0.0))


def _density(t: float, dof: int) -> float:
    """The probability density of T at t."""
    log_norm = math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2) - 0.5 * math.log(dof * math.pi)
    return math.exp(log_norm - (dof + 1) / 2 * math.log1p(t * t / dof))


def t_quantile(level: float, dof: int) -> float:
    """The t with P(|T| ≤ t) = ``level`` (0 < level < 1) for ``dof`` degrees of freedom: the half-width factor of a
    two-sided ``level`` interval, ``scipy.stats.t.ppf(0.5 + level / 2, dof)``."""
    if not 0 < level < 1 or dof < 1 or int(dof) != dof:
        raise ValueError(f"t_quantile needs 0 < level < 1 and a whole dof ≥ 1, not {level}, {dof}")
    dof = int(dof)
    z = math.sqrt(2) * _inverse_erf(level)  # the normal quantile
    if dof > LARGE_DOF:  # Fisher's expansion in 1/dof (Hill 1970), exact to O(dof⁻⁵)
        g = HILL @ z ** np.arange(1, 10, 2)
        return z + float(g @ float(dof) ** -np.arange(1.0, 5.0))
    t = z  # a start from below for every dof
    for _ in range(100):  # P(|T| ≤ t) is increasing and concave in t, so Newton's steps approach from below
        step = (level - _central_probability(t, dof)) / (2 * _density(t, dof))
        t += step
        if abs(step) <= 1e-15 * t:
            break
    return t


def _inverse_erf(y: float) -> float:
    """erf⁻¹(y) for 0 < y < 1 by Newton's method on math.erf."""
    x = 0.0
    for _ in range(100):
        step = (math.erf(x) - y) / (2 / math.sqrt(math.pi) * math.exp(-x * x))
        x -= step
        if abs(step) <= 1e-16 * max(x, 1.0):
            break
    return x
