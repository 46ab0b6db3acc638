"""The batch simulator against two independent references: scipy's Radau on the plant equations
(tests/reference.py, written without the package) and the FMU run through FMPy, with the first harmonic
computed here by its own quadrature.  Relative errors: |H − H_ref|/|H_ref| for H, and |dc − dc_ref|
relative to the response amplitude |H_ref|·m for the DC component."""
import copy
import functools
import os
import subprocess
import sys

import numpy as np
import pytest
from fmpy import simulate_fmu
from reference import friction, gain_from_dc, simulate_reference
from scipy import signal
from scipy.integrate import solve_ivp

from servofmu.errors import UserError
from servofmu.identification.criterion import POLISH_RTOL, SEARCH_RTOL, STEP_BUDGET_FACTOR, SineCriterion, SineData
from servofmu.identification.prior import full_vectors, identified_mask
from servofmu.model.plant import PlantError, bristle_nominal, load_plant, plant_from_dict, state_scale
from servofmu.simulation.batch import (
    BatchSimulator,
    SteadyStateFeatures,
    SteadyStateOptions,
    WarmStarts,
    valid_parameter_sets,
)
from servofmu.simulation.compiled import DRIVER, library_key

COULOMB = {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4, "fv": 0.0, "v_smooth": 1e-3}
NOMINAL = {  # the plant files' contents, written out again: poles, zeros, DC gain, friction
    "g1": ([-10.0], [], 1.0, COULOMB),
    "g2": ([-2.5 + 31.52j, -2.5 - 31.52j, -10.0], [], 1.0, COULOMB),
}
# A second parameter set per plant, so that the parameter vector's order is tested too.
PERTURBED = {
    "g1": ([-7.0], [], 1.3, {**COULOMB, "fc_pos": 0.45, "fc_neg": 0.3, "fv": 0.05}),
    "g2": ([-3.0 + 28.0j, -3.0 - 28.0j, -12.0], [], 0.9, {**COULOMB, "fc_pos": 0.35, "fc_neg": 0.45}),
}
SETS = {"nominal": NOMINAL, "perturbed": PERTURBED}
TOL = 1e-6  # the agreement asked of the batch simulator


def vector(name, params):
    """The parameter vector of ``params`` in the order of the plant's parameter_names()."""
    poles, _, dc, fr = params
    by_name = {"dc_gain": dc, **{k: v for k, v in fr.items() if k != "model"}}
    upper = [p for p in poles if p.imag >= 0]
    for i, p in enumerate(upper, start=1):
        if p.imag != 0:
            by_name.update({f"pole{i}_re": p.real, f"pole{i}_im": p.imag})
        else:
            by_name[f"pole{i}"] = p.real
    return np.array([by_name[n] for n in load_plant(name).parameter_names()])


def period_features(t, v, f, m):
    """H and DC from samples over one whole period (uniform, both ends included): a trapezoid sum, which for
    a periodic signal is exact up to aliasing of harmonics near the sampling rate."""
    t, v = t[:-1], v[:-1]
    s1 = 1j * 2 / len(v) * np.sum(v * np.exp(-2j * np.pi * f * t))
    return s1 / m, v.mean()


def position_features(t, pos, f, m):
    """H and DC from the position (the integral of v) over one whole period: DC is exact, and integrating by
    parts, S1 = j(2/T)∫v·e^{-jωt}dt = −(2ω/T)∫p̃·e^{-jωt}dt with the periodic
    p̃ = pos − pos(t0) − DC·(t − t0), one order smoother than v, so its trapezoid sum converges faster."""
    T, w = 1 / f, 2 * np.pi * f
    dc = (pos[-1] - pos[0]) / T
    ptil = pos - pos[0] - dc * (t - t[0])
    s1 = -(2 * w / T) * np.sum(ptil[:-1] * np.exp(-1j * w * t[:-1])) * (T / (len(t) - 1))
    return s1 / m, dc


def assert_close(H, dc, H_ref, dc_ref, m, tol=TOL):
    assert abs(H - H_ref) / abs(H_ref) < tol, (H, H_ref)
    assert abs(dc - dc_ref) / (abs(H_ref) * m) < tol, (dc, dc_ref)


@functools.lru_cache(maxsize=None)
def simulator(name):
    return BatchSimulator(load_plant(name), threads=2)


@functools.lru_cache(maxsize=None)
def batch_features(name, m, f):
    """Both parameter sets and an invalid one in one call (the invalid row must not disturb the others)."""
    sets = np.array([vector(name, NOMINAL[name]), vector(name, PERTURBED[name]), vector(name, NOMINAL[name])])
    sets[2, 0] = 1.0  # an unstable pole
    return simulator(name).steady_state(sets, [m], [f])


def batch(name, which, m, f):
    r = batch_features(name, m, f)
    i = {"nominal": 0, "perturbed": 1}[which]
    assert r.converged[i, 0]
    return r.H[i, 0], r.dc[i, 0]


# ---------------------------------------------------------------------------
# Steady state against scipy's Radau
# ---------------------------------------------------------------------------
RADAU_CASES = [("g1", "nominal", 2.0, 1.0, 5), ("g1", "perturbed", 0.6, 5.0, 6), ("g2", "nominal", 2.0, 1.0, 14)]


@pytest.mark.parametrize("name, which, m, f, periods", RADAU_CASES)
def test_steady_state_matches_radau(name, which, m, f, periods):
    poles, zeros, dc, fr = SETS[which][name]
    n = 4000  # samples per period
    T = 1 / f
    t = np.concatenate([[0.0], (periods - 2) * T + T * np.arange(2 * n + 1) / n])
    v = simulate_reference(poles, zeros, gain_from_dc(poles, zeros, dc), fr, m, f, t, rtol=1e-10, atol=1e-12)
    H_prev, dc_prev = period_features(t[1:n + 2], v[1:n + 2], f, m)
    H_ref, dc_ref = period_features(t[n + 1:], v[n + 1:], f, m)
    assert_close(H_prev, dc_prev, H_ref, dc_ref, m, tol=1e-8)  # the reference itself is in steady state
    H, dc_b = batch(name, which, m, f)
    assert_close(H, dc_b, H_ref, dc_ref, m)


# ---------------------------------------------------------------------------
# Steady state against the FMU in FMPy
# ---------------------------------------------------------------------------
FMU_CASES = [("g1", "nominal", 2.0, 0.5, 4), ("g1", "nominal", 0.6, 2.0, 4), ("g1", "perturbed", 2.0, 5.0, 20),
             ("g2", "nominal", 2.0, 3.0, 45), ("g2", "nominal", 0.6, 5.2, 90), ("g2", "perturbed", 2.0, 2.0, 40)]


@pytest.mark.parametrize("name, which, m, f, periods", FMU_CASES)
def test_steady_state_matches_fmu(built_fmu, name, which, m, f, periods):
    plant = load_plant(name)
    starts = dict(zip(plant.parameter_names(), vector(name, SETS[which][name]).tolist()))
    starts.update(excitation_amplitude=m, excitation_frequency=f)
    n = 1000  # samples per period
    res = simulate_fmu(str(built_fmu(name, 3)), fmi_type="CoSimulation", stop_time=periods / f,
                       output_interval=1 / (n * f), relative_tolerance=1e-12, start_values=starts,
                       output=["position"])
    t, pos = res["time"], res["position"]
    assert len(t) == periods * n + 1
    H_prev, dc_prev = position_features(t[-2 * n - 1:-n], pos[-2 * n - 1:-n], f, m)
    H_ref, dc_ref = position_features(t[-n - 1:], pos[-n - 1:], f, m)
    assert_close(H_prev, dc_prev, H_ref, dc_ref, m, tol=1e-8)  # the FMU run has reached steady state
    H, dc = batch(name, which, m, f)
    assert_close(H, dc, H_ref, dc_ref, m)


@pytest.mark.parametrize("name, m, f, periods", [("stribeck_servo", 0.6, 0.5, 10), ("lugre_servo", 2.0, 5.0, 20)])
def test_other_friction_models_match_fmu(built_fmu, name, m, f, periods):
    n = 1000
    res = simulate_fmu(str(built_fmu(name, 3)), fmi_type="CoSimulation", stop_time=periods / f,
                       output_interval=1 / (n * f), relative_tolerance=1e-12,
                       start_values={"excitation_amplitude": m, "excitation_frequency": f}, output=["position"])
    t, pos = res["time"], res["position"]
    H_prev, dc_prev = position_features(t[-2 * n - 1:-n], pos[-2 * n - 1:-n], f, m)
    H_ref, dc_ref = position_features(t[-n - 1:], pos[-n - 1:], f, m)
    assert_close(H_prev, dc_prev, H_ref, dc_ref, m, tol=1e-8)
    r = simulator(name).steady_state(load_plant(name).parameter_vector(), [m], [f])
    assert r.converged[0, 0]
    assert_close(r.H[0, 0], r.dc[0, 0], H_ref, dc_ref, m)


def test_failed_integration_gives_nan():
    r = simulator("g1").steady_state(load_plant("g1").parameter_vector(), [2.0], [1.0],
                                     SteadyStateOptions(max_steps=50))
    assert np.isnan(r.H[0, 0]) and np.isnan(r.dc[0, 0]) and not r.converged[0, 0]


def test_invalid_parameter_set_gives_nan_and_leaves_the_others_alone():
    r = batch_features("g1", 2.0, 0.5)
    assert np.isnan(r.H[2, 0]) and np.isnan(r.dc[2, 0]) and np.isnan(r.distortion[2, 0])
    assert not r.converged[2, 0]
    alone = simulator("g1").steady_state(vector("g1", NOMINAL["g1"]), [2.0], [0.5])
    assert alone.H[0, 0] == r.H[0, 0] and alone.dc[0, 0] == r.dc[0, 0]  # tasks are independent


# ---------------------------------------------------------------------------
# Options, threads, acceleration, distortion
# ---------------------------------------------------------------------------
def test_results_do_not_depend_on_threads_or_batching():
    plant = load_plant("g1")
    rng = np.random.default_rng(7)
    sets = plant.parameter_vector() * rng.uniform(0.8, 1.2, size=(6, len(plant.parameter_names())))
    amps, freqs = [2.0, 0.6, 2.0], [1.0, 1.0, 7.0]
    one = BatchSimulator(plant, threads=1).steady_state(sets, amps, freqs)
    calls = []
    two = BatchSimulator(plant, threads=2).steady_state(sets, amps, freqs, progress=lambda *a: calls.append(a))
    assert np.array_equal(one.H, two.H) and np.array_equal(one.dc, two.dc)
    assert calls[-1] == (6, 6) and [c[0] for c in calls] == sorted(c[0] for c in calls)
    single = BatchSimulator(plant, threads=1).steady_state(sets[3], amps[2:], freqs[2:])
    assert single.H[0, 0] == one.H[3, 2]
    # process pools and Dask ship a simulator by its __reduce__ (rebuilt from its plant); deepcopy goes the same way
    rebuilt = copy.deepcopy(BatchSimulator(plant, threads=1))
    assert rebuilt.steady_state(sets[3], amps[2:], freqs[2:]).H[0, 0] == one.H[3, 2]


@pytest.mark.parametrize("name, m, f", [("g1", 2.0, 10.0), ("g2", 2.0, 4.0)])
def test_acceleration_reaches_the_same_steady_state_sooner(name, m, f):
    plant = load_plant(name)
    sim = simulator(name)
    plain = sim.steady_state(plant.parameter_vector(), [m], [f], SteadyStateOptions(accelerate=False))
    fast = sim.steady_state(plant.parameter_vector(), [m], [f], SteadyStateOptions(accelerate=True))
    assert plain.converged.all() and fast.converged.all()
    assert_close(fast.H[0, 0], fast.dc[0, 0], plain.H[0, 0], plain.dc[0, 0], m, tol=1e-7)
    assert fast.settle_time[0, 0] < plain.settle_time[0, 0]


@pytest.mark.parametrize("distance", [1e-3, 1e-5])
def test_a_run_from_a_nearby_orbit_reaches_the_same_steady_state(distance):
    # g2 at 2 N, 4 Hz settles slowly from rest; a plant nearby starts where the nominal plant's run ended
    plant = load_plant("g2")
    sim = simulator("g2")
    amps, freqs = [2.0, 4.0], [4.0, 0.5]
    rng = np.random.default_rng(2)
    near = plant.parameter_vector() * (1 + distance * rng.uniform(-1, 1, len(plant.parameter_names())))
    nominal = sim.steady_state(plant.parameter_vector(), amps, freqs)
    cold = sim.steady_state(near, amps, freqs)
    for options in (SteadyStateOptions(), SteadyStateOptions(accelerate=False)):  # with and without Newton
        warm = sim.steady_state(near, amps, freqs, options, start=nominal.orbit)
        assert cold.converged.all() and warm.converged.all()
        for k, m in enumerate(amps):
            assert_close(warm.H[0, k], warm.dc[0, k], cold.H[0, k], cold.dc[0, k], m, tol=2e-7)
    loose = SteadyStateOptions(rtol=1e-5, tol=1e-6)  # the swarm's tolerance: a run from rest is mostly transient
    cold = sim.steady_state(near, amps, freqs, loose)
    warm = sim.steady_state(near, amps, freqs, loose, start=sim.steady_state(plant.parameter_vector(), amps, freqs,
                                                                              loose).orbit)
    assert warm.steps.sum() < cold.steps.sum() / 1.5


@pytest.mark.parametrize("name, m, f", [("g2", 2.0, 5.0), ("g2", 4.0, 0.5), ("g1", 2.0, 20.0)])
def test_variational_equations_match_finite_differences_of_the_period(name, m, f):
    """What Newton's method and the features' correction use — the derivatives of one period's end state (the
    monodromy matrix) and of its integrals (S1, DC) with respect to where it began, from the variational equations
    integrated beside the states — against the period differentiated numerically (starts moved by 1e-6 of their
    scale)."""
    plant = load_plant(name)
    sim = simulator(name)
    ns = sim.n_states
    p = plant.parameter_vector()
    settling = sim.steady_state(p, [m], [f], SteadyStateOptions(max_time=3.5 / f, accelerate=False))
    x0, scale = settling.orbit[0, 0, :ns], settling.orbit[0, 0, ns:2 * ns]

    def one_period(x, newton):
        start = np.full((1, 1, ns * (ns + 6)), np.nan)  # no derivatives given: a Newton run computes its own
        start[0, 0, :2 * ns] = np.concatenate([x, scale])
        options = SteadyStateOptions(rtol=1e-12, max_time=0.5 / f, accelerate=newton, give_up_early=False)
        r = sim.steady_state(p, [m], [f], options, start=start)
        return r.orbit[0, 0], np.array([(r.H[0, 0] * m).real, (r.H[0, 0] * m).imag, r.dc[0, 0]])

    orbit, _ = one_period(x0, True)
    flow = orbit[2 * ns:].reshape(ns + 4, ns)
    T = 1 / f
    exact = np.vstack([flow[:ns], 2 / T * flow[ns + 2], 2 / T * flow[ns + 1], flow[ns] / T])  # states, S1, DC
    base_x, base_s = one_period(x0, False)
    columns = []
    for j in range(ns):
        e = 1e-6 * scale[j]
        x, s_ = one_period(x0 + e * np.eye(ns)[j], False)
        columns.append(np.concatenate([x[:ns] - base_x[:ns], s_ - base_s]) / e)
    fd = np.column_stack(columns)
    # 1e-2: the variational equations hold the Jacobian fixed over each step
    assert np.max(np.abs(exact - fd)) < 1e-2 * max(np.max(np.abs(fd)), 1e-3)


def test_warm_starts_begin_each_experiment_on_the_nearest_converged_orbit():
    def features(orbit, converged):
        nan = np.full(converged.shape, np.nan)
        return SteadyStateFeatures(H=nan, dc=nan, distortion=nan, converged=converged, settle_time=nan,
                                   steps=np.arange(converged.size).reshape(converged.shape) + 10, orbit=orbit)

    warm = WarmStarts(capacity=3)
    assert warm.start(np.ones(2)) is None
    orbits = np.arange(2 * 2 * 3, dtype=float).reshape(2, 2, 3)  # 2 sets x 2 experiments x 3 numbers
    warm.add([[1.0, 0.0], [2.0, 0.0]], features(orbits, np.array([[True, False], [True, True]])))
    start, steps = warm.nearest([[1.1, 0.0], [np.nan, 0.0]])
    np.testing.assert_array_equal(start[0, 0], orbits[0, 0])  # the nearest set, [1, 0]
    np.testing.assert_array_equal(start[0, 1], orbits[1, 1])  # [1, 0] did not converge there: the next nearest
    np.testing.assert_array_equal(steps[0], [10, 13])  # the steps of the runs begun there
    assert np.isnan(start[1]).all() and np.isnan(steps[1]).all()  # a NaN set is near nothing: from rest
    warm.add([[5.0, 1.0], [6.0, 1.0]], features(orbits + 100, np.ones((2, 2), bool)))  # [1, 0] is forgotten
    np.testing.assert_array_equal(warm.start([[1.0, 0.0]])[0, 0], orbits[1, 0])


def test_the_steps_expected_at_a_tighter_tolerance_grow_as_the_integrators_order_says():
    # RODAS4's error is of order 4 in the step: a run at rtol 1e-5 takes (1e-5/1e-10)^(1/4) ≈ 17.8 times fewer
    # steps than one at 1e-10 (the polish's budget is a multiple of the run it begins on)
    nan = np.full((1, 2), np.nan)
    warm = WarmStarts()
    warm.add([[1.0, 0.0]], SteadyStateFeatures(H=nan, dc=nan, distortion=nan, converged=np.ones((1, 2), bool),
                                               settle_time=nan, steps=np.array([[100, 400]]),
                                               orbit=np.zeros((1, 2, 3))), rtol=1e-5)
    np.testing.assert_allclose(warm.nearest([[1.0, 0.0]], 1e-10)[1], [[100 * 10 ** 1.25, 400 * 10 ** 1.25]])
    np.testing.assert_array_equal(warm.nearest([[1.0, 0.0]], 1e-3)[1], [[100, 400]])  # never fewer
    np.testing.assert_array_equal(warm.nearest([[1.0, 0.0]])[1], [[100, 400]])  # no tolerance: as taken


def test_a_polish_run_far_stiffer_than_the_run_it_begins_on_is_cut_at_its_step_budget():
    # lugre_servo with a rest stiffness 1e5 times its own settles from rest in ~2.4e5 steps per experiment; begun
    # on the orbit of its own plant (~6000 steps), a polish's run may take 20 times that: it counts as without
    # steady state (the polish steps back) instead of paying for a region no short step would reach
    plant = load_plant("lugre_servo")
    sim = simulator("lugre_servo")
    amps, freqs = np.array([0.5, 0.5, 2.0, 2.0]), np.array([0.5, 5.0, 0.5, 5.0])
    nominal = plant.parameter_vector()
    truth = sim.steady_state(nominal, amps, freqs)
    data = SineData(amplitudes=amps, frequencies=freqs, H=truth.H[0], dc=truth.dc[0], noisy=False, source="test",
                    skipped=0, noise=np.zeros(4))
    mask = identified_mask(plant)
    stiff = nominal.copy()
    stiff[list(sim.parameter_names).index("sigma0")] *= 1e5
    assert np.all(np.isfinite(SineCriterion(plant, data, sim).residuals(stiff[mask], POLISH_RTOL)))  # from rest
    warm = SineCriterion(plant, data, sim)
    assert np.allclose(warm.residuals(nominal[mask], POLISH_RTOL), 0, atol=1e-7)
    _, steps = warm.warm_starts.nearest(stiff)
    assert np.nanmax(steps) * STEP_BUDGET_FACTOR < 2e5
    assert np.all(np.isnan(warm.residuals(stiff[mask], POLISH_RTOL)))
    assert np.all(np.isfinite(warm.residuals(stiff[mask], SEARCH_RTOL * 10)))  # a search's run has no budget


def test_whole_sets_end_a_sets_other_experiments_once_one_fails():
    # g2 at 0.6 N, 1 Hz never settles (below); at 2 N it does.  With whole_sets the experiment after the failed one
    # is not run (one thread: the set's experiments in order); the criterion, which needs both, runs the one that
    # failed before first next time
    plant = load_plant("g2")
    sim = BatchSimulator(plant, threads=1)
    amps, freqs = [0.6, 2.0], [1.0, 1.0]
    every = sim.steady_state(plant.parameter_vector(), amps, freqs)
    whole = sim.steady_state(plant.parameter_vector(), amps, freqs, SteadyStateOptions(whole_sets=True))
    assert list(every.converged[0]) == [False, True] and not whole.converged[0].any()
    assert whole.steps[0, 1] == 0 and np.isnan(whole.settle_time[0, 1]) and whole.steps[0, 0] == every.steps[0, 0]
    assert list(whole.failed()[0]) == [True, False]  # the run not made is no failure
    backwards = sim.steady_state(plant.parameter_vector(), amps[::-1], freqs, SteadyStateOptions(whole_sets=True))
    assert backwards.converged[0, 0] and backwards.experiments([1, 0]).failed()[0].tolist() == [True, False]
    data = SineData(amplitudes=np.array(amps[::-1]), frequencies=np.array(freqs), H=every.H[0, ::-1],
                    dc=every.dc[0, ::-1], noisy=False, source="test", skipped=0, noise=np.zeros(2))
    crit = SineCriterion(plant, data, sim)
    assert np.isnan(crit.residuals(plant.parameter_vector()[identified_mask(plant)], SEARCH_RTOL)).all()
    assert crit.failures.tolist() == [0, 1]


def test_hopeless_experiment_is_given_up_early_with_the_same_verdict():
    # g2 at 0.6 N, 1 Hz: the friction's relay oscillation near 5 Hz does not lock to the excitation
    plant = load_plant("g2")
    sim = simulator("g2")
    full = sim.steady_state(plant.parameter_vector(), [0.6], [1.0], SteadyStateOptions(give_up_early=False))
    early = sim.steady_state(plant.parameter_vector(), [0.6], [1.0])
    assert not full.converged[0, 0] and not early.converged[0, 0]
    assert full.settle_time[0, 0] >= 60.0 and early.settle_time[0, 0] < 30.0


# Two g2-like plants from the prior (full precision): under 2 N at 5 Hz a plain run never settles (the friction's
# relay oscillation beats with the excitation), yet the period map has a periodic orbit that extrapolation can reach.
NOT_ATTRACTING = [[-1.844723726427092, 21.711499862421043, -9.005377762769967, 1.2352925927577314,
                   0.4619676721033513, 0.4519204552217606],
                  [-1.6723177362972232, 21.189038181984564, -13.987340601136477, 1.3588868522873856,
                   0.6659456888702873, 0.3546893031306171]]


def test_no_steady_state_where_a_plain_run_never_settles():
    plant = load_plant("g2")
    sim = simulator("g2")
    sets = full_vectors(plant, np.array(NOT_ATTRACTING))
    plain = sim.steady_state(sets, [2.0], [5.0], SteadyStateOptions(accelerate=False, give_up_early=False,
                                                                       max_time=300.0))
    fast = sim.steady_state(sets, [2.0], [5.0])
    assert not plain.converged.any() and plain.settle_time.min() >= 300.0
    assert not fast.converged.any()


def test_loose_tolerance_converges_at_the_integrators_scatter():
    # g2 near its relay oscillation (5 Hz) at rtol 1e-5: steady periods differ by about 2e-5 from one to the next
    # (the step sequence alternates); every slightly perturbed plant still reaches its steady state
    plant = load_plant("g2")
    rng = np.random.default_rng(1)
    sets = plant.parameter_vector() * (1 + 1e-5 * rng.standard_normal((8, len(plant.parameter_names()))))
    loose = simulator("g2").steady_state(sets, [4.0, 2.0], [5.0, 5.0], SteadyStateOptions(rtol=1e-5, tol=1e-6))
    tight = simulator("g2").steady_state(sets, [4.0, 2.0], [5.0, 5.0])
    assert loose.converged.all() and tight.converged.all()
    for i in range(8):  # a tolerance for ranking candidates (the swarm's), not for the final fit
        for k, m in enumerate([4.0, 2.0]):
            assert_close(loose.H[i, k], loose.dc[i, k], tight.H[i, k], tight.dc[i, k], m, tol=1e-3)


def test_looser_tolerance_is_less_accurate_but_close():
    plant = load_plant("g1")
    sim = simulator("g1")
    fine = sim.steady_state(plant.parameter_vector(), [0.6], [2.0], SteadyStateOptions(rtol=1e-11))
    coarse = sim.steady_state(plant.parameter_vector(), [0.6], [2.0], SteadyStateOptions(rtol=1e-6))
    err = abs(coarse.H[0, 0] - fine.H[0, 0]) / abs(fine.H[0, 0])
    assert 1e-9 < err < 1e-4
    assert coarse.steps[0, 0] < fine.steps[0, 0] / 4


def test_distortion_matches_the_harmonics_of_the_reference():
    poles, zeros, dc, fr = NOMINAL["g1"]
    m, f, n = 0.6, 1.0, 4096
    t = np.concatenate([[0.0], 4 + np.arange(n + 1) / (n * f)])
    v = simulate_reference(poles, zeros, gain_from_dc(poles, zeros, dc), fr, m, f, t, rtol=1e-10, atol=1e-12)
    spectrum = np.fft.rfft(v[1:-1]) * 2 / n  # |S_k| of the last period
    ref = np.sqrt(np.sum(np.abs(spectrum[2:n // 2]) ** 2)) / np.abs(spectrum[1])
    r = simulator("g1").steady_state(load_plant("g1").parameter_vector(), [m], [f])
    assert ref > 0.05  # stick-slip: a clearly distorted response
    assert abs(r.distortion[0, 0] - ref) < 1e-5 * ref


# ---------------------------------------------------------------------------
# Validity of parameter sets
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["g1", "g2", "stribeck_servo", "lugre_servo"])
def test_valid_parameter_sets_follow_the_plant_file_rules(name):
    import tomllib

    plant = load_plant(name)
    rng = np.random.default_rng(3)
    nominal = plant.parameter_vector()
    sets = nominal * rng.uniform(-0.3, 1.7, size=(300, nominal.size))
    sets[rng.random(sets.shape) < 0.05] = 0.0
    sets[0, 0], sets[1, -1] = np.nan, np.inf
    expected = []
    for row in sets:
        try:
            plant_from_dict(tomllib.loads(plant.with_parameters(row).to_toml()))
            expected.append(True)
        except PlantError:
            expected.append(False)
    assert np.array_equal(valid_parameter_sets(plant, sets), expected)
    assert 0 < sum(expected) < len(expected)


# ---------------------------------------------------------------------------
# Records
# ---------------------------------------------------------------------------
def reference_record(params, t, u, hold):
    """v and position at t for u held (zoh), linear (foh) between samples, or a function of time: scipy's Radau
    on the equations, written without the package, restarted at every sample like a drive's command steps."""
    poles, zeros, dc, fr = params
    A, B, C, _ = signal.zpk2ss(zeros, poles, gain_from_dc(poles, zeros, dc))
    n = A.shape[0]
    x, v, pos = np.zeros(n + 1), [0.0], [0.0]
    for i in range(t.size - 1):
        if callable(u):
            force_in = u
        elif hold == "zoh":
            force_in = (lambda tt, ui=u[i]: ui)
        else:
            force_in = (lambda tt, i=i: u[i] + (u[i + 1] - u[i]) * (tt - t[i]) / (t[i + 1] - t[i]))

        def rhs(tt, z):
            vel = float(C[0] @ z[:n])
            force, _ = friction(vel, 0.0, fr)
            return np.concatenate([A @ z[:n] + B[:, 0] * (force_in(tt) - force), [vel]])

        sol = solve_ivp(rhs, (t[i], t[i + 1]), x, method="Radau", rtol=1e-11, atol=1e-13)
        assert sol.success
        x = sol.y[:, -1]
        v.append(float(C[0] @ x[:n]))
        pos.append(x[n])
    return np.array(v), np.array(pos)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize("name", ["g1", "g2"])
def test_record_matches_radau(name, hold):
    rng = np.random.default_rng(11)
    t = 0.5 + np.cumsum(rng.uniform(0.01, 0.03, 60))  # irregular sampling, starting away from zero
    u = 1.5 * np.sin(2 * np.pi * 1.3 * (t - t[0])) + 0.4 * rng.standard_normal(t.size)
    sets = np.array([vector(name, NOMINAL[name]), vector(name, PERTURBED[name])])
    response = simulator(name).simulate_record(sets, t, u, hold=hold, rtol=1e-10)
    for row, which in enumerate(("nominal", "perturbed")):
        v, pos = reference_record(SETS[which][name], t, u, hold)
        assert np.abs(v).max() > 0.1
        assert np.abs(response.v[row] - v).max() < 1e-8 * np.abs(v).max()
        assert np.abs(response.position[row] - pos).max() < 1e-8 * np.abs(pos).max()


def test_zoh_and_foh_differ_as_the_hold_does():
    """The same samples held or interpolated are different inputs: their responses differ by about the hold's
    half-sample delay (a check that the hold is honoured, not an accuracy test)."""
    t = np.linspace(0.0, 2.0, 41)
    u = 2.0 * np.sin(2 * np.pi * t)
    sets = vector("g1", NOMINAL["g1"])[None]
    zoh = simulator("g1").simulate_record(sets, t, u, hold="zoh").v[0]
    foh = simulator("g1").simulate_record(sets, t, u, hold="foh").v[0]
    assert np.abs(zoh - foh).max() > 0.02 * np.abs(foh).max()


def test_sine_series_matches_radau():
    t = np.linspace(0.0, 1.5, 151)
    sets = vector("g2", PERTURBED["g2"])[None]
    response = simulator("g2").simulate_sine(sets, t, 2.0, 1.7, rtol=1e-10)
    v, pos = reference_record(SETS["perturbed"]["g2"], t, lambda tt: 2.0 * np.sin(2 * np.pi * 1.7 * tt), None)
    assert np.abs(response.v[0] - v).max() < 1e-8 * np.abs(v).max()
    assert np.abs(response.position[0] - pos).max() < 1e-8 * np.abs(pos).max()


def test_record_of_an_invalid_set_is_nan():
    t = np.linspace(0, 1, 11)
    sets = np.array([vector("g1", NOMINAL["g1"]), vector("g1", NOMINAL["g1"])])
    sets[1, 2] = -0.5  # negative Coulomb friction
    v = simulator("g1").simulate_record(sets, t, np.ones_like(t)).v
    assert np.all(np.isfinite(v[0])) and np.all(np.isnan(v[1]))


# ---------------------------------------------------------------------------
# User errors
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("call", [
    lambda s: s.steady_state(np.ones(3), [1.0], [1.0]),                      # wrong number of parameters
    lambda s: s.steady_state(load_plant("g1").parameter_vector(), [1.0, 2.0], [1.0]),
    lambda s: s.steady_state(load_plant("g1").parameter_vector(), [0.0], [1.0]),
    lambda s: s.steady_state(load_plant("g1").parameter_vector(), [1.0], [-1.0]),
    lambda s: s.simulate_record(load_plant("g1").parameter_vector(), [0.0, 1.0, 1.0], [0.0, 1.0, 2.0]),
    lambda s: s.simulate_record(load_plant("g1").parameter_vector(), [0.0, 1.0], [0.0, np.nan]),
    lambda s: s.simulate_record(load_plant("g1").parameter_vector(), [0.0, 1.0], [0.0, 1.0], hold="linear"),
    lambda s: SteadyStateOptions(rtol=0.5),
    lambda s: SteadyStateOptions(min_periods=0),
    lambda s: s.steady_state(load_plant("g1").parameter_vector(), [1.0], [1.0], start=np.zeros((1, 1, 2))),
])
def test_bad_inputs_raise_user_errors(call):
    with pytest.raises(UserError):
        call(simulator("g1"))


def test_the_library_is_built_once_by_concurrent_processes_then_loaded_without_generating_code(tmp_path):
    code = ("import sys; from servofmu.model.plant import load_plant; "
            "from servofmu.simulation.batch import BatchSimulator; BatchSimulator(load_plant('g1')); "
            "print('casadi' in sys.modules)")
    env = {**os.environ, "SERVOFMU_CACHE": str(tmp_path)}
    builders = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, text=True)
                for _ in range(3)]
    assert [b.wait() for b in builders] == [0, 0, 0]
    for b in builders:
        b.stdout.close()
    assert [p.suffix for p in tmp_path.iterdir()] == [".so"]  # one library, no partial files left
    loaded = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert loaded.stdout.strip() == "False"  # CasADi, which generates the code, is not even imported


def cache_key(plant, extra=None) -> str:
    """The cache key of the batch simulator's library for ``plant`` (with ``extra`` generated files)."""
    return library_key(plant, DRIVER, extra or {})


def test_the_cache_key_follows_what_determines_the_library():
    """The structure and the two constants the code holds (the state scale, LuGre's bristle nominal: powers of
    two), not the values: the parameters are the library's arguments."""
    g1 = load_plant("g1")
    near = g1.with_parameters(g1.parameter_vector() * 1.1)  # poles 10 % faster: the same power of two
    far = g1.with_parameters(g1.parameter_vector() * 2.0)  # twice as fast: the states scaled otherwise
    assert state_scale(near) == state_scale(g1) != state_scale(far)
    assert cache_key(g1) == cache_key(load_plant("g1")) == cache_key(near)
    keys = {cache_key(g1), cache_key(far), cache_key(load_plant("g2")), cache_key(g1, {"extra.h": "#define X 1\n"})}
    assert len(keys) == 4
    lugre = load_plant("lugre_servo")
    stiffer = lugre.with_parameters([v * 4 if n == "sigma0" else v for n, v in lugre.parameters().items()])
    assert bristle_nominal(stiffer.friction) == bristle_nominal(lugre.friction) / 4
    assert cache_key(stiffer) != cache_key(lugre)


def test_plants_sharing_a_library_simulate_as_with_a_library_of_their_own(tmp_path, monkeypatch):
    """A library built for one plant, run with another plant's values of the same key, gives bit for bit what a
    library built for that other plant gives (in a cache of its own)."""
    g2 = load_plant("g2")
    other = g2.with_parameters(g2.parameter_vector() * 1.05)
    assert cache_key(other) == cache_key(g2)
    t = np.arange(0, 2, 0.01)
    u = np.sin(2 * np.pi * t)
    shared = BatchSimulator(g2, threads=1).simulate_record(other.parameter_vector()[None], t, u, rtol=1e-9)
    monkeypatch.setenv("SERVOFMU_CACHE", str(tmp_path))
    own = BatchSimulator(other, threads=1).simulate_record(other.parameter_vector()[None], t, u, rtol=1e-9)
    assert [p.suffix for p in tmp_path.iterdir()] == [".so"]  # built anew there, from the other plant
    assert np.array_equal(shared.v, own.v) and np.array_equal(shared.position, own.position)


def test_a_library_built_for_this_processor_gives_the_portable_results_bit_for_bit(monkeypatch):
    from servofmu.simulation import compiled

    if compiled.driver_cflags() == compiled.EXTRA_CFLAGS:
        pytest.skip("no build for the processor on this machine")
    plant = load_plant("g2")
    rng = np.random.default_rng(3)
    sets = plant.parameter_vector() * rng.uniform(0.8, 1.2, size=(4, len(plant.parameter_names())))
    amps, freqs = [2.0, 0.6, 2.0], [1.0, 4.0, 5.0]
    native = BatchSimulator(plant, threads=1).steady_state(sets, amps, freqs)
    key_here = cache_key(plant)
    monkeypatch.setattr(compiled, "_processor", lambda: "another processor")
    assert cache_key(plant) != key_here  # a shared cache never mixes processors
    monkeypatch.setattr(compiled, "driver_cflags", lambda: compiled.EXTRA_CFLAGS)
    monkeypatch.setattr(BatchSimulator, "_load", staticmethod(lambda p: compiled.compiled_driver(p, DRIVER)))
    assert cache_key(plant) != key_here
    portable = BatchSimulator(plant, threads=1).steady_state(sets, amps, freqs)
    for name in ("H", "dc", "distortion", "converged", "settle_time", "steps", "orbit"):
        assert np.array_equal(getattr(native, name), getattr(portable, name), equal_nan=True), name


def test_a_polish_that_starts_without_steady_state_takes_no_derivatives():
    # every run of g2 at 0.6 N, 1 Hz has no steady state: the polish returns its start and a NaN Jacobian after
    # one evaluation, instead of p more runs to the time limit for a Jacobian of NaN residuals
    from servofmu.identification.polish import polish

    plant = load_plant("g2")
    sim = BatchSimulator(plant, threads=1)
    data = SineData(amplitudes=np.array([0.6]), frequencies=np.array([1.0]), H=np.array([1.0 + 0j]),
                    dc=np.zeros(1), noisy=False, source="test", skipped=0, noise=np.zeros(1))
    crit = SineCriterion(plant, data, sim)
    y0 = plant.parameter_vector()[identified_mask(plant)]
    y, jac = polish(crit, lambda rows: rows, y0)
    assert crit.evaluations == 1 and np.array_equal(y, y0) and np.isnan(jac).all()
