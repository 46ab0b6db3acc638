"""The frequency-domain fit of G(s) to the BLA: exact on noise-free linear plants (the BLA from an independent
state-space periodic steady state), intervals that cover the truth with noise, and `identify` on broadband data
(the frequency-domain G as the start of the records' fit of G and the friction), with one-line refusals."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from scipy import signal

from servofmu.broadband import BroadbandPlan, estimate_bla, split_periods
from servofmu.broadband.simulate import write_simulated
from servofmu.errors import UserError
from servofmu.identification.frequency_fit import fit_bla, g_names
from servofmu.identification.results import read_result
from servofmu.model.plant import load_plant
from servofmu.selection.data import load_selection_data

ROOT = Path(__file__).resolve().parent.parent

RATE = 200.0


def frictionless(name: str):
    plant = load_plant(name)
    levels = {k: 0.0 for k in ("fc_pos", "fc_neg", "fs_pos", "fs_neg") if getattr(plant.friction, k) is not None}
    return replace(plant, friction=replace(plant.friction, **levels))


def zoh_bla(plant, noise=0.0, seed=0, realisations=4):
    """The BLA of the plant's linear part G/(1 + fv·G) from its exact periodic steady state (scipy's zero-order-hold
    discretisation, independent of the fit's own response)."""
    num, den = plant.transfer_function()
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss(num, np.polyadd(den, plant.friction.fv * num)), 1 / RATE,
                                         "zoh")
    p = BroadbandPlan("multisine", (1.0,), (0.5, 40.0), RATE, period=2.0, periods=2, transient_periods=0,
                      realisations=realisations, seed=1)
    u = p.signals()[0]
    ys = []
    for x in u:
        state = np.zeros(a.shape[0])
        for k in range(p.samples):
            state = a @ state + b[:, 0] * x[k]
        x0 = np.linalg.solve(np.eye(a.shape[0]) - np.linalg.matrix_power(a, p.samples), state)
        ys.append(signal.dlsim((a, b, c, d, 1 / RATE), x, x0=x0)[1][:, 0])
    y = np.stack(ys)
    y = y + noise * np.std(y) * np.random.default_rng(seed).standard_normal(y.shape)
    return estimate_bla(*(split_periods(s, p.samples, 2, 0) for s in (u, y)), p.lines, RATE, p.free_lines)


def truth_of(plant, names):
    values = plant.parameters()
    return np.array([values[n] for n in names])


def perturbed(plant, factor=1.3):
    vector, names = plant.parameter_vector(), plant.parameter_names()
    for n in g_names(plant):
        vector[names.index(n)] *= factor
    return plant.with_parameters(vector)


@pytest.mark.parametrize("name", ["g2", "stribeck_servo"])  # a resonance; two real poles with viscous friction
def test_on_a_noise_free_linear_plant_the_fit_gives_gs_parameters_to_1e_6(name):
    truth = frictionless(name)
    fit = fit_bla(perturbed(truth), [zoh_bla(truth)], RATE)
    assert fit.names == tuple(g_names(truth))
    assert np.max(np.abs(fit.theta / truth_of(truth, fit.names) - 1)) <= 1e-6
    assert fit.relative_error < 1e-9


def test_with_noise_the_intervals_cover_the_truth_and_the_cost_is_the_noises():
    truth = frictionless("g2")
    covered, ratios = [], []
    for seed in range(4):
        fit = fit_bla(truth, [zoh_bla(truth, noise=0.01, seed=seed)], RATE)
        t = truth_of(truth, fit.names)
        covered += list((fit.intervals[:, 0] <= t) & (t <= fit.intervals[:, 1]))
        ratios.append(fit.cost_ratio)
        assert fit.weights == "total"
    assert np.mean(covered) >= 0.8  # 16 intervals of 95 %
    assert 0.8 < np.mean(ratios) < 1.3  # a linear G explains the BLA within its variance


def test_a_bla_with_fewer_numbers_than_gs_parameters_is_refused():
    truth = frictionless("g2")
    bla = zoh_bla(truth)
    few = replace(bla, frequencies=bla.frequencies[:1], G=bla.G[:1], var_total=bla.var_total[:1],
                  var_noise=bla.var_noise[:1])
    with pytest.raises(UserError, match="too few"):
        fit_bla(truth, [few], RATE)


SMALL = BroadbandPlan("multisine", (2.0, 0.8), (0.5, 20.0), RATE, period=2.0, periods=2, transient_periods=1,
                      realisations=2, seed=3)


def test_identify_on_broadband_data_fits_g_and_the_friction_from_the_frequency_domain_start(tmp_path):
    truth = load_plant("g1")
    data, out = tmp_path / "bb.h5", tmp_path / "r.h5"
    write_simulated(data, truth, SMALL, noise_snr_db=40.0, seed=1)
    proc = run("identify", data, "--structure", "g1", "-o", out, "--iterations", "10")
    assert proc.returncode == 0, proc.stderr
    assert "frequency-domain fit of G to the BLA" in proc.stdout and "biased" in proc.stdout
    result = read_result(out)
    assert [s.name for s in result.stages][:2] == ["frequency", "pso"]
    fd = result.provenance["frequency_fit"]
    assert fd["cost_ratio"] > 3  # friction: a linear G does not explain the BLA
    t = truth_of(truth, result.names)
    assert np.all(np.abs(result.theta / t - 1) < 0.02), (result.names, result.theta)
    assert result.provenance["data_kind"] == "broadband"
    proc = run("validate", out, data, "--json")  # its records, as identify fitted them
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["passed"] and report["own_data"] and len(report["records"]) == 1
    proc = run("report", out, "-o", tmp_path / "r.html")
    assert proc.returncode == 0, proc.stderr
    assert "the G fitted to the BLA" in (tmp_path / "r.html").read_text()


def test_identify_and_plot_refuse_what_they_cannot_do_with_broadband_data_and_select_reads_its_records(tmp_path):
    data = tmp_path / "bb.h5"
    write_simulated(data, frictionless("g1"), SMALL)
    proc = run("identify", data, "--structure", "g1", "--method", "ga-ann", "-o", tmp_path / "r.h5")
    assert_one_line_error(proc, "ga-ann needs a network trained on this broadband plan")
    proc = run("identify", data, "--structure", "g1", "--closed-loop", ROOT / "fmu_models" / "axis_controller.toml",
               "-o", tmp_path / "r.h5")
    assert_one_line_error(proc, "broadband data is open loop", "without --closed-loop")
    assert not (tmp_path / "r.h5").exists()
    # select fits its candidates to the records as identify does (one run from rest); not in a loop
    fit, files = load_selection_data([data])
    (series,) = fit.records
    assert series.u.size == 2 * 2 * 3 * SMALL.samples and files[0].kind == "broadband"
    other = tmp_path / "other.h5"
    write_simulated(other, frictionless("g1"), SMALL, noise_snr_db=30.0)
    proc = run("select", data, "--validate", other, "--closed-loop", ROOT / "fmu_models" / "axis_controller.toml",
               "-o", tmp_path / "s.h5")
    assert_one_line_error(proc, "broadband data is open loop", "without --closed-loop")
    assert not (tmp_path / "s.h5").exists()
    proc = run("plot", data, "--what", "time", "-o", tmp_path / "t.png")
    assert_one_line_error(proc, "broadband", "--what bode")
    proc = run("plot", data, "-o", tmp_path / "bode.png")  # the BLA with its ±2σ band
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "bode.png").read_bytes()[:4] == b"\x89PNG"


def test_the_first_polish_on_a_smoothed_sign_leaves_the_minimum_a_stick_event_away():
    """stribeck_servo at 0.6 N RMS sticks and slips: from where a plain polish of the default plan once stopped (a
    stick event from the best fit), the plain polish stays at three times the noise; with the first descent on the
    sign smoothed as SMOOTHING_CONTINUATION says (identify's broadband fit), the polish reaches the fit at the noise,
    below the residual of the truth itself."""
    from servofmu.broadband.simulate import simulate_broadband
    from servofmu.broadband.store import BroadbandData
    from servofmu.identification.broadband_identify import SMOOTHING_CONTINUATION, broadband_records
    from servofmu.identification.criterion import POLISH_RTOL, RecordCriterion
    from servofmu.identification.features import to_targets
    from servofmu.identification.identifier import PSOANNIdentifier
    from servofmu.identification.prior import identified_names
    from servofmu.identification.pso import PsoOptions
    from servofmu.simulation.batch import BatchSimulator

    plant = load_plant("stribeck_servo")
    plan = BroadbandPlan("multisine", (0.6,), (0.2, 50.0), 1000.0, period=5.0, periods=1, realisations=1)
    data = broadband_records(BroadbandData("s", plan, tuple(simulate_broadband(plant, plan, 40.0, seed=0))))
    stuck = np.array([-4.94695, -39.99361, 2.0192, 0.30376, 0.25257, 0.44084, 0.35079, 0.0451])
    y0 = to_targets(plant, stuck[None])[0]
    truth = RecordCriterion(plant, data, BatchSimulator(plant)).relative_rms(
        truth_of(plant, identified_names(plant)), POLISH_RTOL)
    fitness = {}
    for factors in ((), SMOOTHING_CONTINUATION):
        est = PSOANNIdentifier(plant, method="pso", pso=PsoOptions(particles=2, iterations=0), threads=1)
        est.start, est.smoothing_continuation = (y0 - 1e-12, y0 + 1e-12, y0), factors  # the polish from y0
        fitness[factors] = est.fit(data).fitness_
    assert fitness[()] > 2 * truth
    assert fitness[SMOOTHING_CONTINUATION] <= truth


def test_the_periods_give_the_noise_level_and_identify_reports_its_residuals_against_it(tmp_path):
    """period_noise: white noise of a known σ recovered from the periods' deviations (within 6 %, three standard
    deviations of an estimate on 1600 degrees of freedom, against the σ simulate_broadband adds), from the levels
    marked periodic only; identify's fit at the noise reports a ratio of about 1, and a fit stopped at the
    swarm's first particles, unpolished, is reported above the noise in one warning line."""
    from servofmu.broadband.simulate import simulate_broadband
    from servofmu.broadband.store import read_broadband
    from servofmu.identification.broadband_identify import period_noise

    truth = load_plant("g1")
    data = tmp_path / "bb.h5"
    write_simulated(data, truth, SMALL, noise_snr_db=40.0, seed=2)
    clean = np.concatenate([lv.v for lv in simulate_broadband(truth, SMALL)])
    sigma = float(np.std(clean)) / 100  # 40 dB
    assert period_noise(read_broadband(data)) == pytest.approx(sigma, rel=0.06)
    bb = read_broadband(data)  # a second level whose periods differ (a limit cycle's): left out when so marked
    wild = replace(bb.levels[1], v_noisy=bb.levels[1].v_noisy + 50 * sigma * np.random.default_rng(0).standard_normal(
        bb.levels[1].v_noisy.shape))
    bb = replace(bb, levels=(bb.levels[0], wild))
    assert period_noise(bb) > 10 * sigma
    assert period_noise(bb, [True, False]) == pytest.approx(sigma, rel=0.08)
    assert np.isnan(period_noise(bb, [False, False]))
    proc = run("identify", data, "--structure", "g1", "-o", tmp_path / "r.h5", "--iterations", "10")
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr
    noise = read_result(tmp_path / "r.h5").provenance["records_noise"]
    assert noise["residual_ratio"] == pytest.approx(1.0, abs=0.03) and "times the noise of the periods" in proc.stdout
    proc = run("identify", data, "--structure", "g1", "-o", tmp_path / "r0.h5", "--iterations", "0", "--no-polish")
    assert proc.returncode == 0
    assert "times the noise of the periods" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert read_result(tmp_path / "r0.h5").provenance["records_noise"]["residual_ratio"] > 1.05


def test_identify_warns_when_no_level_is_periodic(tmp_path):
    """A tone between the period's lines at every level (as a limit cycle puts there): the periods then differ by
    more than the noise, so identify says it has no noise level, in one warning line and in its table."""
    from servofmu.broadband.store import read_broadband, write_broadband

    truth = load_plant("g1")
    data, cycling = tmp_path / "bb.h5", tmp_path / "cycling.h5"
    write_simulated(data, truth, SMALL, noise_snr_db=40.0, seed=2)
    bb = read_broadband(data)
    tone = [0.3 * np.std(lv.v) * np.sin(2 * np.pi * 7.3 * np.arange(lv.v.size) / RATE).reshape(lv.v.shape)
            for lv in bb.levels]  # 7.3 Hz: between the 0.5 Hz lines
    write_broadband(cycling, bb.plan, [replace(lv, v_noisy=lv.v_noisy + x) for lv, x in zip(bb.levels, tone)],
                    bb.provenance, truth.parameters())
    for path, periodic in ((data, True), (cycling, False)):
        proc = run("identify", path, "--structure", "g1", "-o", tmp_path / "r.h5", "--force", "--iterations", "0",
                   "--no-polish")
        assert proc.returncode == 0, proc.stderr
        assert ("no level's response is periodic" in proc.stderr) is not periodic
        assert ("no noise level" in proc.stdout) is not periodic
        assert read_result(tmp_path / "r.h5").provenance["records_noise"]["levels"] == ([2.0, 0.8] if periodic else [])
