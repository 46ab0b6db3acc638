"""The paper's comparators: a real-coded genetic algorithm (GA-ANN) and an adaptive GA (adaptive GA-ANN).

Both minimise a vectorised cost ``cost(X[n, dims]) -> (n,)`` over a search box, like
``servofmu.identification.pso.minimize_pso``, and stop after ``max_evaluations`` cost evaluations so that a
comparison can give them exactly the model evaluations PSO-ANN used (10 particles × 51
swarms = 510 with the paper's settings).

Adaptive GA after M. Srinivas, L. M. Patnaik, "Adaptive probabilities of crossover and
mutation in genetic algorithms", IEEE Trans. SMC 24(4), 1994.  Written there for a fitness f
to maximise:

    pc = k1 (fmax − f') / (fmax − favg)   if f' ≥ favg,   else k3
    pm = k2 (fmax − f)  / (fmax − favg)   if f  ≥ favg,   else k4

with f' the larger fitness of the two parents.  Here the cost c is minimised, f = −c, so
fmax − f = c − cmin, fmax − favg = cavg − cmin and "f ≥ favg" is "c ≤ cavg": good
individuals are disturbed little (the best one not at all, apart from a small default
mutation rate added against stagnation), poor ones fully.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError, check_int, check_optional_real, check_range, is_real
from ..runtime import Progress
from .search import CostFunction, OptimizeResult, check_box, check_initial, evaluate, random_population

__all__ = ["GaOptions", "AdaptiveGaOptions", "minimize_ga", "select", "crossover", "mutate",
           "adaptive_probabilities"]

SELECTIONS = ("tournament", "roulette")
CROSSOVERS = ("blend", "arithmetic")


@dataclass(frozen=True)
class _GaSettings:
    """What both GAs share: population, evaluation budget, selection, crossover kind, mutation size, elitism."""

    population: int = 20
    max_evaluations: int = 510
    selection: str = "tournament"
    tournament_size: int = 2
    crossover: str = "blend"
    blend_alpha: float = 0.5
    mutation_scale: float = 0.1
    elite: int = 1
    cost_tolerance: float | None = None


@dataclass(frozen=True)
class GaOptions(_GaSettings):
    """A real-coded GA with elitism.

    ``selection``: "tournament" (best of ``tournament_size`` drawn at random) or "roulette"
    (probability proportional to cmax − c).  ``crossover``: "blend" (BLX-α: each gene uniform
    in the parents' interval widened by ``blend_alpha`` on each side) or "arithmetic"
    (λ·a + (1 − λ)·b, one λ ~ U(0, 1) per pair).  Mutation adds N(0, (mutation_scale·width)²)
    to a gene with probability ``mutation_probability``.  ``elite`` best individuals survive
    unchanged.
    """

    crossover_probability: float = 0.8
    mutation_probability: float = 0.1

    def __post_init__(self):
        _check_common(self, "GA")
        check_range("GA option crossover_probability", self.crossover_probability, 0.0, 1.0)
        check_range("GA option mutation_probability", self.mutation_probability, 0.0, 1.0)


@dataclass(frozen=True)
class AdaptiveGaOptions(_GaSettings):
    """The adaptive GA: as GaOptions, but crossover and mutation probabilities follow each
    individual's cost (module docstring).  Srinivas & Patnaik's values: k1 = k3 = 1,
    k2 = k4 = 0.5.  Their default mutation rate on top (0.005) is per bit of a binary string;
    ``mutation_floor`` is per real gene, which stands for many bits, hence the larger 0.02.
    Without it a converged population breeds copies of its parents only."""

    k1: float = 1.0
    k2: float = 0.5
    k3: float = 1.0
    k4: float = 0.5
    mutation_floor: float = 0.02

    def __post_init__(self):
        _check_common(self, "adaptive GA")
        for name in ("k1", "k2", "k3", "k4", "mutation_floor"):
            check_range(f"adaptive GA option {name}", getattr(self, name), 0.0, 1.0)


def _check_common(o, what: str) -> None:
    check_int(f"{what} option population", o.population, 2)
    check_int(f"{what} option max_evaluations", o.max_evaluations, o.population)
    if o.selection not in SELECTIONS:
        raise UserError(f"{what} option selection must be one of {', '.join(SELECTIONS)}, not {o.selection!r}")
    check_int(f"{what} option tournament_size", o.tournament_size, 1)
    if o.crossover not in CROSSOVERS:
        raise UserError(f"{what} option crossover must be one of {', '.join(CROSSOVERS)}, not {o.crossover!r}")
    check_range(f"{what} option blend_alpha", o.blend_alpha, 0.0, 1.0)
    if not (is_real(o.mutation_scale) and o.mutation_scale > 0):
        raise UserError(f"{what} option mutation_scale must be positive, not {o.mutation_scale!r}")
    check_int(f"{what} option elite", o.elite, 0)
    if o.elite >= o.population:
        raise UserError(f"{what} option elite = {o.elite} leaves no room for offspring "
                        f"in a population of {o.population}")
    check_optional_real(f"{what} option cost_tolerance", o.cost_tolerance)


# ---------------------------------------------------------------------------
# Operators (pure functions; P: (n, dims) population, c: (n,) costs, +inf = failed)
# ---------------------------------------------------------------------------
def select(c: np.ndarray, n: int, method: str, tournament_size: int, rng: np.random.Generator) -> np.ndarray:
    """Indices (n,) of parents chosen by tournament or roulette on the costs ``c`` (lower is better)."""
    if method == "tournament":
        entrants = rng.integers(0, c.size, size=(n, tournament_size))
        return entrants[np.arange(n), np.argmin(c[entrants], axis=1)]
    finite = np.isfinite(c)
    if not finite.any():
        return rng.integers(0, c.size, size=n)
    # Fitness cmax − c (+ a little so that the worst finite one keeps a chance); failures get none.
    fitness = np.where(finite, c[finite].max() - np.where(finite, c, 0.0), 0.0)
    fitness = np.where(finite, fitness + 1e-12 * (1.0 + fitness.max()), 0.0)
    return rng.choice(c.size, size=n, p=fitness / fitness.sum())


def crossover(a: np.ndarray, b: np.ndarray, p: np.ndarray, method: str, alpha: float,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two children per parent pair (a[i], b[i]); pair i is crossed with probability p[i], else copied."""
    if method == "blend":
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        span = hi - lo
        u1, u2 = rng.random(a.shape), rng.random(a.shape)
        c1 = lo - alpha * span + u1 * (1 + 2 * alpha) * span
        c2 = lo - alpha * span + u2 * (1 + 2 * alpha) * span
    else:
        lam = rng.random((a.shape[0], 1))
        c1, c2 = lam * a + (1 - lam) * b, lam * b + (1 - lam) * a
    cross = (rng.random(a.shape[0]) < p)[:, None]
    return np.where(cross, c1, a), np.where(cross, c2, b)


def mutate(X: np.ndarray, p: np.ndarray, sigma: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gaussian mutation: gene j of row i moves by N(0, sigma[j]²) with probability p[i]."""
    hit = rng.random(X.shape) < p[:, None]
    return X + hit * rng.normal(size=X.shape) * sigma


def adaptive_probabilities(c_parent: np.ndarray, c: np.ndarray, population_cost: np.ndarray,
                           o: AdaptiveGaOptions) -> tuple[np.ndarray, np.ndarray]:
    """(pc, pm) of Srinivas & Patnaik for minimisation (module docstring).

    ``c_parent`` (pairs,): the lower cost of each parent pair; ``c`` (children,): the cost of the
    parent a child comes from; both relative to the minimum and mean of ``population_cost``
    (n,), taken over the finite costs (failed candidates count as "below average").
    """
    finite = population_cost[np.isfinite(population_cost)]
    cmin, cavg = (finite.min(), finite.mean()) if finite.size else (np.inf, np.inf)

    def rate(x, k_good, k_bad):
        good = np.isfinite(x) & (x <= cavg)
        spread = cavg - cmin
        # A converged population (cavg = cmin) leaves everyone at the minimum: rate 0 like the best.
        with np.errstate(invalid="ignore"):  # inf − inf for failed candidates, masked out by `good`
            ratio = np.where(good, (x - cmin) / spread if spread > 0 else 0.0, 1.0)
        return np.where(good, k_good * ratio, k_bad)

    pc = rate(c_parent, o.k1, o.k3)
    pm = np.minimum(rate(c, o.k2, o.k4) + o.mutation_floor, 1.0)
    return pc, pm


def minimize_ga(cost: CostFunction, lower, upper, options: GaOptions | AdaptiveGaOptions = GaOptions(),
                x0=None, seed: int | np.random.Generator = 0,
                progress: Progress | None = None) -> OptimizeResult:
    """Minimise ``cost`` over the box [lower, upper] (each (dims,)) with a GA or the adaptive GA.

    The type of ``options`` chooses the algorithm.  ``options.max_evaluations`` points are
    evaluated: a child that left crossover and mutation unchanged (a copy of its parent, common
    in the adaptive GA, whose good parents are rarely crossed) inherits its parent's cost and is
    not counted; the last generation is cut short when the budget does not cover all new
    children.  Fewer evaluations happen only if the cost tolerance stops the run or no child
    differs from its parent for ``max_evaluations`` generations in a row.  ``x0`` and ``seed``
    as in ``minimize_pso``; ``progress(evaluations, max_evaluations)`` once per
    generation.  ``iterations`` in the result counts generations.
    """
    if not isinstance(options, (GaOptions, AdaptiveGaOptions)):
        raise UserError(f"GA options must be GaOptions or AdaptiveGaOptions, not {type(options).__name__}")
    lower, upper = check_box(lower, upper)
    guesses = check_initial(x0, lower, upper, options.population)
    rng = np.random.default_rng(seed)
    sigma = options.mutation_scale * (upper - lower)
    n, budget = options.population, options.max_evaluations

    P = random_population(lower, upper, n, rng, guesses)
    c = evaluate(cost, P)
    evaluations = n
    best = int(np.argmin(c))
    cost_history, position_history = [c[best]], [P[best].copy()]
    stopped, done, idle = False, 0, 0

    while evaluations < budget and idle < budget:
        if options.cost_tolerance is not None and c[best] <= options.cost_tolerance:
            stopped = True
            break
        n_children = n - options.elite
        pairs = (n_children + 1) // 2
        ia = select(c, pairs, options.selection, options.tournament_size, rng)
        ib = select(c, pairs, options.selection, options.tournament_size, rng)
        parent = np.concatenate([ia, ib])  # the parent each child comes from
        if isinstance(options, AdaptiveGaOptions):
            pc, pm = adaptive_probabilities(np.minimum(c[ia], c[ib]), c[parent], c, options)
        else:
            pc = np.full(pairs, options.crossover_probability)
            pm = np.full(2 * pairs, options.mutation_probability)
        ca, cb = crossover(P[ia], P[ib], pc, options.crossover, options.blend_alpha, rng)
        children = np.clip(mutate(np.concatenate([ca, cb]), pm, sigma, rng), lower, upper)
        # One child of each pair first, so that an odd count or a cut-short generation mixes all pairs.
        order = np.concatenate([np.arange(pairs), pairs + np.arange(pairs)])[:n_children]
        children, parent = children[order], parent[order]

        new = np.flatnonzero(np.any(children != P[parent], axis=1))
        dropped = new[budget - evaluations:]  # new children beyond the budget are not evaluated
        keep = np.setdiff1d(np.arange(n_children), dropped)
        new = new[: budget - evaluations]
        c_children = c[parent]
        if new.size:
            c_children[new] = evaluate(cost, children[new])
        evaluations += new.size
        idle = 0 if new.size else idle + 1
        children, c_children = children[keep], c_children[keep]

        survivors = np.argsort(c, kind="stable")[: n - keep.size]
        P = np.concatenate([P[survivors], children])
        c = np.concatenate([c[survivors], c_children])
        best = int(np.argmin(c))
        cost_history.append(c[best])
        position_history.append(P[best].copy())
        done += 1
        if progress is not None:
            progress(evaluations, budget)

    return OptimizeResult(position=P[best].copy(), cost=float(c[best]), cost_history=np.array(cost_history),
                          position_history=np.array(position_history), evaluations=evaluations,
                          iterations=done, stopped_early=stopped)
