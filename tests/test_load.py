"""Forces on the load besides friction (a plant file's [load] section: offset, spring, ripple), through the whole
pipeline, against references written here without the package:

- the FMUs (FMPy, FMI 2 and 3, Model Exchange and Co-Simulation) and the batch simulator (record and sine tasks)
  against scipy's Radau on the equations of docs/model.md;
- the smoothed friction at rest and in breakaway against a true stick–slip solution (an event-based Karnopp
  integration: the axis holds any net force up to the static friction with v = 0 exactly), within the tolerance
  docs/model.md states;
- identification of every term from noise-free open-loop records, stepped sines and closed-loop records;
- the export round trip and the plant file's errors.
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import scipy.io
from clitools import assert_one_line_error, run
from fmpy import read_model_description, simulate_fmu
from scipy import signal
from scipy.integrate import solve_ivp
from stick_slip import stick_slip

import servofmu as sf
from servofmu.errors import ServofmuWarning
from servofmu.identification.criterion import RecordData, RecordSeries, SineData
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.identification.results import Result, write_result
from servofmu.model.plant import plant_from_dict
from servofmu.simulation.batch import BatchSimulator, SteadyStateOptions

COULOMB = {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}
LOAD = {"offset": 0.15, "stiffness": 4.0, "x0": 0.02, "ripple_amplitude": 0.1, "ripple_period": 0.03,
        "ripple_phase": 0.4}


def plant(load, friction=COULOMB, poles=(-10.0,), dc_gain=1.0, name="loaded"):
    return plant_from_dict({"name": name, "linear": {"poles": [[p, 0.0] for p in poles], "dc_gain": dc_gain},
                            "friction": friction, "load": load})


# ---------------------------------------------------------------------------
# The equations written out again (docs/model.md), integrated by scipy's Radau
# ---------------------------------------------------------------------------
def load_force(x, load):
    out = load.get("offset", 0.0) - load.get("stiffness", 0.0) * (x - load.get("x0", 0.0))
    if "ripple_amplitude" in load:
        out += load["ripple_amplitude"] * np.sin(2 * np.pi * x / load["ripple_period"] + load.get("ripple_phase", 0.0))
    return out


def radau(poles, dc_gain, fr, load, t, u_of_t, max_step=np.inf):
    """v and position of G(s) = dc_gain·∏(−p)/∏(s − p) driven by u(t) − F(v) + L(x), from rest."""
    k = dc_gain * np.prod([-p for p in poles])
    A, B, C, _ = signal.zpk2ss([], list(poles), k)
    n = A.shape[0]

    def friction(v):
        th = np.tanh(v / fr.get("v_smooth", 1e-3))
        return fr["fc_pos"] * max(th, 0.0) + fr["fc_neg"] * min(th, 0.0) + fr.get("fv", 0.0) * v

    def rhs(time, s):
        v = float(C[0] @ s[:n])
        return np.concatenate([A @ s[:n] + B[:, 0] * (u_of_t(time) - friction(v) + load_force(s[n], load)), [v]])

    def jac(time, s):
        v, x, h = float(C[0] @ s[:n]), s[n], 1e-7
        J = np.zeros((n + 1, n + 1))
        J[:n, :n] = A - np.outer(B[:, 0], C[0]) * (friction(v + h) - friction(v - h)) / (2 * h)
        J[:n, n] = B[:, 0] * (load_force(x + h, load) - load_force(x - h, load)) / (2 * h)
        J[n, :n] = C[0]
        return J

    sol = solve_ivp(rhs, (t[0], t[-1]), np.zeros(n + 1), method="Radau", t_eval=t, rtol=1e-10, atol=1e-13, jac=jac,
                    max_step=max_step)
    assert sol.success, sol.message
    return (C @ sol.y[:n]).ravel(), sol.y[n]


STOP, INTERVAL, AMPLITUDE, FREQUENCY = 4.0, 0.01, 0.8, 1.0


@pytest.fixture(scope="module")
def loaded_reference():
    t = np.linspace(0.0, STOP, int(round(STOP / INTERVAL)) + 1)
    v, x = radau((-10.0,), 1.0, COULOMB, LOAD, t, lambda s: AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * s))
    assert np.ptp(x) > 2 * LOAD["ripple_period"]  # the ripple is crossed, not sampled at one place
    return t, v, x


@pytest.mark.parametrize("version", [3, 2])
def test_the_fmus_match_radau_with_offset_spring_and_ripple(tmp_path, loaded_reference, version):
    t, v_ref, x_ref = loaded_reference
    fmu = sf.build_fmu(plant(LOAD), tmp_path / "loaded.fmu", fmi_version=version)
    starts = {"excitation_amplitude": AMPLITUDE, "excitation_frequency": FREQUENCY}
    me = simulate_fmu(str(fmu), fmi_type="ModelExchange", stop_time=STOP, output_interval=INTERVAL,
                      relative_tolerance=1e-12, start_values=starts, output=["v", "position"])
    cs = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=STOP, output_interval=INTERVAL,
                      start_values=starts, output=["v", "position"])
    for res, tol in ((me, 1e-7), (cs, 1e-7)):
        assert np.allclose(res["time"], t)
        assert np.abs(res["v"] - v_ref).max() < tol and np.abs(res["position"] - x_ref).max() < tol
    # every term is a tunable parameter of the FMU, with its unit
    variables = {v.name: v for v in read_model_description(str(fmu)).modelVariables}
    for key, value in plant(LOAD).load.values().items():
        assert variables[key].causality == "parameter" and float(variables[key].start) == value
    assert variables["ripple_phase"].declaredType is not None or variables["ripple_phase"].unit == "rad"


def test_a_load_term_set_through_the_fmu_changes_the_motion(tmp_path):
    """The offset set as a start value acts: an FMU of the plant with offset 0 driven with offset 0.3 moves as the
    reference with 0.3 does."""
    t = np.linspace(0.0, 2.0, 201)
    load = {"offset": 0.0, "stiffness": 4.0, "ripple_amplitude": 0.1, "ripple_period": 0.03}
    fmu = sf.build_fmu(plant(load), tmp_path / "p.fmu", fmi_version=3)
    res = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=2.0, output_interval=0.01,
                       start_values={"offset": 0.3, "excitation_amplitude": 0.8, "excitation_frequency": 1.0},
                       output=["v", "position"])
    v_ref, x_ref = radau((-10.0,), 1.0, COULOMB, {**load, "offset": 0.3}, t,
                         lambda s: 0.8 * np.sin(2 * np.pi * s))
    assert np.abs(res["position"] - x_ref).max() < 1e-7 and np.abs(x_ref).max() > 0.05


def test_the_batch_simulator_matches_radau_in_record_and_sine_tasks(loaded_reference):
    t, v_ref, x_ref = loaded_reference
    p = plant(LOAD)
    sim = BatchSimulator(p)
    assert sim.n_states == 2  # v and the position, which acts back through the spring and the ripple
    sine = sim.simulate_sine(p.parameter_vector()[None], t, AMPLITUDE, FREQUENCY, rtol=1e-10)
    record = sim.simulate_record(p.parameter_vector()[None], t, AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * t),
                                 hold="foh", rtol=1e-10)
    assert np.abs(sine.v[0] - v_ref).max() < 1e-7 and np.abs(sine.position[0] - x_ref).max() < 1e-7
    # the record's input linear between its samples, in the reference too (its first 2 s)
    u, early = AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * t), t <= 2.0
    v_foh, x_foh = radau((-10.0,), 1.0, COULOMB, LOAD, t[early], lambda s: np.interp(s, t, u), max_step=INTERVAL)
    assert np.abs(record.v[0, early] - v_foh).max() < 1e-7 and np.abs(record.position[0, early] - x_foh).max() < 1e-7
    # the stepped sine's steady state: the spring holds the axis, so the period closes
    features = sim.steady_state(p.parameter_vector()[None], [0.8, 2.0], [1.0, 3.0], SteadyStateOptions(rtol=1e-9))
    assert features.converged.all()
    T = 1.0 / 3.0
    t_long = np.concatenate([[0.0], np.linspace(10 * T, 11 * T, 401)])  # the transient decays as exp(−5 t)
    v_long, _ = radau((-10.0,), 1.0, COULOMB, LOAD, t_long, lambda s: 2.0 * np.sin(2 * np.pi * 3.0 * s))
    last = t_long >= 10 * T
    s1 = 1j * 2 / T * np.trapezoid(v_long[last] * np.exp(-1j * 2 * np.pi * 3.0 * t_long[last]), t_long[last])
    assert abs(features.H[0, 1] - s1 / 2.0) < 1e-5 * abs(s1 / 2.0)


# ---------------------------------------------------------------------------
# At rest and in breakaway: a true stick–slip reference
# ---------------------------------------------------------------------------
# G = 10/(s + 10): a mass m = 1/K = 0.1 kg with viscous damping c = −p/K = 1 N·s/m; v_smooth = 1e-3 m/s
M, C_VISC, V_SMOOTH = 0.1, 1.0, 1e-3


def test_at_rest_the_creep_stays_within_the_documented_bound():
    """|u + offset| < Fs: the stick–slip reference stays at x = 0; the smoothed model creeps at no more than
    v_smooth·atanh(|u + offset|/Fs) (docs/model.md), and at about that (the bound is what it does)."""
    t = np.linspace(0.0, 3.0, 301)
    offsets = np.array([0.3, -0.3, 0.45, -0.36])
    p = plant({"offset": 0.3})
    params = np.tile(p.parameter_vector(), (offsets.size, 1))
    params[:, p.parameter_names().index("offset")] = offsets
    r = BatchSimulator(p).simulate_record(params, t, np.zeros_like(t), rtol=1e-10)
    for i, offset in enumerate(offsets):
        x_ref, v_ref = stick_slip(M, C_VISC, 0.5, 0.4, lambda s: 0.0, lambda x, f=offset: f, t)
        assert np.all(x_ref == 0.0) and np.all(v_ref == 0.0)
        bound = V_SMOOTH * np.arctanh(abs(offset) / (0.5 if offset > 0 else 0.4))
        assert np.abs(r.v[i]).max() <= bound * (1 + 1e-6)
        assert abs(r.v[i, -1]) > 0.95 * bound
        assert np.abs(r.position[i] - x_ref).max() <= bound * t[-1]


def test_breakaway_under_a_ramp_agrees_with_the_stick_slip_solution():
    """offset 0.3 N, then u rising at 0.1 N/s: the reference breaks away at t = 2 s (u + offset = Fs = 0.5 N).
    The smoothed model stays within 3·v_smooth of the reference's velocity throughout — stuck, breaking away and
    sliding — and its position within that velocity times the time."""
    t = np.linspace(0.0, 4.0, 4001)
    x_ref, v_ref = stick_slip(M, C_VISC, 0.5, 0.4, lambda s: 0.1 * s, lambda x: 0.3, t)
    assert np.all(v_ref[t < 1.999] == 0.0) and np.all(v_ref[t > 2.001] > 0.0) and x_ref[-1] > 0.15
    p = plant({"offset": 0.3})
    r = BatchSimulator(p).simulate_record(p.parameter_vector()[None], t, 0.1 * t, hold="foh", rtol=1e-10)
    assert np.abs(r.v[0] - v_ref).max() <= 3 * V_SMOOTH
    assert np.abs(r.position[0] - x_ref).max() <= 3 * V_SMOOTH * t[-1]
    # sliding, the two agree to far better than v_smooth once the smoothing's transient is over
    late = t > 3.0
    assert np.abs(r.v[0, late] - v_ref[late]).max() < 1e-3 * V_SMOOTH


def test_stick_slip_on_a_spring_agrees_with_the_stick_slip_solution(tmp_path):
    """A sine against a spring: the axis sticks at every reversal (38 % of the time); the FMU (Co-Simulation)
    stays within 3·v_smooth of the reference's velocity, and its position within 1 % of the stroke."""
    t = np.linspace(0.0, 4.0, 401)
    load = {"offset": 0.1, "stiffness": 20.0, "x0": 0.0}
    x_ref, v_ref = stick_slip(M, C_VISC, 0.5, 0.4, lambda s: 1.2 * np.sin(np.pi * s),
                              lambda x: load_force(x, load), t)
    stuck = v_ref == 0.0
    assert 0.2 < stuck.mean() < 0.6
    fmu = sf.build_fmu(plant(load), tmp_path / "spring.fmu", fmi_version=3)
    res = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=4.0, output_interval=0.01,
                       start_values={"excitation_amplitude": 1.2, "excitation_frequency": 0.5},
                       output=["v", "position"])
    assert np.abs(res["v"] - v_ref).max() <= 3 * V_SMOOTH
    assert np.abs(res["position"] - x_ref).max() <= 0.01 * np.ptp(x_ref)


def test_lugre_holds_the_axis_at_rest():
    """LuGre's bristles hold a constant force below the static level: the axis comes to rest (no creep) after a
    presliding displacement of the order of F/sigma0."""
    fr = {"model": "lugre", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.4, "fs_neg": 0.3, "vs": 0.05,
          "sigma0": 1000.0, "sigma1": 5.0}
    t = np.linspace(0.0, 20.0, 2001)
    p = plant({"offset": 0.28}, friction=fr)
    r = BatchSimulator(p).simulate_record(p.parameter_vector()[None], t, np.zeros_like(t), rtol=1e-10)
    x = r.position[0]
    assert abs(x[-1] - x[500]) < 1e-9 and abs(r.v[0, -1]) < 1e-9
    assert 0.28 / 1000.0 < x[-1] < 0.28 / 1000.0 / (1 - 0.28 / 0.4) * 1.5


# ---------------------------------------------------------------------------
# Identification
# ---------------------------------------------------------------------------
def perturbed(truth, factor=1.3, period_factor=1.005, phase_shift=0.5):
    values = []
    for name, value in truth.parameters().items():
        if name == "ripple_period":
            value *= period_factor
        elif name == "ripple_phase":
            value += phase_shift
        elif name in identified_names(truth):
            value *= factor
        values.append(value)
    return truth.with_parameters(values)


def test_open_loop_records_identify_offset_spring_and_ripple():
    """Velocity and position records (noise-free, zero-order hold, 100 Hz) of a plant with all three terms: the
    swarm from a structure 30 % off (the ripple's period 0.5 % off) finds every parameter."""
    truth = plant({"offset": 0.2, "stiffness": 8.0, "ripple_amplitude": 0.3, "ripple_period": 0.05,
                   "ripple_phase": 0.5})
    t = np.arange(0.0, 8.0 + 0.005, 0.01)
    u = np.where(t < 4, 2.0 * np.sin(2 * np.pi * 0.5 * t), 0.9 * np.sin(2 * np.pi * 1.0 * t))
    r = BatchSimulator(truth).simulate_record(truth.parameter_vector()[None], t, u)
    fitted = np.ones(t.size, bool)
    data = RecordData((RecordSeries("v", t, u, r.v[0], "v", "zoh", fitted),
                       RecordSeries("x", t, u, r.position[0], "position", "zoh", fitted)), "records")
    est = sf.PSOANNIdentifier(perturbed(truth), method="pso", seed=1).fit(data)
    true = truth.parameter_vector()[identified_mask(truth)]
    assert est.names_ == ["pole1", "dc_gain", "fc_pos", "fc_neg", "offset", "stiffness", "ripple_amplitude",
                          "ripple_period", "ripple_phase"]  # x0 fixed beside an offset: k·x0 is an offset
    assert np.max(np.abs(est.theta_ - true) / np.maximum(np.abs(true), 0.1)) < 1e-5


def test_stepped_sines_identify_the_spring_but_do_not_see_x0():
    """Stepped-sine first harmonics and mean velocities: the spring's stiffness and the friction are found; x0 is
    not seen at all (docs/identification.md: fit it from records with the position)."""
    truth = plant({"stiffness": 8.0, "x0": 0.05})
    amps, freqs = np.array([2.0, 2.0, 2.0, 0.6, 0.6, 0.6]), np.array([0.5, 2.0, 10.0, 0.5, 2.0, 10.0])
    f = BatchSimulator(truth).steady_state(truth.parameter_vector()[None], amps, freqs, SteadyStateOptions(rtol=1e-9))
    assert f.converged.all() and np.abs(f.dc).max() < 1e-12  # a spring holds the mean velocity at zero
    data = SineData(amps, freqs, f.H[0], f.dc[0], False, "sines", 0)
    with warnings.catch_warnings():  # a fit whose residuals cannot all vanish may warn of the noise floor
        warnings.simplefilter("ignore", ServofmuWarning)
        est = sf.PSOANNIdentifier(perturbed(truth), method="pso", seed=1).fit(data)
    names = list(est.names_)
    assert abs(est.theta_[names.index("stiffness")] / 8.0 - 1) < 1e-2
    fc_sum = est.theta_[names.index("fc_pos")] + est.theta_[names.index("fc_neg")]
    assert abs(fc_sum / 0.9 - 1) < 1e-2
    assert abs(est.theta_[names.index("fc_pos")] / 0.5 - 1) < 1e-2
    # x0 (or an offset) only moves the periodic orbit's mean position, which a stepped sine does not measure:
    # the velocity's harmonics are the same for any x0
    other = truth.with_parameters([0.3 if n == "x0" else v for n, v in truth.parameters().items()])
    g = BatchSimulator(truth).steady_state(other.parameter_vector()[None], amps, freqs, SteadyStateOptions(rtol=1e-9))
    assert np.abs(g.H - f.H).max() < 1e-7 * np.abs(f.H).max()


def test_closed_loop_records_identify_the_inclined_axis(tmp_path):
    """inclined_axis (gravity, a cable carrier, cogging) in the example drive's loop, co-simulated by FMPy; the
    closed-loop identification from the structure 30 % off recovers every term."""
    from servofmu.model.plant import example_files

    ctrl = tmp_path / "ctrl.toml"
    ctrl.write_text(example_files()["axis_controller"].read_text().replace("resolution = 1e-6", "resolution = 0.0"))
    t = np.arange(0.0, 2.0 + 5e-4, 1e-3)
    x = 0.03 * (1 - np.cos(2 * np.pi * 0.5 * t)) + 0.01 * (1 - np.cos(2 * np.pi * 2.3 * t))
    np.savetxt(tmp_path / "ref.csv", np.column_stack([t, x]), delimiter=",", header="time,position", comments="")
    truth = sf.load_plant("inclined_axis")
    structure = perturbed(truth, period_factor=1.002)
    (tmp_path / "structure.toml").write_text(structure.to_toml())
    for args in (("build", "inclined_axis", "--fmi-version", "2", "-o", tmp_path / "plant.fmu"),
                 ("controller", ctrl, "--fmi-version", "2", "-o", tmp_path / "ctrl.fmu"),
                 ("system", tmp_path / "plant.fmu", tmp_path / "ctrl.fmu", "--reference", tmp_path / "ref.csv",
                  "-o", tmp_path / "axis.ssp"),
                 ("cosim", tmp_path / "axis.ssp", "--engine", "fmpy", "-o", tmp_path / "rec.h5"),
                 ("identify", tmp_path / "rec.h5", "--structure", tmp_path / "structure.toml", "--closed-loop", ctrl,
                  "-o", tmp_path / "r.h5")):
        proc = run(*args)
        assert proc.returncode == 0, proc.stderr
    # the batch simulator's loop is the co-simulated loop of the FMUs
    from servofmu.identification.closed_loop import closed_loop_data
    from servofmu.measurement.datafile import read_data_file
    from servofmu.model.controller import load_controller
    from servofmu.simulation.closed_loop import LoopSimulator

    controller = load_controller(ctrl)
    (series,) = closed_loop_data(read_data_file(tmp_path / "rec.h5"), controller).records
    loop = series.simulate(LoopSimulator(truth), truth.parameter_vector()[None], controller, rtol=1e-10)
    assert np.abs(loop.position[0] - series.position).max() <= 1e-8 * np.abs(series.position).max()
    result = sf.read_result(tmp_path / "r.h5")
    true = truth.parameter_vector()[identified_mask(truth)]
    assert "offset" in result.names and "ripple_period" in result.names
    assert np.max(np.abs(result.theta - true) / np.abs(true)) < 1e-4


# ---------------------------------------------------------------------------
# Export and errors
# ---------------------------------------------------------------------------
def loaded_result(tmp_path):
    p = plant(LOAD)
    names = tuple(identified_names(p))
    theta = p.parameter_vector()[identified_mask(p)]
    path = tmp_path / "r.h5"
    write_result(path, Result("pso", p, p, names, theta, np.stack([theta, theta], axis=1), 0.0, 0.0, 0, (),
                              np.zeros(0), {}))
    return p, path


def test_every_export_format_carries_the_load(tmp_path):
    p, path = loaded_result(tmp_path)
    for fmt in ("toml", "json", "mat", "control", "fmu"):
        proc = run("export", path, "--format", fmt, "-o", tmp_path / f"out.{fmt}")
        assert proc.returncode == 0, proc.stderr
    back = sf.load_plant(tmp_path / "out.toml")
    assert back.load == p.load and np.array_equal(back.parameter_vector(), p.parameter_vector())
    doc = json.loads((tmp_path / "out.json").read_text())
    assert {k: doc["plant_parameters"][k] for k in LOAD} == LOAD and "[load]" in doc["plant_toml"]
    assert doc["parameters"]["load"] == LOAD
    mat = scipy.io.loadmat(tmp_path / "out.mat", squeeze_me=True)
    assert {k: float(mat["load"][k]) for k in LOAD} == LOAD
    control = json.loads((tmp_path / "out.control").read_text())
    assert control["load"] == LOAD and "L(x)" in control["about"]
    variables = {v.name: v for v in read_model_description(str(tmp_path / "out.fmu")).modelVariables}
    assert {k: float(variables[k].start) for k in LOAD} == LOAD


def test_the_report_lists_the_load(tmp_path):
    p, path = loaded_result(tmp_path)
    t = np.arange(0.0, 2.0 + 0.005, 0.01)
    u = 0.8 * np.sin(2 * np.pi * t)
    r = BatchSimulator(p).simulate_record(p.parameter_vector()[None], t, u)
    np.savetxt(tmp_path / "rec.csv", np.column_stack([t, u, r.position[0]]), delimiter=",", header="t,u,x",
               comments="")
    for args in (("import", tmp_path / "rec.csv", "--time", "t", "--input", "u", "--output-variable", "x", "--kind",
                  "position", "-o", tmp_path / "rec.h5"),
                 ("report", path, "--data", tmp_path / "rec.h5", "-o", tmp_path / "r.html")):
        proc = run(*args)
        assert proc.returncode == 0, proc.stderr
    page = (tmp_path / "r.html").read_text()
    assert "Load: constant force 0.15 N; spring 4 N/m about x0 = 0.02 m; ripple 0.1 N of period 0.03 m" in page
    assert "ripple_phase" in page and "N/m" in page


GOOD = '''name = "bad"
[linear]
poles = [[-10.0, 0.0]]
dc_gain = 1.0
[friction]
model = "coulomb"
fc_pos = 0.5
fc_neg = 0.4
'''


@pytest.mark.parametrize("section, key, message", [
    ('offset = "heavy"', "load.offset", "must be a finite number"),
    ("ripple_amplitude = 0.1\nripple_period = -0.01", "load.ripple_period", "must be positive"),
    ("ripple_amplitude = 0.1", "load.ripple_period", "missing"),
    ("ripple_phase = 0.3", "load.ripple_phase", "ripple_amplitude"),
    ("x0 = 0.1", "load.x0", "stiffness"),
    ("stiffness = -3.0", "load.stiffness", "must not be negative"),
    ("gravity = 9.81", "load.gravity", "unknown key"),
])
def test_a_bad_load_is_refused_in_one_line_naming_file_and_key(tmp_path, section, key, message):
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD + "[load]\n" + section + "\n")
    proc = run("build", bad, "-o", tmp_path / "bad.fmu")
    assert_one_line_error(proc, str(bad), key, message)
    assert not (tmp_path / "bad.fmu").exists()


def test_a_plant_without_a_load_is_what_it_was():
    """No [load] (or an empty one): no load parameters, and the position does not act back."""
    import casadi as ca

    from servofmu.model.symbolic import build_model

    for p in (sf.load_plant("g1"), plant({})):
        assert p.parameter_names() == ["pole1", "dc_gain", "fc_pos", "fc_neg", "fv", "v_smooth"]
        model = build_model(p)
        assert not ca.depends_on(model.xdot, model.x[model.state_names.index("position")])
    assert BatchSimulator(plant({})).n_states == 1
