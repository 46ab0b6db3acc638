"""Particle swarm optimisation over a search box: pure, vectorised operators on arrays.

The cost function takes the whole swarm at once (servofmu.identification.search).  The defaults are the
paper's Table I: 10 particles, 50 iterations and an inertia weight that falls linearly from w_max = 1 to
w_min = 0.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import UserError, check_int, check_optional_real, check_range, is_real
from ..runtime import Progress
from .search import CostFunction, OptimizeResult, check_box, check_initial, evaluate, random_population

__all__ = ["PsoOptions", "minimize_pso", "inertia_weight", "update_velocity", "update_position"]


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
        check_optional_real("PSO option cost_tolerance", self.cost_tolerance)


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
                 seed: int | np.random.Generator = 0, progress: Progress | None = None,
                 stop: Callable[[], bool] | None = None) -> OptimizeResult:
    """Minimise ``cost`` over the box [lower, upper] (each (dims,)) with a particle swarm.

    ``x0``: an initial guess (dims,) or several (k, dims), placed as the first particles
    (clipped into the box); the identifier passes the ANN estimate here.  ``seed``: an int
    or a numpy Generator; the run is a deterministic function of it.  ``stop``: asked before every iteration; the
    swarm ends there (``stopped_early``) when it says so (a selection's time budget per candidate).
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
        if options.cost_tolerance is not None and pbest_cost[best] <= options.cost_tolerance or stop and stop():
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
            progress(done, options.iterations)

    return OptimizeResult(position=pbest[best].copy(), cost=float(pbest_cost[best]),
                          cost_history=np.array(cost_history), position_history=np.array(position_history),
                          evaluations=evaluations, iterations=done, stopped_early=stopped)
