"""The closed loop: controller files and FMUs, systems of FMUs in SSP, co-simulation on libcosim and FMPy against a
reference written here, closed-loop identification and friction compensation."""
from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from scipy import signal
from scipy.integrate import solve_ivp

import servofmu as sf
from servofmu.control.cosim import cosimulate
from servofmu.identification.prior import identified_mask
from servofmu.model.controller import controller_from_dict, load_controller
from servofmu.model.plant import example_files
from servofmu.simulation.closed_loop import LoopSimulator

TS = 1e-3
# fmu_models/axis_controller.toml's values, written here by hand: the Python reference loop below must not take its
# gains from servofmu's own parser, which would then go unchecked (encoder quantisation off, as in exact()).
AXIS_CONTROLLER = {"sample_time": 1e-3, "delay": 1, "kp_position": 40.0, "kp_velocity": 18850.0,
                   "ki_velocity": 710000.0, "velocity_filter": 0.0, "velocity_feedforward": 1.0,
                   "mass_feedforward": 100.0, "force_limit": 3000.0, "encoder_resolution": 0.0}


def exact(name="axis_controller"):
    """The example controller without encoder quantisation."""
    return load_controller(name).with_values(encoder_resolution=0.0)


def write_reference(path, duration=2.0):
    """A reference from rest at 0 with velocity reversals."""
    t = np.arange(0.0, duration + TS / 2, TS)
    x = 0.03 * (1 - np.cos(2 * np.pi * 0.5 * t)) + 0.01 * (1 - np.cos(2 * np.pi * 2.3 * t))
    np.savetxt(path, np.column_stack([t, x]), delimiter=",", header="time,position", comments="")
    return path


@pytest.fixture(scope="module")
def axis(tmp_path_factory):
    """linear_axis and the exact example controller as FMI 2.0 FMUs, and their system on a 2 s reference."""
    folder = tmp_path_factory.mktemp("axis")
    ctrl = folder / "ctrl.toml"
    ctrl.write_text(example_files()["axis_controller"].read_text()
                    .replace("resolution = 1e-6", "resolution = 0.0"))
    for args in (("build", "linear_axis", "--fmi-version", "2", "-o", folder / "plant.fmu"),
                 ("controller", ctrl, "--fmi-version", "2", "-o", folder / "ctrl.fmu"),
                 ("system", folder / "plant.fmu", folder / "ctrl.fmu", "--reference",
                  write_reference(folder / "ref.csv"), "-o", folder / "axis.ssp")):
        proc = run(*args)
        assert proc.returncode == 0, proc.stderr
    return {"folder": folder, "ssp": folder / "axis.ssp", "ctrl": ctrl}


# ---------------------------------------------------------------------------
# Controller files and FMUs
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("version", [3, 2])
def test_controller_fmus_pass_fmpy_validation(tmp_path, version):
    from fmpy.validation import validate_fmu

    proc = run("controller", "axis_controller", "--fmi-version", version, "-o", tmp_path / "c.fmu")
    assert proc.returncode == 0, proc.stderr
    assert validate_fmu(str(tmp_path / "c.fmu")) == []


@pytest.mark.parametrize("text, fragment", [
    ('sample_time = -0.001\n[velocity]\nkp = 1.0\n', "sample_time"),
    ('sample_time = 1e-300\n[velocity]\nkp = 1.0\n', "sample_time: must be in [1e-06, 1]"),
    ('sample_time = 0.001\nspeed = 3\n[velocity]\nkp = 1.0\n', "speed: unknown key"),
    ('sample_time = 0.001\n[velocity]\nkp = 1.0\nfilter = "kalman"\n', "velocity.filter"),
    ('sample_time = 0.001\n', "velocity.kp: missing"),
])
def test_bad_controller_files_are_one_line_errors(tmp_path, text, fragment):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    out = tmp_path / "c.fmu"
    assert_one_line_error(run("controller", path, "-o", out), "bad.toml", fragment)
    assert not out.exists()


def test_example_controller_file_is_read_as_written():
    spec = load_controller("axis_controller")
    assert spec["encoder_resolution"] == 1e-6
    for name, value in AXIS_CONTROLLER.items():
        if name != "encoder_resolution":
            assert spec[name] == value, name


def test_controller_file_round_trip():
    spec = controller_from_dict({"sample_time": 0.002, "delay": 2, "velocity": {"kp": 5.0, "filter":
                                                                                 "moving-average", "window": 3}})
    assert spec["sample_time"] == 0.002 and spec["delay"] == 2 and spec["velocity_filter"] == 1.0
    assert spec["filter_window"] == 3 and spec["kp_velocity"] == 5.0 and spec["kp_position"] == 0.0


# ---------------------------------------------------------------------------
# Co-simulation against an independent reference
# ---------------------------------------------------------------------------
class PythonController:
    """The cascade of docs/control.md stepped in Python, written from the documentation."""

    def __init__(self, p):
        self.p, self.k, self.r_prev, self.v_prev, self.integral = p, 0, 0.0, 0.0, 0.0
        self.history, self.queue = [], [0.0] * (int(p["delay"]) - 1)

    def sample(self, r, x):
        p, ts = self.p, self.p["sample_time"]
        y = x
        if self.k == 0:
            self.r_prev, self.history = r, [y] * 70
        v_ref = (r - self.r_prev) / ts
        a_ref = 0.0 if self.k == 0 else (v_ref - self.v_prev) / ts
        v_hat = (y - self.history[-1]) / ts  # the example's filter is "none"
        self.history.append(y)
        e = p["kp_position"] * (r - y) + p["velocity_feedforward"] * v_ref - v_hat
        integral = self.integral + p["ki_velocity"] * ts * e
        f = p["kp_velocity"] * e + p["mass_feedforward"] * a_ref
        if abs(f + integral) > p["force_limit"]:
            integral = self.integral
        u = min(max(f + integral, -p["force_limit"]), p["force_limit"])
        self.integral, self.r_prev, self.v_prev, self.k = integral, r, v_ref, self.k + 1
        self.queue.append(u)  # what leaves the delay line is applied from the next sample on
        return self.queue.pop(0)


def python_reference(time, reference, plant, p):
    """The loop: the discrete controller (parameters ``p`` by name) in Python, the plant between samples by scipy's
    Radau (rtol 1e-10), the force computed at t_k applied from t_k+1 on (delay 1)."""
    law = PythonController(p)
    A, B, C, _ = signal.zpk2ss([], [z for z in plant.all_poles()], plant.numerator_gain())
    fr = plant.friction
    z, position, force, applied = np.zeros(A.shape[0] + 1), [], [], 0.0
    for k, (t, r) in enumerate(zip(time, reference)):
        position.append(z[-1])
        force.append(applied)
        next_force = law.sample(r, z[-1])
        if k + 1 < time.size:
            def rhs(_, s, u=applied):
                v = float(C[0] @ s[:-1])
                th = np.tanh(v / fr.v_smooth)
                friction = fr.fc_pos * max(th, 0.0) + fr.fc_neg * min(th, 0.0) + fr.fv * v
                return np.concatenate([A @ s[:-1] + B[:, 0] * (u - friction), [v]])
            sol = solve_ivp(rhs, (t, time[k + 1]), z, method="Radau", rtol=1e-10, atol=1e-14)
            z = sol.y[:, -1]
        applied = next_force
    return np.array(position), np.array(force)


def test_libcosim_and_fmpy_agree_and_match_a_python_reference(axis):
    results = {engine: cosimulate(axis["ssp"], engine=engine) for engine in ("libcosim", "fmpy")}
    a, b = results["libcosim"], results["fmpy"]
    for name in ("position", "force_command", "v", "reference"):
        assert np.max(np.abs(a[name] - b[name])) <= 1e-9 * np.max(np.abs(a[name])), name
    position, force = python_reference(a.time, a["reference"], sf.load_plant("linear_axis"), AXIS_CONTROLLER)
    assert np.max(np.abs(a["position"] - position)) <= 1e-6 * np.max(np.abs(position))
    assert np.max(np.abs(a["force_command"] - force)) <= 1e-6 * np.max(np.abs(force))
    # the batch simulator's loop is the same loop
    loop = LoopSimulator(sf.load_plant("linear_axis")).simulate_loop(
        sf.load_plant("linear_axis").parameter_vector()[None], a.time, a["reference"], exact(), rtol=1e-10)
    assert np.max(np.abs(loop.position[0] - a["position"])) <= 1e-9 * np.max(np.abs(a["position"]))
    assert np.max(np.abs(loop.command[0] - a["force_command"])) <= 1e-6 * np.max(np.abs(a["force_command"]))


def test_the_ssp_is_standard(axis, tmp_path):
    """FMPy's SSP reader reads the archive, validating it against the SSP 1.0 schema, and finds the connections."""
    from fmpy.ssp.ssd import read_ssd

    ssd = read_ssd(str(axis["ssp"]), validate=True)
    names = {c.name for c in ssd.system.elements}
    assert names == {"reference", "controller", "plant"}
    ends = {(c.startElement, c.startConnector, c.endElement, c.endConnector) for c in ssd.system.connections}
    assert ("controller", "force", "plant", "u") in ends and ("plant", "position", "controller", "position") in ends


# ---------------------------------------------------------------------------
# Closed-loop identification
# ---------------------------------------------------------------------------
def truth(name):
    plant = sf.load_plant(name)
    return plant.parameter_vector()[identified_mask(plant)]


@pytest.mark.parametrize("name", ["linear_axis", "stribeck_axis"])
def test_closed_loop_identification_is_exact_on_noise_free_records(axis, tmp_path, name):
    folder = axis["folder"]
    plant_fmu = tmp_path / "plant.fmu"
    assert run("build", name, "--fmi-version", "2", "-o", plant_fmu).returncode == 0
    assert run("system", plant_fmu, folder / "ctrl.fmu", "--reference", folder / "ref.csv",
               "-o", tmp_path / "a.ssp").returncode == 0
    proc = run("cosim", tmp_path / "a.ssp", "--engine", "fmpy", "-o", tmp_path / "rec.h5")
    assert proc.returncode == 0, proc.stderr
    proc = run("identify", tmp_path / "rec.h5", "--structure", name, "--closed-loop", axis["ctrl"], "--json",
               "-o", tmp_path / "r.h5")
    assert proc.returncode == 0, proc.stderr
    result = sf.read_result(tmp_path / "r.h5")
    assert np.max(np.abs(result.theta / truth(name) - 1)) < 1e-6
    assert all(fit > 99.999 for fit in json.loads(proc.stdout)["fit_percent"].values())


def test_closed_loop_identification_with_an_encoder_and_actuator_noise(axis, tmp_path):
    """1 µm encoder and actuator noise of about 40 dB: within 1 %, the intervals covering the truth."""
    folder = axis["folder"]
    assert run("controller", "axis_controller", "--fmi-version", "2", "-o", tmp_path / "c.fmu").returncode == 0
    assert run("system", folder / "plant.fmu", tmp_path / "c.fmu", "--reference", folder / "ref.csv",
               "--force-noise", "1.5", "--seed", "4", "-o", tmp_path / "a.ssp").returncode == 0
    assert run("cosim", tmp_path / "a.ssp", "-o", tmp_path / "rec.h5").returncode == 0
    proc = run("identify", tmp_path / "rec.h5", "--structure", "linear_axis", "--closed-loop", "axis_controller",
               "-o", tmp_path / "r.h5")
    assert proc.returncode == 0, proc.stderr
    result = sf.read_result(tmp_path / "r.h5")
    true = truth("linear_axis")
    assert np.max(np.abs(result.theta / true - 1)) < 0.01
    assert np.all((result.intervals[:, 0] <= true) & (true <= result.intervals[:, 1]))


def test_friction_compensation_lowers_the_tracking_error(axis, tmp_path):
    """The identified friction (here: the truth's, 1 % off) fed forward lowers the RMS tracking error on the
    reversals several times, as much as the true friction does."""
    result = tmp_path / "r.h5"
    plant = sf.load_plant("linear_axis")
    from servofmu.identification.results import Result, write_result

    theta = truth("linear_axis") * np.array([1.0, 1.0, 1.01, 0.99])
    write_result(result, Result("pso", plant, plant.with_parameters(
        np.array([-2.0, 0.01, theta[2], theta[3], 0.0, 1e-4])), ("pole1", "gain", "fc_pos", "fc_neg"), theta,
        np.stack([theta, theta], axis=1), 0.0, 0.0, 0, (), np.zeros(0), {}))
    proc = run("compensate", result, "--axis", axis["ssp"], "--truth", "linear_axis", "--engine", "fmpy", "--json",
               "-o", tmp_path / "c.html")
    assert proc.returncode == 0, proc.stderr
    obj = json.loads(proc.stdout)
    assert obj["rms_reduction"] > 5 and abs(obj["identified_over_true"] - 1) < 0.1
    assert "friction" in (tmp_path / "c.html").read_text()


def test_fmpys_folders_go_with_the_run_when_it_fails(axis, tmp_path, monkeypatch):
    """FMPy extracts the SSP into folders of its own and removes them only after a normal end; a run that fails
    inside FMPy leaves none behind."""
    import tempfile

    import fmpy
    import fmpy.ssp.simulation

    def failing(path, **kwargs):
        fmpy.extract(path)  # what FMPy does first, into tempfile's folder
        raise RuntimeError("an FMU failed")

    monkeypatch.setattr(fmpy.ssp.simulation, "simulate_ssp", failing)
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    monkeypatch.setattr(tempfile, "tempdir", None)
    (tmp_path / "tmp").mkdir()
    with pytest.raises(sf.UserError, match="fmpy failed: an FMU failed"):
        cosimulate(axis["ssp"], engine="fmpy")
    assert list((tmp_path / "tmp").iterdir()) == []


# ---------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------
def test_bad_systems_and_runs_are_one_line_errors(axis, tmp_path, built_fmu):
    folder = axis["folder"]
    # an SSP that names a missing FMU
    broken = tmp_path / "broken.ssp"
    with zipfile.ZipFile(axis["ssp"]) as src, zipfile.ZipFile(broken, "w") as dst:
        for item in src.infolist():
            if item.filename != "resources/plant.fmu":
                dst.writestr(item, src.read(item.filename))
    out = tmp_path / "rec.h5"
    assert_one_line_error(run("cosim", broken, "-o", out), "broken.ssp", "missing FMU")
    assert not out.exists()
    # a connection to a connector the plant does not have: refused on both engines before any run (FMPy alone
    # would run it, the plant never receiving the force)
    for end, fragment in (('endConnector="uu"', "plant.uu"), ('startConnector="force" endElement="plant" '
                                                             'endConnector="u"', "does not connect"),
                          ('endConnector="v"', "an input")):
        miswired = tmp_path / "miswired.ssp"
        with zipfile.ZipFile(axis["ssp"]) as src, zipfile.ZipFile(miswired, "w") as dst:
            for item in src.infolist():
                data = src.read(item.filename)
                if item.filename == "SystemStructure.ssd":
                    text = data.decode()
                    assert 'endConnector="u"' in text
                    if "startConnector" in end:
                        text = text.replace('startConnector="force" endElement="plant" endConnector="u"',
                                            'startConnector="force" endElement="controller" endConnector="position"')
                    else:
                        text = text.replace('endConnector="u"', end)
                    data = text.encode()
                dst.writestr(item, data)
        for engine in ("fmpy", "libcosim"):
            assert_one_line_error(run("cosim", miswired, "--engine", engine, "-o", out), "miswired.ssp", fragment)
            assert not out.exists()
    # an FMI 3.0 plant cannot join a system run by libcosim
    assert_one_line_error(run("system", built_fmu("linear_axis", 3), folder / "ctrl.fmu", "--reference",
                              folder / "ref.csv", "-o", tmp_path / "x.ssp"), "FMI 2.0")
    # records without a reference cannot be identified in the loop
    t = np.arange(0, 1, TS)
    np.savetxt(tmp_path / "open.csv", np.column_stack([t, np.sin(t), np.cos(t)]), delimiter=",",
               header="t,u,x", comments="")
    assert run("import", tmp_path / "open.csv", "--time", "t", "--input", "u", "--output-variable", "x", "--kind", "position",
               "-o", tmp_path / "open.h5").returncode == 0
    assert_one_line_error(run("identify", tmp_path / "open.h5", "--structure", "linear_axis", "--closed-loop",
                              axis["ctrl"], "-o", tmp_path / "r.h5"), "no reference")
    assert not (tmp_path / "r.h5").exists()
