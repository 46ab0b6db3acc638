"""Tuning a drive for an identified axis: the linearised loop against scipy and against a time simulation, the
reference rule against its formulas, the swarm against the given gains on a small case, the controller file it
writes, the check on the axis, and one-line errors for bad input."""
from __future__ import annotations

import itertools
import shlex
from pathlib import Path

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from scipy import signal

import servofmu as sf
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.identification.results import Result, write_result
from servofmu.model.controller import controller_from_dict, controller_toml, load_controller
from servofmu.simulation.closed_loop import LoopSimulator
from servofmu.tuning.check import reversal_velocity_error, settling
from servofmu.tuning.loop import analyse_loop, zoh_position_plant
from servofmu.tuning.rule import equivalent_dead_time, rule_gains, tune_rule
from servofmu.tuning.search import TuneOptions, search_gains, tracking_errors, uncertainty_sets
from servofmu.tuning.task import stroke_task

TS = 1e-3
DOCS = Path(__file__).resolve().parent.parent / "docs" / "tuning.md"


def controller(**changes):
    """The example drive with an exact encoder (and ``changes``)."""
    return load_controller("axis_controller").with_values(encoder_resolution=0.0, **changes)


def scipy_sensitivity(plant, c, omega):
    """|S(e^{jωTs})| = 1/|1 + L| of :func:`scipy_loop`."""
    return np.abs(1 / (1 + scipy_loop(plant, c, omega)))


def scipy_loop(plant, c, omega):
    """L(e^{jωTs}) from scipy's ZOH discretisation and frequency responses, each factor written here from the
    controller law (controller_law.h) by hand."""
    num, den = plant.transfer_function()
    ts = c["sample_time"]
    spring = plant.load.stiffness or 0.0  # x = G_v/s·(u − k·x)
    position = np.polyadd(np.polymul(np.polyadd(den, plant.friction.fv * num), [1, 0]), spring * num)
    pz = signal.cont2discrete((num, position), ts, "zoh")
    w = omega * ts
    _, p = signal.freqz(np.ravel(pz[0]), pz[1], worN=w)
    _, pi = signal.freqz([c["kp_velocity"] + c["ki_velocity"] * ts, -c["kp_velocity"]], [1, -1], worN=w)
    kind = int(c["velocity_filter"])
    if kind == 0:
        _, f = signal.freqz([1 / ts, -1 / ts], [1], worN=w)
    elif kind == 1:
        n = int(c["filter_window"])
        _, f = signal.freqz(np.r_[1.0, np.zeros(n - 1), -1.0] / (n * ts), [1], worN=w)
    else:
        alpha = ts / (c["filter_time_constant"] + ts)
        _, f = signal.freqz([alpha / ts, -alpha / ts], [1, -(1 - alpha)], worN=w)
    delay = np.exp(-1j * w * int(c["delay"]))
    return pi * (c["kp_position"] + f) * delay * p


def test_zoh_plant_of_a_mass_with_damping_is_the_closed_form():
    """G = K/(s + a) over s, held: (K/a)·[(Ts − β/a)z + (β/a − Ts·e^{−aTs})]/((z − 1)(z − e^{−aTs})),
    β = 1 − e^{−aTs}."""
    plant = sf.load_plant("linear_axis")
    k, a = plant.numerator_gain(), -plant.all_poles()[0].real
    e, beta = np.exp(-a * TS), -np.expm1(-a * TS)
    num, den = zoh_position_plant(plant, TS)
    expected_num = k / a * np.array([TS - beta / a, beta / a - TS * e])
    # (the library's numerator is a difference of two characteristic polynomials near (z − 1)²: 1e-8 of it is
    # rounding, far below anything a sensitivity peak can see)
    np.testing.assert_allclose(num[-2:], expected_num, rtol=1e-6)
    np.testing.assert_allclose(den, np.poly([1.0, e]), rtol=1e-12, atol=1e-15)


def sprung_axis():
    """stribeck_axis with viscous friction and a spring on its load (the linearisation keeps both)."""
    from servofmu.model.plant import plant_from_dict

    import tomllib

    data = tomllib.loads(sf.load_plant("stribeck_axis").to_toml())
    data["friction"]["fv"] = 50.0
    data["load"] = {"offset": -40.0, "stiffness": 2e6, "x0": 0.01}  # 22 Hz with the mass: near the crossover
    return plant_from_dict(data)


@pytest.mark.parametrize("changes", [{}, {"velocity_filter": 1.0, "filter_window": 4.0},
                                     {"velocity_filter": 2.0, "filter_time_constant": 2e-3},
                                     {"delay": 2.0, "kp_velocity": 9000.0}, {"kp_position": 120.0}, "spring",
                                     # a P-only velocity loop on a two-sample difference (the EMPS axis's drive)
                                     {"ki_velocity": 0.0, "velocity_filter": 1.0, "filter_window": 2.0}])
def test_sensitivity_peak_matches_scipy(changes):
    plant = sf.load_plant("stribeck_axis") if changes != "spring" else sprung_axis()
    changes = {} if changes == "spring" else changes
    c = controller(**changes)
    analysis = analyse_loop(plant, c)
    omega = np.linspace(0.1, np.pi / TS * (1 - 1e-9), 400_000)
    loop = scipy_loop(plant, c, omega)
    assert analysis.stable
    assert analysis.ms == pytest.approx(np.max(np.abs(1 / (1 + loop))), rel=1e-4)
    # the margins from the same curve: the phase at the last |L| = 1, |L| where L crosses the negative real axis
    last = np.flatnonzero(np.abs(loop) >= 1)[-1]
    assert analysis.phase_margin == pytest.approx(180 + np.degrees(np.angle(loop[last])), abs=0.01)
    crossing = np.flatnonzero((np.sign(loop.imag[:-1]) != np.sign(loop.imag[1:])) & (loop.real[:-1] < 0)
                              & (np.abs(loop[:-1]) < 1))
    assert analysis.gain_margin == pytest.approx(1 / np.max(np.abs(loop[crossing])), rel=1e-3)


def test_an_unstable_loop_has_an_infinite_peak():
    analysis = analyse_loop(sf.load_plant("linear_axis"), controller(kp_velocity=2e5))
    assert not analysis.stable and analysis.ms == np.inf


def test_sensitivity_from_a_frequency_sweep_of_the_time_simulation():
    """The drive's C law and the batch integrator, the reference a ramp (the friction a constant force) plus a
    small sine, feed-forward off: the command's harmonic over the reference's is kp_position·C(z)·S(z) delayed,
    so |S| follows from the simulation alone."""
    plant = sf.load_plant("linear_axis")
    c = controller(velocity_feedforward=0.0, mass_feedforward=0.0)
    sim = LoopSimulator(plant, threads=1)
    t = np.arange(0.0, 1.5 + TS / 2, TS)
    analysis = analyse_loop(plant, c)
    for hz in (10.0, 40.0, analysis.ms_frequency / (2 * np.pi), 150.0):
        omega = 2 * np.pi * hz
        amplitude = 0.01 / omega  # the velocity stays above 0.04 m/s: no reversal
        r = 0.05 * t + amplitude * np.sin(omega * t)
        out = sim.simulate_loop(plant.parameter_vector()[None], t, r, c, rtol=1e-10).command[0]
        keep = t > 0.5
        basis = np.column_stack([np.ones(keep.sum()), t[keep], np.sin(omega * t[keep]), np.cos(omega * t[keep])])
        coef = np.linalg.lstsq(basis, out[keep], rcond=None)[0]
        gain = np.hypot(coef[2], coef[3]) / amplitude
        z = np.exp(1j * omega * TS)
        pi = c["kp_velocity"] + c["ki_velocity"] * TS * z / (z - 1)
        measured = gain / abs(c["kp_position"] * pi)
        assert measured == pytest.approx(scipy_sensitivity(plant, c, np.array([omega]))[0], rel=2e-3)


@pytest.mark.parametrize("changes, lag", [({}, 0.5), ({"velocity_filter": 1.0, "filter_window": 6.0}, 3.0),
                                          ({"velocity_filter": 2.0, "filter_time_constant": 3e-3}, 3.5),
                                          ({"delay": 3.0}, 0.5)])
def test_rule_gains_are_the_closed_form(changes, lag):
    plant = sf.load_plant("linear_axis")
    c = controller(**changes)
    t_sigma = (c["delay"] + 0.5) * TS + lag * TS
    assert equivalent_dead_time(c) == pytest.approx(t_sigma)
    mass = 1 / plant.numerator_gain()
    for a in (2.0, 3.1):
        g = rule_gains(plant, c, a)
        assert g["kp_velocity"] == pytest.approx(mass / (a * t_sigma))
        assert g["ki_velocity"] == pytest.approx(mass / (a ** 3 * t_sigma ** 2))
        assert g["kp_position"] == pytest.approx(1 / (2 * a ** 2 * t_sigma))
        assert (g["velocity_feedforward"], g["mass_feedforward"]) == (1.0, pytest.approx(mass))


def test_rule_meets_the_sensitivity_bound_on_it():
    plant = sf.load_plant("linear_axis")
    rule, a = tune_rule(plant, controller(), 1.7)
    assert a > 2.0  # the textbook a = 2 is above the bound once the position loop is closed
    assert 1.69 < analyse_loop(plant, rule).ms <= 1.7 + 1e-6
    assert analyse_loop(plant, rule_gains(plant, controller(), 2.0)).ms > 1.7


def fake_result(plant, spread=2e-3, controller_file=None):
    """A result of ``plant`` at its true values with 95 % intervals of ±``spread`` (relative)."""
    theta = plant.parameter_vector()[identified_mask(plant)]
    intervals = np.stack([theta - spread * np.abs(theta), theta + spread * np.abs(theta)], axis=1)
    provenance = {"controller_file": str(controller_file)} if controller_file else {}
    return Result("pso", plant, plant, tuple(identified_names(plant)), theta, intervals, 0.0, 0.0, 0,
                  (), np.zeros(1), provenance)


@pytest.fixture(scope="module")
def small_tuning():
    """The swarm on a short stroke from a badly tuned start (every gain a tenth of the example's)."""
    plant = sf.load_plant("linear_axis")
    bad = load_controller("axis_controller")
    bad = bad.with_values(kp_position=4.0, kp_velocity=1885.0, ki_velocity=71000.0, mass_feedforward=10.0)
    task = stroke_task(0.02, 0.05, TS)
    result = fake_result(plant)
    uncertainty = uncertainty_sets(plant, result.theta, result.intervals, draws=2)
    found = search_gains(uncertainty, bad, task, TuneOptions(particles=8, iterations=6, draws=2, threads=1))
    return plant, bad, task, result, found


def test_tune_improves_the_tracking_error_on_a_small_case(small_tuning):
    plant, bad, task, result, found = small_tuning
    sim = LoopSimulator(plant, threads=1)
    truth = plant.parameter_vector()[None]
    given = tracking_errors(sim, truth, task, bad)[0]
    tuned = tracking_errors(sim, truth, task, found.controller)[0]
    assert tuned < given / 3
    assert analyse_loop(plant, found.controller).ms <= 1.7 + 1e-6
    assert np.all(np.diff(found.history) <= 0)


def test_tuned_loop_is_stable_at_every_corner_of_the_box(small_tuning):
    plant, _, _, result, found = small_tuning
    for corner in itertools.product(*result.intervals):  # every identified parameter at either end
        full = plant.parameter_vector()
        full[identified_mask(plant)] = corner
        analysis = analyse_loop(plant.with_parameters(full), found.controller)
        assert analysis.stable and analysis.ms <= 2.0


def test_controller_file_round_trip_with_friction_feedforward():
    from servofmu.model.controller import friction_feedforward

    c = friction_feedforward(controller(velocity_filter=2.0, filter_time_constant=2.5e-3), sf.load_plant(
        "stribeck_axis"))
    import tomllib
    back = controller_from_dict(tomllib.loads(controller_toml(c, "a comment\non two lines")))
    assert back.values == c.values and back.name == c.name


def test_settling_and_reversal_figures_of_known_signals():
    t = np.arange(0, 1.0, 1e-3)
    r = np.where(t > 0, 1.0, 0.0)
    x = 1 - np.exp(-t / 0.1)  # leaves the ±2 % band for good at 0.1·ln 50
    settle, overshoot = settling(t, r, x)
    assert settle == pytest.approx(0.1 * np.log(50), abs=1.5e-3) and overshoot == 0.0
    assert settling(t, r, 1 + 0.1 * np.exp(-t / 0.1) * (t > 0))[1] == pytest.approx(0.1, abs=1e-3)
    reference = 0.5 * (1 - np.cos(2 * np.pi * t))  # reverses at 0.5 s
    v = np.gradient(reference, t) + np.where(np.abs(t - 0.5) < 0.01, 0.3, 0.0) + np.where(t > 0.8, 9.0, 0.0)
    assert reversal_velocity_error(t, reference, v) == pytest.approx(0.3)


# ---------------------------------------------------------------------------
# The command
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tune")
    write_result(folder / "result.h5", fake_result(sf.load_plant("linear_axis")))
    write_result(folder / "g1.h5", fake_result(sf.load_plant("g1")))
    return folder


def test_commands_of_docs_tuning_run(tmp_path):
    """docs/tuning.md's console block, in order, in an empty folder with a reference from rest: the tuned file
    meets the bound on the identified plant and keeps the drive's settings, the rule's feeds the friction forward
    at the other bound, the page holds its tables and figures."""
    block = DOCS.read_text().split("```console", 1)[1].split("```", 1)[0]
    commands = [shlex.split(line[2:]) for line in block.splitlines() if line.startswith("$ servofmu ")]
    assert len(commands) == 8
    t = np.arange(0.0, 2.0005, TS)
    x = 0.03 * (1 - np.cos(np.pi * t)) + 0.01 * (1 - np.cos(2 * np.pi * 2.3 * t))
    np.savetxt(tmp_path / "reference.csv", np.column_stack([t, x]), delimiter=",", header="time,position",
               comments="")
    for argv in commands:
        proc = run(*argv[1:], cwd=tmp_path)
        assert proc.returncode == 0, f"{' '.join(argv)}: {proc.stderr}"
        if argv[1:3] == ["tune", "axis-result.h5"] and "--axis" in argv:
            assert "on the axis" in proc.stdout and "tuned" in proc.stdout.splitlines()[3]
    identified = sf.read_result(tmp_path / "axis-result.h5").plant
    tuned, rule = load_controller(tmp_path / "tuned.toml"), load_controller(tmp_path / "rule.toml")
    assert analyse_loop(identified, tuned).ms <= 1.7 + 1e-6
    assert analyse_loop(identified, rule).ms == pytest.approx(1.5, abs=0.01)
    for c in (tuned, rule):
        assert (c.sample_time, c["delay"], c["force_limit"], c["encoder_resolution"]) == (1e-3, 1, 3000.0, 1e-6)
    assert tuned["friction_feedforward"] == 0.0 and rule["friction_feedforward"] == 1.0
    assert rule["ff_fc_pos"] == pytest.approx(identified.friction.fc_pos)
    html = (tmp_path / "tune.html").read_text()
    assert all(f'id="{t}"' in html for t in ("gains", "loop", "model", "axis")) and html.count("data:image/png") == 3
    assert (tmp_path / "tuned.fmu").stat().st_size > 0


def test_tune_checks_on_the_axis(files, tmp_path, built_fmu):
    """--axis: the given, the rule's and the tuned gains co-simulated on libcosim; the model's promise kept."""
    from servofmu.control.fmus import build_controller_fmu
    from servofmu.control.system import write_system
    from servofmu.tuning.run import tune_axis

    c = load_controller("axis_controller")
    drive = build_controller_fmu(c, tmp_path / "drive.fmu", fmi_version=2)
    task = stroke_task(0.02, 0.05, TS)
    ssp = write_system(built_fmu("linear_axis", 2), drive, (task.time, task.position), tmp_path / "axis.ssp")
    tuning = tune_axis(fake_result(sf.load_plant("linear_axis")), c, task,
                       TuneOptions(particles=6, iterations=2, draws=1, threads=1), axis=ssp)
    axis = {r.label: r.figures for r in tuning.axis_runs}
    assert set(axis) == {"given", "rule", "tuned"}
    for label, run_ in tuning.runs.items():  # the model is the truth here: co-simulation and model agree
        assert axis[label].rms_error == pytest.approx(run_.figures.rms_error, rel=0.05)
        assert axis[label].settling_time == pytest.approx(run_.figures.settling_time, abs=3e-3)
    assert axis["tuned"].rms_error < axis["given"].rms_error


def test_bad_input_is_one_line_and_writes_nothing(files, tmp_path):
    out = tmp_path / "tuned.toml"
    jump = tmp_path / "jump.csv"
    t = np.arange(0, 1.0 + TS / 2, TS)
    np.savetxt(jump, np.column_stack([t, np.where(t > 0.5, 0.01, 0.0)]), delimiter=",", header="time,position",
               comments="")
    cases = [(("--task", jump), ("infeasible", "jumps", "output limit")),
             (("--max-sensitivity", "1.0"), ("sensitivity peak bound must be above 1",)),
             (("--max-sensitivity", "nan"), ("sensitivity peak bound",)),
             (("--task", jump, "--stroke", "0.1"), ("not both",))]
    for extra, fragments in cases:
        assert_one_line_error(run("tune", files / "result.h5", "axis_controller", *extra, "-o", out), *fragments)
        assert not out.exists()
    assert_one_line_error(run("tune", files / "g1.h5", "axis_controller", "-o", out), "another plant")
    other = tmp_path / "slow.toml"
    other.write_text(controller_toml(load_controller("axis_controller").with_values(sample_time=2e-3)))
    result = tmp_path / "logged.h5"
    write_result(result, fake_result(sf.load_plant("linear_axis"), controller_file=other))
    assert_one_line_error(run("tune", result, "axis_controller", "-o", out), "another axis")
    assert not out.exists()


def test_json_of_the_rule_is_its_formula_at_the_bound(files, tmp_path):
    import json

    proc = run("tune", files / "result.h5", "axis_controller", "--method", "rule", "--max-sensitivity", "1.6",
               "--stroke", "0.02", "--speed", "0.05", "--json", "-o", tmp_path / "rule.toml")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["chosen"] == "rule" and set(out["controllers"]) == {"given", "rule"}
    rule = out["controllers"]["rule"]
    expected = rule_gains(sf.load_plant("linear_axis"), load_controller("axis_controller"), out["rule_a"])
    for name in ("kp_position", "kp_velocity", "ki_velocity", "mass_feedforward"):
        assert rule["gains"][name] == pytest.approx(expected[name], rel=1e-9)
    assert 1.59 < rule["loop"]["worst_sensitivity_peak"] <= 1.6 + 1e-6
    assert load_controller(tmp_path / "rule.toml")["kp_velocity"] == pytest.approx(expected["kp_velocity"])
