"""Particle swarm optimisation over a search box: pure, vectorised operators on arrays.

A cost function takes the whole swarm at once, ``cost(X) -> c`` with ``X`` of shape
(particles, dims) and ``c`` of shape (particles,), so that the caller can simulate all
candidates in one batch.  A non-finite cost (a candidate whose simulation failed) counts
as the worst possible cost.

The defaults are the paper's Table I: 10 particles, 50 iterations and an inertia weight
that falls linearly from w_max = 1 to w_min = 0.  The helpers shared with the genetic
algorithms (search box, cost evaluation, the result type) live here as well.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import UserError

CostFunction = Callable[[np.ndarray], np.ndarray]
# progress(done, total, best_cost): once per iteration; PSO counts iterations, the GAs evaluations.
Progress = Callable[[int, int, float], None]


@dataclass(frozen=True)
class PsoOptions:
    """Settings of the swarm (the paper's Table I by default).

    ``velocity_clamp``: largest speed per iteration as a fraction of the box width in each dimension.
    ``cost_tolerance``: stop as soon as the best cost is at or below it (None: run all iterations).
    """

    particles: int = 10
    iterations: int = 50
    w_max: float = 1.0
    w_min: float = 0.0
    c1: float = 1.5
    c2: float = 1.5
    velocity_clamp: float = 0.5
    cost_tolerance: float | None = None

    def __post_init__(self):
        check_int("PSO option particles", self.particles, 1)
        check_int("PSO option iterations", self.iterations, 0)
        for name in ("w_max", "w_min"):
            check_range(f"PSO option {name}", getattr(self, name), 0.0, 1.0)
        if self.w_min > self.w_max:
            raise UserError(f"PSO option w_min = {self.w_min} is above w_max = {self.w_max}")
        for name in ("c1", "c2"):
            check_range(f"PSO option {name}", getattr(self, name), 0.0, 2.0)
        if not (is_real(self.velocity_clamp) and 0.0 < self.velocity_clamp <= 1.0):
            raise UserError(f"PSO option velocity_clamp must be in (0, 1], not {self.velocity_clamp!r}")
        check_tolerance("PSO option cost_tolerance", self.cost_tolerance)


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


# ---------------------------------------------------------------------------
# Helpers shared with ga.py
# ---------------------------------------------------------------------------
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


def is_real(x) -> bool:
    """A finite real number (not a bool)."""
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and math.isfinite(x)


def check_int(what: str, value, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise UserError(f"{what} must be an integer >= {minimum}, not {value!r}")


def check_range(what: str, value, lo: float, hi: float) -> None:
    if not (is_real(value) and lo <= value <= hi):
        raise UserError(f"{what} must be in [{lo:g}, {hi:g}], not {value!r}")


def check_tolerance(what: str, tol) -> None:
    if tol is not None and not is_real(tol):
        raise UserError(f"{what} must be a finite number or None, not {tol!r}")


# ---------------------------------------------------------------------------
# PSO operators (pure functions of the swarm state)
#   X, V, pbest: (particles, dims); pbest_cost: (particles,); gbest: (dims,)
# ---------------------------------------------------------------------------
def inertia_weight(iteration: int, iterations: int, w_max: float, w_min: float) -> float:
    """Linearly falling inertia: w_max at the first iteration, w_min at the last."""
    if iterations <= 1:
        return w_max
    return w_max - (w_max - w_min) * iteration / (iterations - 1)


def update_velocity(X, V, pbest, gbest, w: float, c1: float, c2: float, vmax: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """v ← w·v + c1·r1·(pbest − x) + c2·r2·(gbest − x), clamped to ±vmax (vmax: (dims,))."""
    r1 = rng.random(X.shape)
    r2 = rng.random(X.shape)
    V = w * V + c1 * r1 * (pbest - X) + c2 * r2 * (gbest - X)
    return np.clip(V, -vmax, vmax)


def update_position(X, V, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """x ← x + v, with absorbing walls: a particle that leaves the box stops on its wall.

    The velocity component that pushed it out is zeroed so that it does not keep pressing
    on the wall; an optimum on the boundary stays reachable (a reflecting wall would bounce
    away from it).
    """
    X = X + V
    out = (X < lower) | (X > upper)
    return np.clip(X, lower, upper), np.where(out, 0.0, V)


def minimize_pso(cost: CostFunction, lower, upper, options: PsoOptions = PsoOptions(), x0=None,
                 seed: int | np.random.Generator = 0, progress: Progress | None = None) -> OptimizeResult:
    """Minimise ``cost`` over the box [lower, upper] (each (dims,)) with a particle swarm.

    ``x0``: an initial guess (dims,) or several (k, dims), placed as the first particles
    (clipped into the box); the identifier passes the ANN estimate here.  ``seed``: an int
    or a numpy Generator; the run is a deterministic function of it.
    """
    lower, upper = check_box(lower, upper)
    guesses = check_initial(x0, lower, upper, options.particles)
    rng = np.random.default_rng(seed)
    vmax = options.velocity_clamp * (upper - lower)

    X = random_population(lower, upper, options.particles, rng, guesses)
    V = rng.uniform(-vmax, vmax, size=X.shape)
    c = evaluate(cost, X)
    pbest, pbest_cost = X.copy(), c.copy()
    best = int(np.argmin(pbest_cost))
    cost_history, position_history = [pbest_cost[best]], [pbest[best].copy()]
    evaluations, done, stopped = options.particles, 0, False

    for k in range(options.iterations):
        if options.cost_tolerance is not None and pbest_cost[best] <= options.cost_tolerance:
            stopped = True
            break
        w = inertia_weight(k, options.iterations, options.w_max, options.w_min)
        V = update_velocity(X, V, pbest, pbest[best], w, options.c1, options.c2, vmax, rng)
        X, V = update_position(X, V, lower, upper)
        c = evaluate(cost, X)
        evaluations += options.particles
        improved = c < pbest_cost
        pbest[improved], pbest_cost[improved] = X[improved], c[improved]
        best = int(np.argmin(pbest_cost))
        cost_history.append(pbest_cost[best])
        position_history.append(pbest[best].copy())
        done = k + 1
        if progress is not None:
            progress(done, options.iterations, float(pbest_cost[best]))

    return OptimizeResult(position=pbest[best].copy(), cost=float(pbest_cost[best]),
                          cost_history=np.array(cost_history), position_history=np.array(position_history),
                          evaluations=evaluations, iterations=done, stopped_early=stopped)
