"""What the searches (particle swarm, genetic algorithms) share: the search box, the initial population, cost
evaluation and the result type.

A cost function takes the whole population at once, ``cost(X) -> c`` with ``X`` of shape (n, dims) and ``c`` of
shape (n,), so that the caller can simulate all candidates in one batch.  A non-finite cost (a candidate whose
simulation failed) counts as the worst possible cost.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import UserError

__all__ = ["CostFunction", "OptimizeResult", "check_box", "check_initial", "random_population", "evaluate"]

CostFunction = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class OptimizeResult:
    """The outcome of a search (PSO or GA).

    position          (dims,)                best point found
    cost              float                  its cost (inf if every evaluation failed)
    cost_history      (iterations + 1,)      best cost after the initial population and after each
                                             iteration (generation); non-increasing (for a GA:
                                             if it keeps at least one elite)
    position_history  (iterations + 1, dims) the best point at the same moments
    evaluations       int                    number of points the cost function was asked for
    iterations        int                    iterations (generations) run after the initial population
    stopped_early     bool                   True if the cost tolerance ended the run
    """

    position: np.ndarray
    cost: float
    cost_history: np.ndarray
    position_history: np.ndarray
    evaluations: int
    iterations: int
    stopped_early: bool


def check_box(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """The search box as two float arrays of shape (dims,), finite and with lower < upper."""
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    if lower.ndim != 1 or lower.shape != upper.shape or lower.size == 0:
        raise UserError(f"search box: lower and upper must be 1-D arrays of one length "
                        f"(shapes {lower.shape} and {upper.shape})")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise UserError("search box: bounds must be finite")
    bad = np.flatnonzero(~(lower < upper))
    if bad.size:
        i = bad[0]
        raise UserError(f"search box: dimension {i} has lower {lower[i]} not below upper {upper[i]}")
    return lower, upper


def check_initial(x0, lower: np.ndarray, upper: np.ndarray, population: int) -> np.ndarray:
    """Initial guesses as an array (k, dims), k <= population, clipped into the box.

    Clipping rather than refusing: a box intersected with physical limits (friction >= 0)
    may cut off an estimate that lies just outside.
    """
    if x0 is None:
        return np.empty((0, lower.size))
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    if x0.ndim != 2 or x0.shape[1] != lower.size:
        raise UserError(f"initial guess: expected {lower.size} values per guess, got shape {x0.shape}")
    if x0.shape[0] > population:
        raise UserError(f"initial guess: {x0.shape[0]} guesses for a population of {population}")
    if not np.all(np.isfinite(x0)):
        raise UserError("initial guess: contains NaN or infinite values")
    return np.clip(x0, lower, upper)


def random_population(lower: np.ndarray, upper: np.ndarray, n: int, rng: np.random.Generator,
                      x0: np.ndarray) -> np.ndarray:
    """(n, dims) points uniform in the box; the first rows are the initial guesses ``x0`` (k, dims)."""
    X = lower + rng.random((n, lower.size)) * (upper - lower)
    X[: len(x0)] = x0
    return X


def evaluate(cost: CostFunction, X: np.ndarray) -> np.ndarray:
    """cost(X) as a float array (n,), with NaN and -inf/+inf failures turned into +inf (worst)."""
    c = np.asarray(cost(X.copy()), dtype=float)  # a copy: the cost function must not move the swarm
    if c.shape != (X.shape[0],):
        raise UserError(f"cost function returned shape {c.shape} for {X.shape[0]} candidates "
                        f"(expected ({X.shape[0]},))")
    return np.where(np.isnan(c) | np.isinf(c), np.inf, c)
