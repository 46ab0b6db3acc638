"""The laws beyond Coulomb, Stribeck and LuGre — direction-dependent viscous friction, Stribeck's shape exponent δ
(for stribeck and lugre) and Dahl — against scipy's Radau on their equations written out again here (docs/friction.md),
through reversals and sticking: the batch simulator in the default suite, the FMUs (FMI 2 and 3, Model Exchange and
Co-Simulation) marked long."""
import functools
import os
from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from servofmu.model.plant import load_plant, plant_from_dict

MODELS = Path(__file__).resolve().parent.parent / "fmu_models"
STOP, SAMPLES, FREQUENCY = 1.5, 151, 1.0  # 1.5 periods of a 1 Hz force: two reversals, each with a stop


def tanh_sign(fr, v):
    return np.tanh(v / fr.get("v_smooth", 1e-3))


def stribeck_levels(fr, v):
    delta = fr.get("delta", 2.0)
    bump = np.exp(-abs(v / fr["vs"]) ** delta)
    return (fr["fc_pos"] + (fr["fs_pos"] - fr["fc_pos"]) * bump, fr["fc_neg"] + (fr["fs_neg"] - fr["fc_neg"]) * bump)


def viscous(fr, v):
    if "fv_pos" in fr:
        return fr["fv_pos"] * max(v, 0.0) + fr["fv_neg"] * min(v, 0.0)
    return fr.get("fv", 0.0) * v


def law(fr, v, z):
    """(F, dz/dt) of the plant-file values ``fr`` — the equations of docs/friction.md, without the package."""
    model = fr["model"]
    if model == "coulomb":
        t = tanh_sign(fr, v)
        return fr["fc_pos"] * max(t, 0.0) + fr["fc_neg"] * min(t, 0.0) + viscous(fr, v), []
    if model == "stribeck":
        t, (g_pos, g_neg) = tanh_sign(fr, v), stribeck_levels(fr, v)
        return g_pos * max(t, 0.0) + g_neg * min(t, 0.0) + viscous(fr, v), []
    if model == "lugre":
        g = stribeck_levels(fr, v)[0 if v >= 0 else 1]
        dz = v - fr["sigma0"] * abs(v) * z[0] / g
        return fr["sigma0"] * z[0] + fr["sigma1"] * dz + viscous(fr, v), [dz]
    if model == "dahl":
        fc = fr["fc_pos"] if v >= 0 else fr["fc_neg"]
        return fr["sigma0"] * z[0] + viscous(fr, v), [v - fr["sigma0"] * abs(v) * z[0] / fc]
    raise AssertionError(model)


def radau(linear, fr, amplitude, frequency, t):
    """v(t) of G(s) (poles, dc_gain) driven by amplitude·sin(2πft) − F."""
    poles = [complex(*p) for p in linear["poles"]]
    k = linear["dc_gain"] * np.real(np.prod([-p for p in poles]))
    A, B, C, _ = signal.zpk2ss([], poles, k)
    n, states = A.shape[0], 1 if fr["model"] in ("lugre", "dahl") else 0

    def rhs(time, s):
        v = float(C[0] @ s[:n])
        force, dz = law(fr, v, s[n:])
        return np.concatenate([A @ s[:n] + B[:, 0] * (amplitude * np.sin(2 * np.pi * frequency * time) - force), dz])

    sol = solve_ivp(rhs, (t[0], t[-1]), np.zeros(n + states), method="Radau", t_eval=t, rtol=1e-10, atol=1e-13)
    assert sol.success, sol.message
    return C[0] @ sol.y[:n]


def plant_file(name, **changes):
    import tomllib

    data = tomllib.loads((MODELS / f"{name}.toml").read_text())
    data["friction"].update(changes)
    return data


CASES = {  # name: (plant file contents, force amplitude (N) — near the breakaway force: the axis sticks)
    "viscous_axis": (plant_file("viscous_axis"), 0.5),
    "stribeck_shaped": (plant_file("stribeck_shaped"), 0.5),
    "lugre_shaped": (plant_file("lugre_servo", delta=1.3), 0.5),
    "dahl_servo": (plant_file("dahl_servo"), 0.4),
}


@functools.lru_cache(maxsize=None)
def reference(case):
    data, amplitude = CASES[case]
    t = np.linspace(0.0, STOP, SAMPLES)
    return t, radau(data["linear"], dict(data["friction"]), amplitude, FREQUENCY, t)


def assert_exact(v, v_ref, rel=1e-7):
    assert np.abs(v_ref).max() > 0.01
    assert np.abs(v - v_ref).max() < rel * np.abs(v_ref).max(), np.abs(v - v_ref).max() / np.abs(v_ref).max()


def assert_reverses_and_sticks(v):
    """The reference moves both ways and stands (nearly) still in between: the case tests reversals and sticking."""
    assert v.max() > 0.01 and v.min() < -0.01
    assert np.sum(np.abs(v) < 1e-2 * np.abs(v).max()) >= 5


@pytest.mark.parametrize("case", ["viscous_axis", "stribeck_shaped", "dahl_servo"])
def test_batch_simulator_matches_radau(case):
    from servofmu.simulation.batch import BatchSimulator

    data, amplitude = CASES[case]
    plant = plant_from_dict(data)
    t, v_ref = reference(case)
    assert_reverses_and_sticks(v_ref)
    response = BatchSimulator(plant, threads=1).simulate_sine(plant.parameter_vector()[None], t, amplitude, FREQUENCY,
                                                              rtol=1e-10)
    assert_exact(response.v[0], v_ref)


@pytest.mark.long
@pytest.mark.skipif(os.environ.get("SERVOFMU_FAULTS") != "all", reason="long: SERVOFMU_FAULTS=all runs it")
@pytest.mark.parametrize("version", [3, 2])
@pytest.mark.parametrize("case", list(CASES))
def test_fmu_matches_radau(case, version, tmp_path):
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    from servofmu.fmu.build import build_fmu

    data, amplitude = CASES[case]
    fmu = str(build_fmu(plant_from_dict(data), tmp_path / f"{case}.fmu", fmi_version=version))
    assert validate_fmu(fmu) == []
    t, v_ref = reference(case)
    starts = {"excitation_amplitude": amplitude, "excitation_frequency": FREQUENCY}
    me = simulate_fmu(fmu, fmi_type="ModelExchange", stop_time=STOP, output_interval=t[1],
                      relative_tolerance=1e-12, start_values=starts, output=["v"])
    cs = simulate_fmu(fmu, fmi_type="CoSimulation", stop_time=STOP, output_interval=t[1],
                      relative_tolerance=1e-12, start_values=starts, output=["v"])
    assert_exact(me["v"], v_ref)
    assert_exact(cs["v"], v_ref)


@pytest.mark.long
@pytest.mark.skipif(os.environ.get("SERVOFMU_FAULTS") != "all", reason="long: SERVOFMU_FAULTS=all runs it")
def test_lugre_with_delta_in_the_batch_simulator_matches_radau():
    test_batch_simulator_matches_radau("lugre_shaped")


def test_without_delta_the_stribeck_curve_is_todays_gaussian_exactly():
    """A plant file without ``delta`` has the parameters, the curve and the generated equations it had before the
    key existed; δ = 2 given is the same curve to rounding."""
    from servofmu.model.friction import steady_friction

    plant = load_plant(MODELS / "stribeck_servo.toml")
    assert "delta" not in plant.parameter_names()
    v = np.linspace(-0.2, 0.2, 41)[np.linspace(-0.2, 0.2, 41) != 0]
    fr = dict(plant.friction.values())
    gaussian = np.where(v > 0, fr["fc_pos"] + (fr["fs_pos"] - fr["fc_pos"]) * np.exp(-(v / fr["vs"]) ** 2),
                        fr["fc_neg"] + (fr["fs_neg"] - fr["fc_neg"]) * np.exp(-(v / fr["vs"]) ** 2))
    t = np.tanh(v / fr["v_smooth"])
    expected = gaussian * np.where(v > 0, t, 0) + gaussian * np.where(v < 0, t, 0) + fr["fv"] * v
    assert np.allclose(steady_friction(plant, v), expected, rtol=1e-14, atol=0)
    with_two = plant_from_dict(plant_file("stribeck_servo", delta=2.0))
    assert np.allclose(steady_friction(with_two, v), expected, rtol=1e-13, atol=0)


def test_direction_dependent_viscous_friction_is_fixed_but_its_difference_identified():
    """fv_pos is kept at the structure's value (a G with free poles absorbs the common part), fv_neg is
    identified: the fit identifies fv_neg − fv_pos."""
    from servofmu.identification.prior import identified_names

    plant = load_plant(MODELS / "viscous_axis.toml")
    names = identified_names(plant)
    assert "fv_neg" in names and "fv_pos" not in names and "fv" not in plant.parameter_names()


@pytest.mark.long
@pytest.mark.skipif(os.environ.get("SERVOFMU_FAULTS") != "all", reason="long: SERVOFMU_FAULTS=all runs it")
@pytest.mark.parametrize("name", ["viscous_axis", "stribeck_shaped", "dahl_servo"])
def test_noise_free_stepped_sines_identify_every_parameter(name, tmp_path):
    """The shipped example of each new law, measured through its FMU without noise: PSO and the polish find every
    identified parameter (fv_neg of the direction-dependent viscous friction, delta, Dahl's sigma0) within 1e-6."""
    import servofmu as sf
    from servofmu.identification.criterion import sine_data
    from servofmu.identification.prior import identified_mask
    from servofmu.identification.results import table_text
    from servofmu.measurement.measure import MeasureOptions
    from servofmu.runtime import RunOptions

    plant = load_plant(MODELS / f"{name}.toml")
    fmu = sf.build_fmu(plant, tmp_path / f"{name}.fmu")
    data = tmp_path / f"{name}.h5"
    sf.measure(fmu, data, options=MeasureOptions(), run=RunOptions(workers=0), amplitudes=[2.0, 0.6],
               frequencies=[0.3, 1.0, 3.0, 10.0])
    est = sf.PSOANNIdentifier(plant, method="pso", seed=1).fit(sine_data(sf.read_data_file(data)))
    truth = plant.parameter_vector()[identified_mask(plant)]
    assert np.max(np.abs(est.theta_ / truth - 1)) < 1e-6, dict(zip(est.result().names, est.theta_ / truth - 1))
    note = table_text(est.result()).splitlines()[-1]
    assert note.startswith("viscous friction: fv_pos 0.4 N.s/m is the structure's") == (name == "viscous_axis")


@pytest.mark.long
@pytest.mark.skipif(os.environ.get("SERVOFMU_FAULTS") != "all", reason="long: SERVOFMU_FAULTS=all runs it")
def test_a_first_order_axis_identifies_the_viscous_difference_and_its_pole_holds_the_rest(tmp_path):
    """Truth: G = 10/(s + 10) (mass 0.1 kg, damping 1 N·s/m) with fv_pos 0.3, fv_neg 0.5; structure: fv_pos = fv_neg
    = 0.  The fit finds fv_neg − fv_pos = 0.2 within 1 % and a pole of damping 1 + 0.3 N·s/m (−13 rad/s), and its
    table says so."""
    import servofmu as sf
    from servofmu.identification.criterion import sine_data
    from servofmu.identification.results import table_text
    from servofmu.measurement.measure import MeasureOptions
    from servofmu.runtime import RunOptions

    axis = {"name": "visc1", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
            "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4, "fv_pos": 0.3, "fv_neg": 0.5}}
    truth = plant_from_dict(axis)
    data = tmp_path / "visc1.h5"
    sf.measure(sf.build_fmu(truth, tmp_path / "visc1.fmu"), data, options=MeasureOptions(), run=RunOptions(workers=0),
               amplitudes=[2.0, 0.6], frequencies=[0.3, 1.0, 3.0, 10.0])
    structure = plant_from_dict({**axis, "friction": {**axis["friction"], "fv_pos": 0.0, "fv_neg": 0.0}})
    est = sf.PSOANNIdentifier(structure, method="pso", seed=1).fit(sine_data(sf.read_data_file(data)))
    fitted = est.result().plant
    assert abs((fitted.friction.fv_neg - fitted.friction.fv_pos) / 0.2 - 1) < 0.01
    assert abs(fitted.poles[0].real / -13.0 - 1) < 0.01
    assert "G's pole holds 1.3 N.s/m of damping" in table_text(est.result())
