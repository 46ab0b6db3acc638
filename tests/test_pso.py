"""PSO against known minima, its bookkeeping (bounds, history, determinism) and its option checks."""
import numpy as np
import pytest

from servofmu.errors import UserError
from servofmu.identification.pso import PsoOptions, inertia_weight, minimize_pso, update_position


def sphere(X):
    return np.sum(X**2, axis=1)


def rosenbrock(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


def test_sphere_with_the_papers_settings():
    res = minimize_pso(sphere, -5 * np.ones(2), 5 * np.ones(2), PsoOptions(), seed=1)
    assert res.evaluations == 10 * 51 and res.iterations == 50
    assert res.cost == pytest.approx(sphere(res.position[None])[0])
    np.testing.assert_allclose(res.position, 0.0, atol=1e-3)


@pytest.mark.parametrize("dims, particles, iterations, atol", [(2, 30, 300, 1e-4), (3, 100, 2000, 1e-3),
                                                                (4, 100, 2000, 5e-2)])
def test_rosenbrock(dims, particles, iterations, atol):
    res = minimize_pso(rosenbrock, -2 * np.ones(dims), 2 * np.ones(dims),
                       PsoOptions(particles=particles, iterations=iterations), seed=3)
    np.testing.assert_allclose(res.position, 1.0, atol=atol)


def test_shifted_quadratic_inside_an_asymmetric_box():
    # Scales as in the identification problem: pole −10, gain 10, friction 0.5/0.4.
    target = np.array([-10.0, 10.0, 0.5, 0.4])
    scale = np.array([1.0, 1.0, 0.05, 0.05])
    lower, upper = np.array([-13.0, 7.0, 0.3, 0.1]), np.array([-9.0, 14.0, 0.6, 0.9])

    def cost(X):
        return np.sum(((X - target) / scale) ** 2, axis=1)

    res = minimize_pso(cost, lower, upper, PsoOptions(particles=20, iterations=200), seed=0)
    np.testing.assert_allclose(res.position, target, rtol=1e-4)


def test_minimum_on_the_boundary_is_reached():
    # The unconstrained minimum (−1) lies outside; the best point in the box is its wall at 0.
    res = minimize_pso(lambda X: np.sum((X + 1.0) ** 2, axis=1), np.zeros(3), np.ones(3),
                       PsoOptions(particles=10, iterations=50), seed=2)
    np.testing.assert_array_equal(res.position, 0.0)


def test_bounds_never_violated_and_cost_sees_every_particle():
    lower, upper = np.array([-1.0, 2.0, -0.1]), np.array([1.0, 3.0, 0.1])
    seen = []

    def cost(X):
        seen.append(X.copy())
        return rosenbrock(X)

    res = minimize_pso(cost, lower, upper, PsoOptions(particles=7, iterations=40, c1=2.0, c2=2.0,
                                                      velocity_clamp=1.0), seed=5)
    allX = np.concatenate(seen)
    assert allX.shape == (7 * 41, 3) == (res.evaluations, 3)
    assert np.all(allX >= lower) and np.all(allX <= upper)
    assert np.all(res.position_history >= lower) and np.all(res.position_history <= upper)


def test_absorbing_wall_stops_the_particle_and_its_velocity():
    X, V = update_position(np.array([[0.5, 0.5]]), np.array([[0.8, -0.2]]), np.zeros(2), np.ones(2))
    np.testing.assert_array_equal(X, [[1.0, 0.3]])
    np.testing.assert_array_equal(V, [[0.0, -0.2]])


def test_history_is_monotone_and_ends_at_the_result():
    res = minimize_pso(rosenbrock, -2 * np.ones(3), 2 * np.ones(3), PsoOptions(iterations=60), seed=4)
    assert res.cost_history.shape == (61,) and res.position_history.shape == (61, 3)
    assert np.all(np.diff(res.cost_history) <= 0)
    assert res.cost_history[-1] == res.cost
    np.testing.assert_array_equal(res.position_history[-1], res.position)
    np.testing.assert_allclose(rosenbrock(res.position_history), res.cost_history)


def test_same_seed_same_run_other_seed_other_run():
    box = (-2 * np.ones(3), 2 * np.ones(3))
    a = minimize_pso(rosenbrock, *box, seed=11)
    b = minimize_pso(rosenbrock, *box, seed=11)
    c = minimize_pso(rosenbrock, *box, seed=12)
    np.testing.assert_array_equal(a.position_history, b.position_history)
    assert a.cost == b.cost
    assert not np.array_equal(a.position_history, c.position_history)
    g1, g2 = np.random.default_rng(7), np.random.default_rng(7)
    np.testing.assert_array_equal(minimize_pso(rosenbrock, *box, seed=g1).position,
                                  minimize_pso(rosenbrock, *box, seed=g2).position)


def test_initial_guess_is_a_particle():
    guess = np.array([0.25, -0.5])
    first = []

    def cost(X):
        if not first:
            first.append(X.copy())
        return sphere(X - guess)

    res = minimize_pso(cost, -np.ones(2), np.ones(2), PsoOptions(iterations=0), x0=guess, seed=0)
    np.testing.assert_array_equal(first[0][0], guess)
    np.testing.assert_array_equal(res.position, guess)   # the guess is the exact minimum
    assert res.cost == 0.0 and res.evaluations == 10


def test_initial_guess_outside_the_box_is_clipped():
    """The guess enters the swarm on the box's wall: the first particle the cost sees is the clipped guess.  (The
    result alone cannot tell: sphere's best point in this box is inside it with or without the clipping.)"""
    seen = []

    def cost(X):
        seen.append(X.copy())
        return sphere(X)

    res = minimize_pso(cost, np.ones(2), 2 * np.ones(2), PsoOptions(iterations=3), x0=[0.5, 3.0], seed=0)
    np.testing.assert_array_equal(seen[0][0], [1.0, 2.0])
    allX = np.concatenate(seen)
    assert np.all(allX >= 1.0) and np.all(allX <= 2.0)
    assert np.all(res.position >= 1.0) and np.all(res.position <= 2.0)


def test_cost_tolerance_stops_early():
    res = minimize_pso(sphere, -np.ones(2), np.ones(2), PsoOptions(iterations=500, cost_tolerance=1e-6), seed=0)
    assert res.stopped_early and res.cost <= 1e-6 and res.iterations < 500
    assert res.evaluations == 10 * (res.iterations + 1)
    assert res.cost_history[-2] > 1e-6   # it stopped at the first iteration that met the tolerance


def test_failed_candidates_count_as_worst():
    def cost(X):
        c = sphere(X - 0.5)
        return np.where(X[:, 0] < 0, np.nan, c)   # "simulation failed" in half of the box

    res = minimize_pso(cost, -np.ones(2), np.ones(2), PsoOptions(particles=20, iterations=100), seed=0)
    assert np.isfinite(res.cost_history).all()
    np.testing.assert_allclose(res.position, 0.5, atol=1e-3)


def test_inertia_falls_linearly_from_w_max_to_w_min():
    w = [inertia_weight(k, 50, 1.0, 0.0) for k in range(50)]
    assert w[0] == 1.0 and w[-1] == 0.0
    np.testing.assert_allclose(np.diff(w), -1 / 49)


@pytest.mark.parametrize("kwargs, words", [
    (dict(particles=0), "particles"), (dict(particles=2.5), "particles"), (dict(iterations=-1), "iterations"),
    (dict(w_max=1.2), "w_max"), (dict(w_min=-0.1), "w_min"), (dict(w_min=0.8, w_max=0.5), "w_min"),
    (dict(c1=2.5), "c1"), (dict(c2=-1), "c2"), (dict(c1=float("nan")), "c1"),
    (dict(velocity_clamp=0), "velocity_clamp"), (dict(cost_tolerance="low"), "cost_tolerance"),
])
def test_bad_options_raise_user_error(kwargs, words):
    with pytest.raises(UserError, match=words) as info:
        PsoOptions(**kwargs)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("lower, upper, x0, words", [
    ([0, 1], [1, 0], None, "dimension 1"), ([0, 0], [1, 1, 1], None, "lower and upper"),
    ([0, -np.inf], [1, 1], None, "finite"), ([0, 0], [1, 1], [0.5], "initial guess"),
    ([0, 0], [1, 1], [0.5, np.nan], "initial guess"),
])
def test_bad_box_or_guess_raises_user_error(lower, upper, x0, words):
    with pytest.raises(UserError, match=words):
        minimize_pso(sphere, lower, upper, x0=x0)


def test_cost_of_wrong_shape_raises_user_error():
    with pytest.raises(UserError, match="cost function returned shape"):
        minimize_pso(lambda X: X, np.zeros(2), np.ones(2))
