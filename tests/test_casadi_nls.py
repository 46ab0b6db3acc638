"""The CasADi least-squares baseline (servofmu.baselines.casadi_nls) against the FMU and the batch simulator.

Its periodic steady state (CVODES + Newton on the period map) and the measurement (the FMU's RODAS4, run from
rest until settled) are independent computations of the same responses; its residuals must equal those of
servofmu.identification.criterion.SineCriterion (batch simulator) at any parameters, and its Jacobian central
differences."""
from __future__ import annotations

import time

import numpy as np
import pytest

from servofmu.baselines.casadi_nls import CasadiCriterion, NlsOptions, fit_casadi_nls
from servofmu.errors import UserError
from servofmu.identification.criterion import RecordData, SineCriterion, SineData, sine_data
from servofmu.identification.prior import identified_mask
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.measure import measure
from servofmu.model.plant import load_plant
from servofmu.simulation.batch import BatchSimulator
from servofmu.runtime import RunOptions

G1 = load_plant("g1")
TRUTH = G1.parameter_vector()[identified_mask(G1)]  # pole1, dc_gain, fc_pos, fc_neg


@pytest.fixture(scope="module")
def g1_data(built_fmu, tmp_path_factory) -> SineData:
    """g1 measured from its FMU at the paper's magnitudes 2.0 and 0.6 N, default frequencies, no noise."""
    path = tmp_path_factory.mktemp("nls") / "g1.h5"
    measure(built_fmu("g1"), path, amplitudes=(2.0, 0.6), run=RunOptions(workers=0))
    return sine_data(read_data_file(path))


def start_near_truth(seed: int) -> np.ndarray:
    return TRUTH * (1 + 0.05 * np.random.default_rng(seed).choice([-1.0, 1.0], TRUTH.size))


def test_residuals_equal_sine_criterion_and_vanish_at_the_truth(g1_data):
    crit = CasadiCriterion(G1, g1_data, NlsOptions(rtol=1e-10))
    batch = SineCriterion(G1, g1_data, BatchSimulator(G1, threads=1))
    at_truth = crit.residuals(TRUTH)
    assert np.max(np.abs(at_truth)) < 1e-7  # CVODES periodic orbit vs the FMU's settled response
    for theta in (TRUTH, start_near_truth(0), TRUTH * [1.2, 0.8, 0.7, 1.3]):
        r = crit.residuals(theta)
        assert r.shape == (3 * g1_data.amplitudes.size,)
        assert np.max(np.abs(r - batch.residuals(theta, 1e-10)[0])) < 1e-7


def test_a_symmetric_structure_ties_fc_neg_to_fc_pos_in_both_implementations(g1_data):
    """g1 fitted as symmetric (one level): the CasADi model and the batch simulator see the same plant at any
    (pole1, dc_gain, fc_pos) — fc_neg follows fc_pos, not the structure's value."""
    from dataclasses import replace

    symmetric = replace(G1, friction=replace(G1.friction, symmetric=True, fc_neg=G1.friction.fc_pos))
    crit = CasadiCriterion(symmetric, g1_data, NlsOptions(rtol=1e-10))
    batch = SineCriterion(symmetric, g1_data, BatchSimulator(symmetric, threads=1))
    assert crit.steady.names == ["pole1", "dc_gain", "fc_pos"]
    for theta in ([-10.0, 1.0, 0.3], [-9.0, 1.1, 0.6]):
        r = crit.residuals(np.array(theta))
        assert np.max(np.abs(r - batch.residuals(np.array(theta), 1e-10)[0])) < 1e-7
        assert np.max(np.abs(r - CasadiCriterion(G1, g1_data, NlsOptions(rtol=1e-10)).residuals(
            np.array(theta + [theta[2]])))) < 1e-7  # the asymmetric structure at fc_neg = fc_pos


def test_jacobian_matches_central_differences(g1_data):
    crit = CasadiCriterion(G1, g1_data, NlsOptions(rtol=1e-12))
    theta = start_near_truth(1)
    r, J = crit.residuals_and_jacobian(theta)
    assert np.max(np.abs(r - crit.residuals(theta))) < 1e-9  # the same residuals (integrated with more states)
    for i in range(theta.size):
        h = 1e-4 * abs(theta[i])
        step = np.eye(theta.size)[i] * h
        column = (crit.residuals(theta + step) - crit.residuals(theta - step)) / (2 * h)
        assert np.max(np.abs(J[:, i] - column)) < 1e-5 * np.max(np.abs(J[:, i])), i


@pytest.mark.parametrize("method", ["gauss-newton", "ipopt"])
def test_converges_to_the_truth_from_five_percent_off(g1_data, method):
    theta0 = start_near_truth(2)
    t0 = time.perf_counter()
    result = fit_casadi_nls(G1, g1_data, theta0, NlsOptions(method=method))
    err = np.abs(result.theta - TRUTH) / np.abs(TRUTH)
    print(f"\ng1 {method}: max relative error {err.max():.2e}, fitness {result.fitness:.2e}, "
          f"{result.iterations} iterations, {result.evaluations} evaluations, {time.perf_counter() - t0:.1f} s "
          f"({result.message})")
    assert result.success, result.message
    assert err.max() < 1e-6
    assert result.fitness < 1e-7 and result.names == ("pole1", "dc_gain", "fc_pos", "fc_neg")


# long (SERVOFMU_FAULTS=all): 15-25 s; the first-order cases above check the same path
@pytest.mark.long
def test_g2_with_its_complex_pair_from_five_percent_off(built_fmu, tmp_path):
    """Third order, a lightly damped pair near 5 Hz; magnitudes and frequencies where g2 settles (no limit cycle)."""
    path = tmp_path / "g2.h5"
    measure(built_fmu("g2"), path, amplitudes=(4.0, 2.0), frequencies=(0.5, 1.0, 2.0, 5.0), run=RunOptions(workers=0))
    g2 = load_plant("g2")
    truth = g2.parameter_vector()[identified_mask(g2)]
    theta0 = truth * (1 + 0.05 * np.random.default_rng(3).choice([-1.0, 1.0], truth.size))
    result = fit_casadi_nls(g2, sine_data(read_data_file(path)), theta0)
    err = np.abs(result.theta - truth) / np.abs(truth)
    print(f"\ng2 {result.method}: max relative error {err.max():.2e}, {result.iterations} iterations, "
          f"{result.seconds:.1f} s")
    assert result.success and err.max() < 1e-6


def test_default_start_is_the_structure_file(g1_data):
    """From theta0=None the fit starts at the structure's values: here a structure 5 % off g1 on g1's data, so the
    fit must move to the truth, exactly as it does when given those values as theta0 (the same run: the same
    iterations and result).  Starting at the truth on the truth's data would pass whatever the default start."""
    off = start_near_truth(4)
    vector = G1.parameter_vector()
    vector[identified_mask(G1)] = off
    structure = G1.with_parameters(vector)
    result = fit_casadi_nls(structure, g1_data)
    assert result.success and np.max(np.abs(result.theta - TRUTH) / TRUTH) < 1e-6
    explicit = fit_casadi_nls(structure, g1_data, off)
    assert (result.iterations, result.evaluations) == (explicit.iterations, explicit.evaluations)
    np.testing.assert_array_equal(result.theta, explicit.theta)


# ---------------------------------------------------------------------------
# Inputs a user can get wrong
# ---------------------------------------------------------------------------
def test_bad_inputs_are_user_errors(g1_data):
    with pytest.raises(UserError, match="has 3 values; g1 identifies 4 .pole1, dc_gain, fc_pos, fc_neg."):
        fit_casadi_nls(G1, g1_data, TRUTH[:3])
    with pytest.raises(UserError, match="not a valid plant"):
        fit_casadi_nls(G1, g1_data, TRUTH * [-1, 1, 1, 1])  # a pole at +10
    with pytest.raises(UserError, match="not a valid plant"):
        fit_casadi_nls(G1, g1_data, [np.nan, 1, 0.5, 0.4])
    t = np.linspace(0, 1, 11)
    with pytest.raises(UserError, match="stepped-sine"):
        fit_casadi_nls(G1, RecordData(records=((t, np.sin(t), np.cos(t)),), source="rec.h5"))
    one = SineData(amplitudes=np.array([2.0]), frequencies=np.array([1.0]), H=g1_data.H[:1], dc=g1_data.dc[:1],
                   noisy=False, source="one.h5", skipped=0)
    with pytest.raises(UserError, match="one.h5: 1 experiments give fewer residuals than the 4 parameters"):
        fit_casadi_nls(G1, one)
    with pytest.raises(UserError, match="unknown least-squares method 'newton'"):
        NlsOptions(method="newton")
    with pytest.raises(UserError, match="rtol"):
        NlsOptions(rtol=0.1)
