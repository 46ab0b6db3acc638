"""The third probe's closed-loop classes: a drive's log that does not match its controller file (class 1: the file's
law, fed the log's own reference and encoder, must give the logged command — a wrong gain, delay, encoder quantum or
a reference out of step is refused in one line naming the key the log fits instead; the right file passes silently;
tune refuses an undetermined parameter unless told to keep it) and absurd work refused up front (class 6: a search
whose options multiply to days is estimated — its evaluations times the measured time of one — and refused in one
line naming the estimate and the option that raises the bound; nothing is written)."""
from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from clitools import assert_one_line_error, run

import servofmu as sf
from servofmu.errors import ServofmuWarning, UserError
from servofmu.identification.closed_loop import check_law
from servofmu.identification.law_check import LAW_WARNED, law_command, law_fit
from servofmu.identification.results import write_result
from servofmu.model.controller import controller_from_dict, controller_toml, load_controller
from servofmu.simulation.closed_loop import LoopSimulator

from test_drive_logs import CONTROLLER, FORCE_CONSTANT, IMPORT, STRUCTURE, drive_log, reference_and_pulses, write_log
from test_tune import fake_result

AXIS = {"name": "axis", "sample_time": 1e-3, "delay": 1, "position": {"kp": 40.0},
        "velocity": {"kp": 18850.0, "ki": 710000.0}, "output": {"limit": 3000.0}, "encoder": {"resolution": 1e-6}}


def _drive(**sections):
    """The docs/control.md drive, with keys changed (section__key=value, or a whole section)."""
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in AXIS.items()}
    for key, value in sections.items():
        section, _, name = key.partition("__")
        if name:
            data.setdefault(section, {})[name] = value
        else:
            data[section] = value
    return controller_from_dict(data, "drive.toml")


def _simulated_log(controller, seconds=1.5, pulses=True):
    """The axis (linear_axis) in ``controller``'s loop by servofmu's C law, with injected pulses."""
    t = np.arange(0.0, seconds, controller.sample_time)
    r = 0.02 * (1 - np.cos(2 * np.pi * 1.1 * t)) + 0.004 * np.sin(2 * np.pi * 7.3 * t)
    d = np.where((t % 0.2 > 0.1) & (t % 0.2 < 0.11), 400.0, 0.0) if pulses else None
    plant = sf.load_plant("linear_axis")
    loop = LoopSimulator(plant).simulate_loop(plant.parameter_vector()[None], t, r, controller, rtol=1e-10,
                                              disturbance=d)
    return r, loop.position[0], loop.command[0], d


@pytest.mark.parametrize("changes", [
    {}, {"velocity__filter": "moving-average", "velocity__window": 3},
    {"velocity__filter": "first-order", "velocity__time_constant": 0.004, "delay": 3},
    {"feedforward": {"velocity": 0.7, "mass": 40.0}, "output": {"limit": 600.0}},
    {"compensation": {"share": 1.0, "fc_pos": 40.0, "fc_neg": 32.0, "fs_pos": 55.0, "fs_neg": 41.0, "vs": 0.01,
                      "fv": 20.0}},
    {"encoder": {"resolution": 0.0}, "velocity": {"kp": 9000.0, "ki": 0.0}},
])
def test_c1_the_law_in_numpy_reproduces_the_simulators_C_law(changes):
    controller = _drive(**changes)
    r, x, command, d = _simulated_log(controller)
    own, delay = command - d, int(controller["delay"])
    logged = np.concatenate([np.zeros(delay), law_command(controller, r, x)])[:own.size]
    np.testing.assert_allclose(logged, own, rtol=0, atol=1e-9 * np.max(np.abs(own)))
    if "output" in changes:
        assert np.mean(np.abs(own) >= controller["force_limit"] * (1 - 1e-12)) > 0.01  # the limit was reached
    assert law_fit(controller, r, x, command, d).residual < 1e-9


@pytest.mark.parametrize("wrong, key, logged", [
    ({"velocity__kp": 2 * 18850.0}, "velocity.kp", "18850"),
    ({"velocity__ki": 0.0}, "velocity.ki", "710000"),
    ({"position__kp": 55.0}, "position.kp", "40"),
    ({"delay": 2}, "delay", "1"),
    ({"encoder": {"resolution": 1e-3}}, "encoder.resolution", "1e-06"),
    ({"encoder": {"resolution": 1e99}}, "encoder.resolution", "1e-06"),
])
def test_c1_a_wrong_key_is_refused_naming_the_value_the_log_fits(wrong, key, logged):
    r, x, command, d = _simulated_log(_drive())
    fit = law_fit(_drive(**wrong), r, x, command, d)
    assert fit.verdict() == "refuse" and fit.key == key and fit.logged == logged, fit
    with pytest.raises(UserError, match=rf"log.h5: record a: the law of drive.toml leaves .* fits {key} = {logged}"):
        check_law("log.h5: record a", _drive(**wrong), r, x, command, d, np.ones(r.size, bool))


@pytest.mark.parametrize("shift", [50, -50, 7])
def test_c1_a_reference_out_of_step_with_the_encoder_is_named(shift):
    r, x, command, d = _simulated_log(_drive())
    moved = np.concatenate([r[shift:], np.full(shift, r[-1])]) if shift > 0 else \
        np.concatenate([np.full(-shift, r[0]), r[:shift]])
    fit = law_fit(_drive(), moved, x, command, d)
    assert fit.verdict() == "refuse" and fit.key == "reference"
    assert fit.logged == f"{abs(shift)} samples {'earlier' if shift > 0 else 'later'} than logged"


def test_c1_an_independent_drive_log_passes_silently_with_its_file_and_is_refused_with_a_doubled_gain(tmp_path):
    """The drive of test_drive_logs (its cascade in volts, written there in plain Python) through import."""
    log = drive_log(*reference_and_pulses(1.0, 5), seed=5, encoder=1e-6, noise=2.0)
    write_log(tmp_path / "log.csv", log)
    assert run("import", tmp_path / "log.csv", *IMPORT, "-o", tmp_path / "log.h5").returncode == 0
    s = sf.read_data_file(tmp_path / "log.h5").records[0].series
    (tmp_path / "drive.toml").write_text(CONTROLLER)
    right = load_controller(tmp_path / "drive.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("error", ServofmuWarning)
        check_law("w", right, s.reference, s.position, s.u, s.disturbance, np.ones(s.u.size, bool))
    assert law_fit(right, s.reference, s.position, s.u, s.disturbance).residual < LAW_WARNED / 100
    kv = right["kp_velocity"]
    (tmp_path / "gain.toml").write_text(CONTROLLER.replace(f"kp = {kv}", f"kp = {2 * kv}"))
    (tmp_path / "s.toml").write_text(STRUCTURE)
    proc = run("identify", tmp_path / "log.h5", "--structure", tmp_path / "s.toml", "--closed-loop",
               tmp_path / "gain.toml", "-o", tmp_path / "r.h5")
    assert_one_line_error(proc, f"fits velocity.kp = {kv:.6g}")
    assert "gain.toml" in proc.stderr and not (tmp_path / "r.h5").exists()
    assert FORCE_CONSTANT * 60.0 == kv  # the volt drive's gain, in N/(m/s)


def test_c1_a_rough_match_is_a_warning_not_a_refusal():
    """A command logged through the drive's own noise (a measured current, say): a few per cent off the law."""
    r, x, command, d = _simulated_log(_drive())
    noisy = command + 0.05 * np.std(command - d) * np.random.default_rng(0).standard_normal(command.size)
    fit = law_fit(_drive(), r, x, noisy, d)
    assert fit.verdict() == "ok", fit
    wrong = law_fit(_drive(delay=2), r, x, noisy, d)
    assert wrong.verdict() in ("warn", "refuse") and (wrong.key, wrong.logged) == ("delay", "1"), wrong


def test_c1_tune_refuses_an_undetermined_parameter_unless_told_to_keep_it(tmp_path):
    """A result whose fc_neg interval is infinite (the data did not separate it): refused naming it; with --keep it
    is tuned at its identified value, and the tuned controller equals the one of a result where its interval has
    width 0 (the same uncertainty set)."""
    plant = sf.load_plant("linear_axis")
    result = fake_result(plant)
    names = list(result.names)
    open_ = result.intervals.copy()
    open_[names.index("fc_neg")] = [-np.inf, np.inf]
    point = result.intervals.copy()
    point[names.index("fc_neg")] = result.theta[names.index("fc_neg")]
    write_result(tmp_path / "open.h5", replace(result, intervals=open_))
    write_result(tmp_path / "point.h5", replace(result, intervals=point))
    rule = ("axis_controller", "--method", "rule", "--stroke", "0.02", "--speed", "0.05")
    proc = run("tune", tmp_path / "open.h5", *rule, "-o", tmp_path / "t.toml")
    assert_one_line_error(proc, "did not determine fc_neg", "--keep fc_neg")
    assert not (tmp_path / "t.toml").exists()
    assert_one_line_error(run("tune", tmp_path / "open.h5", *rule, "--keep", "mass", "-o", tmp_path / "t.toml"),
                          "--keep mass: not an identified parameter")
    assert run("tune", tmp_path / "open.h5", *rule, "--keep", "fc_neg", "-o", tmp_path / "t.toml").returncode == 0
    assert run("tune", tmp_path / "point.h5", *rule, "-o", tmp_path / "p.toml").returncode == 0
    kept, pointed = load_controller(tmp_path / "t.toml"), load_controller(tmp_path / "p.toml")
    assert kept.values == pointed.values


def _closed_loop_log(folder):
    """A short closed-loop log of linear_axis in the docs/control.md drive, as a records file."""
    controller = _drive()
    r, x, command, d = _simulated_log(controller, seconds=0.5)
    t = np.arange(r.size) * controller.sample_time
    np.savetxt(folder / "log.csv", np.column_stack([t, r, x, command, d]), delimiter=",",
               header="t,ref,enc,out,pulse", comments="", fmt="%.17g")
    assert run("import", folder / "log.csv", "--time", "t", "--reference", "ref", "--output-variable", "enc",
               "--kind", "position", "--input", "out", "--disturbance", "pulse",
               "-o", folder / "log.h5").returncode == 0
    (folder / "drive.toml").write_text(controller_toml(controller))
    return folder / "log.h5"


def test_c6_searches_estimated_at_years_are_refused_and_the_limit_can_be_raised(tmp_path):
    log = _closed_loop_log(tmp_path)
    DRIVE = tmp_path / "drive.toml"  # noqa: N806 (the drive of the log, as a file)
    out = tmp_path / "out.h5"
    proc = run("identify", log, "--structure", "linear_axis", "--closed-loop", DRIVE, "--iterations",
               "1000000000", "-o", out)
    assert_one_line_error(proc, "the search (10 particles × 1000000000 iterations", "years on this machine",
                          "--work-limit 8 h", "fewer --iterations")
    proc = run("select", log, "--validate", log, "--closed-loop", DRIVE, "--budget", "1e9", "-o", out)
    assert_one_line_error(proc, "candidates' swarms of up to --budget 1e+09 s each", "--work-limit")
    assert_one_line_error(run("identify", log, "--structure", "linear_axis", "--closed-loop", DRIVE,
                              "--work-limit", "0", "-o", out), "--work-limit must be a positive number of hours")
    assert not out.exists()
    write_result(tmp_path / "r.h5", fake_result(sf.load_plant("linear_axis")))
    proc = run("tune", tmp_path / "r.h5", "axis_controller", "--stroke", "0.02", "--speed", "0.05", "--particles",
               "10000", "--iterations", "100000", "-o", tmp_path / "t.toml")
    assert_one_line_error(proc, "the tuning's swarm (10000 particles × 100000 iterations on 7 plants)",
                          "fewer --particles or --iterations")
    assert not (tmp_path / "t.toml").exists()
    # the estimate is a bound the user may raise: a search just past a tiny limit runs once it is raised
    proc = run("identify", log, "--structure", "linear_axis", "--closed-loop", DRIVE, "--iterations",
               "3000", "--work-limit", "1e-6", "-o", out)
    assert_one_line_error(proc, "the search (10 particles × 3000 iterations")
