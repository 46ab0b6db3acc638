"""The GA and adaptive GA comparators: known minima, evaluation budget, bounds, history, determinism, options."""
import numpy as np
import pytest

from servofmu.errors import UserError
from servofmu.identification.ga import (
    AdaptiveGaOptions,
    GaOptions,
    adaptive_probabilities,
    crossover,
    minimize_ga,
    select,
)

ALGORITHMS = [GaOptions, AdaptiveGaOptions]


def sphere(X):
    return np.sum(X**2, axis=1)


def rosenbrock(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


@pytest.mark.parametrize("Options", ALGORITHMS)
@pytest.mark.parametrize("selection", ["tournament", "roulette"])
@pytest.mark.parametrize("method", ["blend", "arithmetic"])
def test_sphere_all_operator_choices(Options, selection, method):
    res = minimize_ga(sphere, -5 * np.ones(3), 5 * np.ones(3),
                      Options(max_evaluations=4000, selection=selection, crossover=method), seed=0)
    np.testing.assert_allclose(res.position, 0.0, atol=0.05)


@pytest.mark.parametrize("Options", ALGORITHMS)
def test_shifted_quadratic_inside_an_asymmetric_box(Options):
    target = np.array([-10.0, 10.0, 0.5, 0.4])
    scale = np.array([1.0, 1.0, 0.05, 0.05])
    lower, upper = np.array([-13.0, 7.0, 0.3, 0.1]), np.array([-9.0, 14.0, 0.6, 0.9])

    def cost(X):
        return np.sum(((X - target) / scale) ** 2, axis=1)

    res = minimize_ga(cost, lower, upper, Options(max_evaluations=5000), seed=1)
    np.testing.assert_allclose(res.position, target, rtol=2e-3)


@pytest.mark.parametrize("Options", ALGORITHMS)
def test_rosenbrock_2d(Options):
    # GAs creep along the curved valley: a loose tolerance, but far from the start (the box's random points).
    res = minimize_ga(rosenbrock, -2 * np.ones(2), 2 * np.ones(2), Options(max_evaluations=10000), seed=0)
    np.testing.assert_allclose(res.position, 1.0, atol=0.2)
    assert res.cost < 1e-2 < res.cost_history[0]


@pytest.mark.parametrize("Options", ALGORITHMS)
@pytest.mark.parametrize("budget", [510, 20, 37])
def test_evaluation_budget_is_spent_exactly_and_bounds_hold(Options, budget):
    lower, upper = np.array([-1.0, 2.0, -0.1]), np.array([1.0, 3.0, 0.1])
    seen = []

    def cost(X):
        seen.append(X.copy())
        return rosenbrock(X)

    res = minimize_ga(cost, lower, upper, Options(max_evaluations=budget, mutation_scale=1.0), seed=5)
    allX = np.concatenate(seen)
    assert allX.shape[0] == res.evaluations == budget
    assert np.all(allX >= lower) and np.all(allX <= upper)


@pytest.mark.parametrize("Options", ALGORITHMS)
def test_children_copied_from_a_parent_are_not_evaluated_again(Options):
    seen = []

    def cost(X):
        seen.append(X.copy())
        return rosenbrock(X)

    res = minimize_ga(cost, -2 * np.ones(3), 2 * np.ones(3), Options(max_evaluations=1000), seed=3)
    allX = np.concatenate(seen)
    assert res.evaluations == 1000 == len(np.unique(allX, axis=0))
    # The adaptive GA rarely crosses good parents, so copies are common there: it needs more generations.
    if Options is AdaptiveGaOptions:
        assert res.iterations > (1000 - 20) / 19


@pytest.mark.parametrize("Options", ALGORITHMS)
def test_history_is_monotone_and_ends_at_the_result(Options):
    res = minimize_ga(rosenbrock, -2 * np.ones(3), 2 * np.ones(3), Options(max_evaluations=600), seed=4)
    assert res.cost_history.shape == (res.iterations + 1,) and res.position_history.shape == (res.iterations + 1, 3)
    assert np.all(np.diff(res.cost_history) <= 0)
    assert res.cost_history[-1] == res.cost
    np.testing.assert_allclose(rosenbrock(res.position_history), res.cost_history)


def test_elitism_off_can_lose_the_best():
    # Without elites and with a destructive mutation the best cost may rise; the history
    # records the population's best, so it need not be monotone, but the result is still its last entry.
    res = minimize_ga(sphere, -np.ones(2), np.ones(2),
                      GaOptions(elite=0, mutation_probability=1.0, mutation_scale=1.0, max_evaluations=400), seed=0)
    assert np.any(np.diff(res.cost_history) > 0)
    assert res.cost == res.cost_history[-1]


@pytest.mark.parametrize("Options", ALGORITHMS)
def test_same_seed_same_run_other_seed_other_run(Options):
    box = (-2 * np.ones(3), 2 * np.ones(3))
    a = minimize_ga(rosenbrock, *box, Options(), seed=11)
    b = minimize_ga(rosenbrock, *box, Options(), seed=11)
    c = minimize_ga(rosenbrock, *box, Options(), seed=12)
    np.testing.assert_array_equal(a.position_history, b.position_history)
    assert not np.array_equal(a.position_history, c.position_history)


@pytest.mark.parametrize("Options", ALGORITHMS)
def test_initial_guess_is_an_individual(Options):
    guess = np.array([0.25, -0.5])
    res = minimize_ga(lambda X: sphere(X - guess), -np.ones(2), np.ones(2), Options(max_evaluations=20),
                      x0=guess, seed=0)
    np.testing.assert_array_equal(res.position, guess)
    assert res.cost == 0.0


def test_cost_tolerance_stops_early():
    res = minimize_ga(sphere, -np.ones(2), np.ones(2), GaOptions(max_evaluations=100000, cost_tolerance=1e-4),
                      seed=0)
    assert res.stopped_early and res.cost <= 1e-4 and res.evaluations < 100000


def test_failed_candidates_count_as_worst():
    def cost(X):
        return np.where(X[:, 0] < 0, np.inf, sphere(X - 0.5))

    for Options in ALGORITHMS:
        for selection in ("tournament", "roulette"):
            res = minimize_ga(cost, -np.ones(2), np.ones(2), Options(max_evaluations=3000, selection=selection),
                              seed=0)
            np.testing.assert_allclose(res.position, 0.5, atol=0.02)


def test_tournament_picks_the_better_entrant():
    c = np.array([3.0, 1.0, 2.0, np.inf])
    rng = np.random.default_rng(0)
    picks = select(c, 2000, "tournament", 4, rng)
    # With 4 entrants drawn with replacement, index 1 wins whenever drawn: P = 1 − (3/4)^4.
    assert abs(np.mean(picks == 1) - (1 - 0.75**4)) < 0.03
    # A failed candidate (inf) wins only a tournament against itself: P = (1/4)^2 with 2 entrants.
    assert abs(np.mean(select(c, 20000, "tournament", 2, rng) == 3) - 1 / 16) < 0.01


def test_roulette_is_proportional_to_cmax_minus_c_and_skips_failures():
    c = np.array([0.0, 1.0, 3.0, np.nan])
    picks = select(np.where(np.isnan(c), np.inf, c), 20000, "roulette", 2, np.random.default_rng(1))
    freq = np.bincount(picks, minlength=4) / picks.size
    np.testing.assert_allclose(freq[:3], [3 / 5, 2 / 5, 0.0], atol=0.01)
    assert freq[3] == 0.0


def test_blend_crossover_stays_in_the_widened_interval_and_arithmetic_on_the_segment():
    rng = np.random.default_rng(0)
    a, b = np.zeros((500, 2)), np.ones((500, 2))
    c1, c2 = crossover(a, b, np.ones(500), "blend", 0.5, rng)
    both = np.concatenate([c1, c2])
    assert both.min() >= -0.5 and both.max() <= 1.5 and both.min() < -0.4 and both.max() > 1.4
    c1, c2 = crossover(a, b, np.ones(500), "arithmetic", 0.5, rng)
    np.testing.assert_allclose(c1 + c2, 1.0)              # λa + (1−λ)b and λb + (1−λ)a
    np.testing.assert_allclose(c1[:, 0], c1[:, 1])        # one λ per pair
    c1, c2 = crossover(a, b, np.zeros(500), "blend", 0.5, rng)
    np.testing.assert_array_equal(c1, a)                  # probability 0: copies
    np.testing.assert_array_equal(c2, b)


def test_adaptive_probabilities_follow_srinivas_patnaik_for_minimisation():
    o = AdaptiveGaOptions(k1=1.0, k2=0.5, k3=1.0, k4=0.5, mutation_floor=0.0)
    population = np.array([1.0, 2.0, 3.0, 6.0])            # cmin 1, cavg 3
    pc, pm = adaptive_probabilities(np.array([1.0, 2.0, 3.0, 4.0, np.inf]),
                                    np.array([1.0, 2.0, 3.0, 6.0, np.inf]), population, o)
    # Written for the fitness f = −c: pc = k1 (fmax − f')/(fmax − favg) if f' ≥ favg else k3.
    f, fp = -population, -np.array([1.0, 2.0, 3.0, 4.0])
    fmax, favg = f.max(), f.mean()
    expected_pc = np.where(fp >= favg, 1.0 * (fmax - fp) / (fmax - favg), 1.0)
    np.testing.assert_allclose(pc[:4], expected_pc)
    np.testing.assert_allclose(pm[:4], np.where(f >= favg, 0.5 * (fmax - f) / (fmax - favg), 0.5))
    assert pc[4] == 1.0 and pm[4] == 0.5                  # a failed candidate is "below average"
    assert pc[0] == 0.0 and pm[0] == 0.0                  # the best is left alone
    _, pm = adaptive_probabilities(np.zeros(1), np.zeros(2), np.zeros(4), AdaptiveGaOptions())
    np.testing.assert_allclose(pm, AdaptiveGaOptions().mutation_floor)  # converged: only the floor


@pytest.mark.parametrize("Options, kwargs, words", [
    (GaOptions, dict(population=1), "population"), (GaOptions, dict(max_evaluations=5), "max_evaluations"),
    (GaOptions, dict(selection="rank"), "selection"), (GaOptions, dict(crossover="sbx"), "crossover"),
    (GaOptions, dict(crossover_probability=1.5), "crossover_probability"),
    (GaOptions, dict(mutation_probability=-0.1), "mutation_probability"),
    (GaOptions, dict(mutation_scale=0), "mutation_scale"), (GaOptions, dict(elite=20), "elite"),
    (GaOptions, dict(tournament_size=0), "tournament_size"), (GaOptions, dict(blend_alpha=2), "blend_alpha"),
    (AdaptiveGaOptions, dict(k1=1.5), "k1"), (AdaptiveGaOptions, dict(k4=-1), "k4"),
    (AdaptiveGaOptions, dict(mutation_floor=2), "mutation_floor"),
    (AdaptiveGaOptions, dict(cost_tolerance=float("nan")), "cost_tolerance"),
])
def test_bad_options_raise_user_error(Options, kwargs, words):
    with pytest.raises(UserError, match=words) as info:
        Options(**kwargs)
    assert "\n" not in str(info.value)


def test_bad_box_guess_cost_or_options_type_raise_user_error():
    with pytest.raises(UserError, match="dimension 0"):
        minimize_ga(sphere, [1.0], [0.0])
    with pytest.raises(UserError, match="initial guess"):
        minimize_ga(sphere, [0.0, 0.0], [1.0, 1.0], x0=[1.0, 2.0, 3.0])
    with pytest.raises(UserError, match="cost function returned shape"):
        minimize_ga(lambda X: X[:2, 0], [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(UserError, match="GaOptions or AdaptiveGaOptions"):
        minimize_ga(sphere, [0.0], [1.0], options={"population": 10})
