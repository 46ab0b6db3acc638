"""Restarts of the search: the floor test, the agreement of two fits, and a fit found again when the first search
missed (servofmu.identification.restarts)."""
import numpy as np
import pytest

from servofmu.errors import ServofmuWarning
from servofmu.identification.criterion import POLISH_RTOL, SineData
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import full_vectors, identified_mask
from servofmu.identification.pso import PsoOptions
from servofmu.identification.restarts import (FloorTest, RestartOptions, chi2_quantile, fits_agree, floor_test,
                                               noise_half_widths)
from servofmu.identification.results import restarts_line, result_from_estimator, table_text
from servofmu.measurement.frf import harmonics
from servofmu.model.plant import load_plant
from servofmu.simulation.batch import BatchSimulator
from servofmu.identification.criterion import steady_state_options

AMPS = np.array([2.0, 2.0, 2.0, 0.6, 0.6, 0.6])
FREQS = np.array([0.5, 2.0, 10.0, 0.5, 2.0, 10.0])


@pytest.mark.parametrize("dof", [3, 10, 30, 100, 1000])
def test_chi2_quantile_matches_scipy(dof):
    from scipy.stats import chi2

    for level in (0.95, 0.99, 0.999):
        assert chi2_quantile(level, dof) == pytest.approx(chi2.ppf(level, dof), rel=0.02 if dof < 10 else 0.01)


def test_the_noise_a_window_puts_on_the_first_harmonic():
    """sine_data's noise model: white noise σ on N samples of whole periods gives Re and Im of the phasor a
    standard deviation σ·√(2/N) and the mean σ/√N (checked by simulation of many windows)."""
    rng = np.random.default_rng(1)
    n, sigma, f = 200, 0.1, 2.0
    t = np.arange(n + 1) / (n * f / 4)  # 4 periods, N samples and the closing one
    s1, dc = [], []
    for _ in range(4000):
        h = harmonics(t, np.sin(2 * np.pi * f * t) + sigma * rng.standard_normal(t.size), f, n_harmonics=1)
        s1.append(h.first)
        dc.append(h.dc)
    assert np.std(np.real(s1)) == pytest.approx(sigma * np.sqrt(2 / n), rel=0.05)
    assert np.std(np.imag(s1)) == pytest.approx(sigma * np.sqrt(2 / n), rel=0.05)
    assert np.std(dc) == pytest.approx(sigma / np.sqrt(n), rel=0.05)


def _data(plant, theta, noise=None, rng=None):
    sim = BatchSimulator(plant)
    feats = sim.steady_state(full_vectors(plant, theta[None]), AMPS, FREQS, steady_state_options(POLISH_RTOL))
    H, dc = feats.H[0], feats.dc[0]
    if noise is not None:  # relative noise of the given std on Re, Im and the weighted mean
        H = H + noise * np.abs(H) * (rng.standard_normal(H.size) + 1j * rng.standard_normal(H.size))
        dc = dc + noise * np.abs(H) * AMPS / np.sqrt(2) * rng.standard_normal(H.size)
    return SineData(amplitudes=AMPS, frequencies=FREQS, H=H, dc=dc, noisy=noise is not None, source="test", skipped=0,
                    noise=None if noise is None else np.full(AMPS.size, noise))


def test_floor_test_passes_the_truth_and_fails_a_wrong_plant():
    plant = load_plant("g1")
    truth = plant.parameter_vector()[identified_mask(plant)]
    rng = np.random.default_rng(3)
    data = _data(plant, truth, noise=0.01, rng=rng)
    crit_r = PSOANNIdentifier(plant)._criterion(data).residuals
    opts = RestartOptions()
    at_truth = floor_test(data, crit_r(truth[None], POLISH_RTOL)[0], truth.size, opts)
    off = floor_test(data, crit_r((truth * [1.05, 1, 1, 1])[None], POLISH_RTOL)[0], truth.size, opts)
    assert at_truth.at_floor and 0.5 < at_truth.ratio < 2
    assert not off.at_floor and off.ratio > 2


def test_agreement_within_intervals_or_the_relative_tolerance():
    theta = np.array([1.0, 2.0])
    narrow = np.zeros(2)
    assert fits_agree(theta, narrow, theta * (1 + 1e-7), narrow, 1e-6)
    assert not fits_agree(theta, narrow, theta * (1 + 1e-4), narrow, 1e-6)
    intervals = np.array([[0.9, 1.1], [1.9, 2.1]])
    assert fits_agree(theta, noise_half_widths(intervals, None), theta + 0.05, narrow, 1e-6)
    # a fit 100 times above the noise floor: its intervals are its misfit's, and shrink to the noise's
    misfit = FloorTest(statistic=1e4 * 30, limit=60.0, ratio=100.0)
    assert np.allclose(noise_half_widths(intervals, misfit), 0.001)
    assert not fits_agree(theta, noise_half_widths(intervals, misfit), theta + 0.05, narrow, 1e-6)


def test_a_search_that_missed_is_restarted_until_it_finds_the_plant():
    """The truth lies outside the first box (prior of spread 0.3: gain and friction 2 to 2.6 times g1's): the first
    search and its polish end in another minimum, 77 % off and far above the floor, and a widened box finds it."""
    plant = load_plant("g1")
    truth = plant.parameter_vector()[identified_mask(plant)] * np.array([0.88, 2.58, 2.22, 1.99])
    data = _data(plant, truth)
    options = dict(method="pso", spread=0.3, pso=PsoOptions(iterations=5), threads=1)
    never = PSOANNIdentifier(plant, restarts=RestartOptions(restarts=0), **options).fit(data)
    assert never.restarts_ == 0 and not never.floor_.at_floor
    assert np.max(np.abs(never.theta_ / truth - 1)) > 0.1
    with pytest.warns(ServofmuWarning, match="stayed above the noise floor after 1 restarts"):
        PSOANNIdentifier(plant, restarts=RestartOptions(restarts=1), **options).fit(data)  # the budget spent
    est = PSOANNIdentifier(plant, **options).fit(data)
    assert est.restarts_ >= 1 and est.floor_.at_floor
    assert np.max(np.abs(est.theta_ / truth - 1)) < 1e-6
    assert [s.name for s in est.stages_][2:] == [f"restart {k}" for k in range(1, est.restarts_ + 1)]
    result = result_from_estimator(est, "pso", {})
    assert result.provenance["restarts"] == est.restarts_
    assert f"swarm restarts: {est.restarts_}" in table_text(result)
    assert restarts_line({}) is None  # an older file's result: no line


def test_a_fit_at_the_floor_is_not_restarted_and_is_unchanged():
    plant = load_plant("g1")
    truth = plant.parameter_vector()[identified_mask(plant)] * np.array([1.1, 0.9, 1.05, 0.95])
    data = _data(plant, truth)
    options = dict(method="pso", pso=PsoOptions(iterations=5), threads=1)
    est = PSOANNIdentifier(plant, **options).fit(data)
    never = PSOANNIdentifier(plant, restarts=RestartOptions(restarts=0), **options).fit(data)
    assert est.restarts_ == 0 and est.floor_.at_floor
    assert np.array_equal(est.theta_, never.theta_) and np.array_equal(est.intervals_, never.intervals_)
