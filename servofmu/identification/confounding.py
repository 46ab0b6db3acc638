"""The parameter directions a fit's data does not separate, read from the covariance its intervals come from.

Parameters whose estimates move together (an inclined axis's constant load ``offset`` and its friction levels,
which only standstill tells apart; a spring and a pole on a short stroke; a Stribeck level and its velocity) each
get a wide interval, and the intervals alone do not say that one combination of them is known far better than any
of them.  :func:`confounded_groups` names such groups, each with the combinations the data determines (value and
95 % half-width) and the directions it does not (docs/identification.md, "Parameters the data does not
separate").

The rule.  Standardise the precision (the inverse covariance, a pseudo-inverse where the covariance is singular)
by each parameter's conditional standard deviation — how well it would be known were the others fixed: S_ij =
P_ij/√(P_ii·P_jj), a matrix of (negated) partial correlations with unit diagonal.  Moving the parameters by
w_i conditional standard deviations each (‖w‖ = 1) raises the criterion by wᵀSw, and by 1 for any one parameter
moved alone by one.  An eigenvector w of S with eigenvalue λ ≤ :data:`THRESHOLD` (0.01) is a direction along which
the data lets the parameters move together 1/√λ ≥ 10 times farther than it lets any one of them move alone: the
members' intervals are then mostly that shared motion.  For two parameters λ = 1 − |r|, r their estimates'
correlation, so the rule is |r| ≥ 0.99; for three or more it also finds a combination such as a + b − c that is
pinned while every pair correlates less (which a rule on pairs misses).  The members of a direction are the
parameters with |w_i| ≥ :data:`MEMBER_SHARE` (a share of at least 1 % of the direction); directions with a member
in common form one group.

For a group with m such directions, m members (pivots: the last in the order of the names — load terms, then
Stribeck and static levels, come after what they trade against — among those with a large share) carry the free
directions, and every other member i has the determined combination θ_i − Σ c_ij·θ_pivot_j, which no free
direction changes; its half-width is from the full covariance, with the quantile the intervals used.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

__all__ = ["Combination", "Confounded", "confounded_groups", "interval_quantile", "with_free_directions", "THRESHOLD",
           "MEMBER_SHARE", "FREE_VARIANCE"]

THRESHOLD = 0.01  # largest eigenvalue of the standardised precision that marks a direction (|r| ≥ 0.99 for two)
MEMBER_SHARE = 0.1  # smallest |component| of a parameter in a direction's unit vector that makes it a member
SINGULAR = 1e-12  # correlation eigenvalues below this (relative) are exact null directions of the data
FREE_VARIANCE = 1e8  # a direction the data does not see at all: its members' variance times this (see below)


@dataclass(frozen=True)
class Combination:
    """A linear combination Σ c_i·θ_i: ``coefficients`` ((name, c) pairs, the first 1), its ``value``, the 95 %
    ``half_width`` (inf: not determined) and the ``unit`` of its first parameter."""

    coefficients: tuple[tuple[str, float], ...]
    value: float
    half_width: float
    unit: str

    def expression(self) -> str:
        """The combination as text: ``fc_pos − 1.00·offset``."""
        out = self.coefficients[0][0]
        for name, c in self.coefficients[1:]:
            out += f" {'−' if c < 0 else '+'} {_coefficient(abs(c))}·{name}"
        return out

    def text(self) -> str:
        """``fc_pos − 1.00·offset = 12.3 ± 0.03 N``."""
        return f"{self.expression()} = {_value(self.value, self.half_width)}{' ' + self.unit if self.unit else ''}"

    def to_json(self) -> dict:
        """JSON-ready: coefficients by name, value, half_width (null when unbounded), unit."""
        return {"coefficients": dict(self.coefficients), "value": self.value,
                "half_width": self.half_width if math.isfinite(self.half_width) else None, "unit": self.unit}


@dataclass(frozen=True)
class Confounded:
    """A group of parameters the data does not separate: its ``names``, ``correlation`` (the strongest correlation
    of two members' estimates), the ``determined`` combinations and the ``free`` directions — each as a
    :class:`Combination` led by a pivot, coefficients giving how the other members move with it, value the
    pivot's estimate and half-width its interval's (the motion is mostly along this direction)."""

    names: tuple[str, ...]
    correlation: float
    determined: tuple[Combination, ...]
    free: tuple[Combination, ...]

    def line(self) -> str:
        """One line for identify's table."""
        r = f" (r = {_signed(self.correlation)})" if math.isfinite(self.correlation) else ""
        free = "; ".join(f"{c.coefficients[0][0]} ± {_short(c.half_width)} {c.unit}".rstrip()
                         + (" moving " + ", ".join(f"{n} {'−' if k < 0 else '+'}{_coefficient(abs(k))}"
                                                   for n, k in c.coefficients[1:]) if len(c.coefficients) > 1 else "")
                         for c in self.free)
        return (f"not separated by the data: {', '.join(self.names)}{r}; determined: "
                + ", ".join(c.text() for c in self.determined) + f"; free: {free}")

    def to_json(self) -> dict:
        """JSON-ready: names, correlation (null when not defined), determined and free combinations."""
        return {"names": list(self.names),
                "correlation": self.correlation if math.isfinite(self.correlation) else None,
                "determined": [c.to_json() for c in self.determined], "free": [c.to_json() for c in self.free]}


def with_free_directions(covariance: np.ndarray, jac: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """The covariance with the directions the data does not see at all given a variance: a pseudo-inverse's
    covariance has zero variance along a null direction n of the Jacobian — as a combination nᵀθ known exactly,
    the opposite of the truth — so FREE_VARIANCE times its members' largest variance is added along n (as a
    displacement of the parameters, n nᵀ).  The determined combinations (those orthogonal to every null direction)
    keep their variance; the members' intervals are unbounded anyway (criterion.undetermined, same rule).  A
    parameter without any effect (a zero column) keeps its zero variance."""
    cov = np.array(covariance, dtype=float)
    scale = np.linalg.norm(jac, axis=0)
    live = scale > 0
    if not np.all(np.isfinite(cov)) or not np.all(np.isfinite(jac)) or live.sum() < 2:
        return cov
    _, sv, vt = np.linalg.svd(jac[:, live] / scale[live], full_matrices=False)
    for v in vt[sv <= rtol * sv[0]]:
        n = np.zeros(scale.size)
        n[live] = v / scale[live]
        n /= np.abs(n).max()
        members = np.abs(n) > 1e-6
        var = max(float(np.max(np.diag(cov)[members] / n[members] ** 2)), 1e-300)
        cov += FREE_VARIANCE * var * np.outer(n, n)
    return cov


def interval_quantile(covariance: np.ndarray, intervals: np.ndarray) -> float:
    """The quantile the intervals were made with (half-width over standard deviation, the median over the
    parameters whose interval is finite; 1.96 when none is)."""
    sd = np.sqrt(np.clip(np.diag(covariance), 0, None))
    half = (intervals[:, 1] - intervals[:, 0]) / 2
    ok = np.isfinite(half) & (sd > 0)
    return float(np.median(half[ok] / sd[ok])) if ok.any() else 1.96


def confounded_groups(names: Sequence[str], theta: np.ndarray, covariance: np.ndarray | None,
                      intervals: np.ndarray, units: Mapping[str, str] | None = None,
                      threshold: float = THRESHOLD) -> list[Confounded]:
    """The groups of parameters whose estimates the data does not separate (the module docstring's rule).

    Parameters
    ----------
    names, theta : sequence of str, ndarray (p,)
        The identified parameters and their estimates.
    covariance : ndarray (p, p) or None
        The estimates' covariance the ``intervals`` come from (None, or not finite: no groups).
    intervals : ndarray (p, 2)
        Their intervals (the quantile of the combinations' half-widths is theirs).
    units : mapping, optional
        Unit of each parameter, for the text.
    threshold : float
        Largest eigenvalue of the standardised precision that marks a direction.

    Returns
    -------
    list of Confounded
        One per group, in the order of their first member; empty for data that separates every parameter.
    """
    if covariance is None or not np.all(np.isfinite(covariance)) or len(names) < 2:
        return []
    cov = np.asarray(covariance, dtype=float)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    keep = np.flatnonzero(sd > 0)  # a parameter without variance has no effect at all: not a confounding
    if keep.size < 2:
        return []
    corr = cov[np.ix_(keep, keep)] / np.outer(sd[keep], sd[keep])
    mu, vec = np.linalg.eigh((corr + corr.T) / 2)
    live = mu > SINGULAR * mu.max()
    precision = (vec[:, live] / mu[live]) @ vec[:, live].T  # in standardised units; 0 along exact null directions
    cond = np.sqrt(np.clip(np.diag(precision), 1e-300, None))
    lam, w = np.linalg.eigh(precision / np.outer(cond, cond))
    weak = [w[:, j] for j in np.flatnonzero(lam <= threshold)]
    members = [set(np.flatnonzero(np.abs(d) >= MEMBER_SHARE)) for d in weak]
    groups: list[tuple[set, list]] = []
    for m, d in zip(members, weak):
        if len(m) < 2:
            continue
        joined = [g for g in groups if g[0] & m]
        groups = [g for g in groups if not g[0] & m]
        groups.append((set().union(m, *(g[0] for g in joined)), sum((g[1] for g in joined), []) + [d]))
    q = interval_quantile(cov, intervals)
    units = units or {}
    out = []
    for idx, dirs in sorted(groups, key=lambda g: min(g[0])):
        local = sorted(idx)
        W = np.array(dirs).T[local]  # (k, m) in conditional standard deviations
        D = W * (sd[keep][local] / cond[local])[:, None]  # in parameter units
        pivots = _pivots(W)
        Dp = D @ np.linalg.inv(D[pivots])  # the free directions, each with its pivot's coefficient 1
        full = keep[local]
        group_names = tuple(names[i] for i in full)
        determined, free = [], []
        for a in range(len(local)):
            if a in pivots:
                continue
            coef = np.zeros(len(names))
            coef[full[a]] = 1.0
            for j, b in enumerate(pivots):
                coef[full[b]] -= Dp[a, j]
            determined.append(_combination(names, theta, cov, q, units, coef, full[a]))
        for j, b in enumerate(pivots):
            coef = np.zeros(len(names))
            coef[full] = Dp[:, j]
            pairs = ((names[full[b]], 1.0),) + tuple((names[i], float(coef[i])) for i in full if i != full[b])
            half = float(intervals[full[b], 1] - intervals[full[b], 0]) / 2
            free.append(Combination(pairs, float(theta[full[b]]), half, units.get(names[full[b]], "")))
        sub = corr[np.ix_(local, local)]
        off = sub[~np.eye(len(local), dtype=bool)]
        out.append(Confounded(group_names, float(off[np.argmax(np.abs(off))]), tuple(determined), tuple(free)))
    return out


def _pivots(W: np.ndarray) -> list[int]:
    """m rows of the (k, m) directions that carry them: greedily the row with the largest part not yet spanned,
    the last such row (in the order of the names) among those within half of the largest."""
    chosen: list[int] = []
    for _ in range(W.shape[1]):
        basis = np.linalg.qr(W[chosen].T)[0] if chosen else np.zeros((W.shape[1], 0))
        rest = np.linalg.norm(W - (W @ basis) @ basis.T, axis=1)
        rest[chosen] = 0
        chosen.append(int(np.flatnonzero(rest >= 0.5 * rest.max())[-1]))
    return chosen


def _combination(names, theta, cov, q, units, coef, lead) -> Combination:
    order = [lead] + [i for i in np.flatnonzero(coef) if i != lead]
    half = q * math.sqrt(max(float(coef @ cov @ coef), 0.0))
    return Combination(tuple((names[i], float(coef[i])) for i in order), float(coef @ theta), half,
                       units.get(names[lead], ""))


def _coefficient(c: float) -> str:
    return f"{c:.2f}" if 0.1 <= c < 100 else f"{c:.3g}"


def _signed(r: float) -> str:
    return f"{'−' if r < 0 else ''}{abs(r):.4f}".rstrip("0") if abs(r) < 0.9999 else f"{'−' if r < 0 else ''}{abs(r):.6f}"


def _short(x: float) -> str:
    return f"{x:.2g}" if math.isfinite(x) else "∞"


def _value(value: float, half: float) -> str:
    """value ± half, the value to the half-width's second significant digit."""
    if not (math.isfinite(half) and half > 0):
        return f"{value:.6g} ± {_short(half)}"
    decimals = max(0, 1 - int(math.floor(math.log10(half))))
    return f"{value:.{decimals}f} ± {half:.{decimals}f}" if decimals <= 12 else f"{value:.6g} ± {half:.2g}"
