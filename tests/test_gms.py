"""The generalised Maxwell-slip law (docs/friction.md#gms): the shipped example's FMUs, the batch simulator and the
FMUs against scipy's Radau on the element equations written out again here (N = 1 and N = 4, through reversals and
sticking), the non-local memory of its presliding loops (a closed minor loop returns onto the outer branch, as the
elasto-plastic elements of the published model do exactly), noise-free identification, and bad keys refused in one
line naming the key."""
import functools
import json
import os
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from servofmu.errors import UserError
from servofmu.model.plant import PlantError, load_plant, plant_from_dict

MODELS = Path(__file__).resolve().parent.parent / "fmu_models"
STOP, SAMPLES, FREQUENCY, AMPLITUDE = 1.5, 151, 1.0, 0.45  # two reversals of a 1 Hz force, each with a stop
RTOL, ATOL = 1e-10, 1e-13  # the reference's tolerances (its error: about 1e-10 of the peak velocity)
LONG = pytest.mark.skipif(os.environ.get("SERVOFMU_FAULTS") != "all", reason="long: SERVOFMU_FAULTS=all runs it")


def gms_data(elements=4, **changes):
    data = tomllib.loads((MODELS / "gms_servo.toml").read_text())
    data["friction"].update(elements=elements, **changes)
    return data


# ---- the equations of docs/friction.md, written out without the package -----------------------------------------
def slip_level(fr, v):
    """s(v)/N: each element's share of the Stribeck curve of the side of v."""
    side = "pos" if v >= 0 else "neg"
    fc, fs = fr[f"fc_{side}"], fr[f"fs_{side}"]
    return (fc + (fs - fc) * np.exp(-abs(v / fr["vs"]) ** fr.get("delta", 2.0))) / fr["elements"]


def stiffnesses(fr):
    n = fr["elements"]
    return np.array([fr["sigma0"] / (i * sum(1.0 / j for j in range(1, n + 1))) for i in range(1, n + 1)])


def elements(fr, v, z):
    """(Σ k_i z_i, dz/dt): each element a spring that sticks, and slips at its level s(v)/N (attraction C)."""
    k, c = stiffnesses(fr), fr.get("attraction", 50.0)
    load = k * z / slip_level(fr, v)
    return k @ z, v - v * c * np.maximum(0.0, np.sign(v) * load - 1.0 + 1.0 / c)


def radau_servo(data, t):
    """v(t) of G(s) driven by AMPLITUDE·sin(2πft) − F(v, z)."""
    linear, fr = data["linear"], data["friction"]
    poles = [complex(*p) for p in linear["poles"]]
    A, B, C, _ = signal.zpk2ss([], poles, linear["dc_gain"] * np.real(np.prod([-p for p in poles])))
    n = A.shape[0]

    def rhs(time, s):
        v = float(C[0] @ s[:n])
        force, dz = elements(fr, v, s[n:])
        w = AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * time) - force - fr.get("fv", 0.0) * v
        return np.concatenate([A @ s[:n] + B[:, 0] * w, dz])

    sol = solve_ivp(rhs, (t[0], t[-1]), np.zeros(n + fr["elements"]), method="Radau", t_eval=t, rtol=RTOL,
                    atol=ATOL)
    assert sol.success, sol.message
    return C[0] @ sol.y[:n]


@functools.lru_cache(maxsize=None)
def reference(n):
    t = np.linspace(0.0, STOP, SAMPLES)
    return t, radau_servo(gms_data(n), t)


def relative_error(v, v_ref):
    assert np.abs(v_ref).max() > 0.01
    return float(np.abs(v - v_ref).max() / np.abs(v_ref).max())


def assert_reverses_and_sticks(v):
    assert v.max() > 0.01 and v.min() < -0.01
    assert np.sum(np.abs(v) < 1e-2 * np.abs(v).max()) >= 5


# ---- 1. the shipped example and its FMUs --------------------------------------------------------------------------
def test_the_example_has_four_elements_and_round_trips(tmp_path):
    plant = load_plant(MODELS / "gms_servo.toml")
    assert plant.friction.structure() == {"elements": 4}
    assert [s.name for s in plant.friction.states()] == ["z1", "z2", "z3", "z4"]
    assert "elements" not in plant.parameter_names() and plant.parameter_names()[-3:] == ["sigma0", "attraction",
                                                                                           "fv"]
    path = tmp_path / "back.toml"
    path.write_text(plant.to_toml())
    assert load_plant(path) == plant and 'elements = 4\n' in path.read_text()
    assert "gms elements=4, 8 parameters" in repr(plant.friction)
    assert ("N", "4") in plant.friction.law.rows({**plant.friction.structure(), **plant.friction.values()})


@pytest.mark.parametrize("version", [2, 3])
def test_the_fmus_validate_with_one_state_per_element(version, tmp_path):
    import fmpy
    from fmpy.validation import validate_fmu

    from servofmu.fmu.build import build_fmu

    fmu = str(build_fmu(load_plant(MODELS / "gms_servo.toml"), tmp_path / f"gms{version}.fmu", fmi_version=version))
    assert validate_fmu(fmu) == []
    md = fmpy.read_model_description(fmu)
    assert md.modelExchange is not None and md.coSimulation is not None
    names = {v.name: v for v in md.modelVariables}
    assert {"z1", "z4", "der(z4)", "sigma0", "attraction"} <= set(names) and "z5" not in names
    assert "elements" not in names and names["z3"].unit == "m"


# ---- 2. exactness ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 4])
def test_batch_simulator_matches_the_element_equations(n):
    from servofmu.simulation.batch import BatchSimulator

    plant = plant_from_dict(gms_data(n))
    t, v_ref = reference(n)
    assert_reverses_and_sticks(v_ref)
    response = BatchSimulator(plant, threads=1).simulate_sine(plant.parameter_vector()[None], t, AMPLITUDE,
                                                              FREQUENCY, rtol=1e-10)
    assert relative_error(response.v[0], v_ref) < 1e-7


@pytest.mark.long
@LONG
@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("n", [1, 4])
def test_fmus_match_the_element_equations(n, version, tmp_path):
    from fmpy import simulate_fmu

    from servofmu.fmu.build import build_fmu

    fmu = str(build_fmu(plant_from_dict(gms_data(n)), tmp_path / f"gms{n}.fmu", fmi_version=version))
    t, v_ref = reference(n)
    starts = {"excitation_amplitude": AMPLITUDE, "excitation_frequency": FREQUENCY}
    for kind in ("ModelExchange", "CoSimulation"):
        out = simulate_fmu(fmu, fmi_type=kind, stop_time=STOP, output_interval=t[1], relative_tolerance=1e-12,
                           start_values=starts, output=["v"])
        assert relative_error(out["v"], v_ref) < 1e-7, kind


# ---- 3. non-local memory -----------------------------------------------------------------------------------------
OUTER, TURN, INNER, SPEED = 1.5e-3, 0.6e-3, 0.5e-3, 1e-3  # m, m, m, m/s: ±1.5 mm, a 0.5 mm reversal at 0.6 mm


def presliding(force, corners, points=120):
    """(x, F, z) per segment under a prescribed position through ``corners`` at SPEED; ``force(v, z)``: (F, dz/dt)."""
    xs, fs, zs, z = [], [], [], np.zeros(4)
    for a, b in zip(corners[:-1], corners[1:]):
        v, duration = np.sign(b - a) * SPEED, abs(b - a) / SPEED
        sol = solve_ivp(lambda _, s: force(v, s)[1], (0.0, duration), z, method="Radau", rtol=1e-10, atol=1e-14,
                        t_eval=np.linspace(0.0, duration, points))
        xs.append(a + v * sol.t)
        fs.append(np.array([force(v, s)[0] for s in sol.y.T]))
        zs.append(sol.y.T)
        z = sol.y[:, -1]
    return xs, fs, zs


def elasto_plastic(fr, xs, corners):
    """F along the path (segments ``xs`` between ``corners``) of the published model's elements in the limit of an
    instant slip: each force moves with k_i·dx and is clipped at its level α_i·s(v) in the direction of motion."""
    k, forces, at, out = stiffnesses(fr), np.zeros(fr["elements"]), 0.0, []
    for a, b, segment in zip(corners[:-1], corners[1:], xs):
        v = np.sign(b - a) * SPEED
        low, high = (-slip_level(fr, v), np.inf) if v < 0 else (-np.inf, slip_level(fr, v))
        row = []
        for x in segment:
            forces, at = np.clip(forces + k * (x - at), low, high), x
            row.append(forces.sum())
        out.append(np.array(row))
    return out


def package_force(plant):
    """The package's own friction expression (servofmu.model.symbolic.friction_force) as a function of (v, z),
    without the viscous term."""
    import casadi as ca

    from servofmu.model.symbolic import friction_force

    v, z = ca.SX.sym("v"), ca.SX.sym("z", 4)
    force, dz = friction_force(plant, {**plant.parameters(), "fv": 0.0}, v, [z[i] for i in range(4)])
    return ca.Function("f", [v, z], [force, ca.vertcat(*dz)])


def test_a_closed_minor_loop_returns_onto_the_outer_branch():
    """Out to +1.5 mm, back to −1.5 mm with a 0.5 mm reversal at 0.6 mm on the way: the package's force and
    element equations are the reference's along the path, which follows the published model's elasto-plastic
    elements (instant slip) within 1/C of the slip level all along, the minor loop closes onto the branch it left within
    1/C of the slip level (the published elasto-plastic elements close it exactly; C = 50 leaves 0.2 %), and
    from there on the force is that of the outer loop without the reversal — the reversal is wiped out.  The
    single-state (Dahl) element does not: the same path leaves it 10 % of the level off the branch."""
    plant = load_plant(MODELS / "gms_servo.toml")
    fr = {**gms_data(4)["friction"], "fv": 0.0}
    minor = [0.0, OUTER, TURN, TURN + INNER, TURN, -OUTER]
    x, f_reference, z_reference = presliding(lambda v, z: elements(fr, v, z), minor)
    package = package_force(plant)
    for a, b, zs in zip(minor[:-1], minor[1:], z_reference):
        v = np.sign(b - a) * SPEED
        f, dz = package(v, zs.T)  # along the reference's path: the same force and derivatives
        assert np.allclose(np.asarray(f).ravel(), [elements(fr, v, z)[0] for z in zs], rtol=1e-13, atol=1e-15)
        assert np.allclose(np.asarray(dz).T, [elements(fr, v, z)[1] for z in zs], rtol=1e-12, atol=1e-15)
    hybrid = elasto_plastic(fr, x, minor)  # the published elements: within 1/C of the level all along the path
    assert max(np.abs(a - b).max() for a, b in zip(f_reference, hybrid)) < fr["fs_neg"] / 50.0
    x_outer, f_outer, _ = presliding(lambda v, z: elements(fr, v, z), [0.0, OUTER, -OUTER], points=600)
    branch = np.interp(-x[4], -x_outer[1], f_outer[1])  # the outer branch at the positions after the loop
    level, c = fr["fs_neg"], fr.get("attraction", 50.0)
    assert abs(f_reference[2][-1] - f_reference[2][0]) > 0.5 * level  # the inner loop is no small one
    assert abs(f_reference[4][0] - f_reference[4][-1]) > 0.3 * level  # nor is what is left of the outer one
    assert abs(f_reference[4][0] - branch[0]) < level / c  # closed where it left the branch
    assert np.abs(f_reference[4] - branch).max() < level / c  # and on it from there
    k = stiffnesses(fr)
    xd, fd, _ = presliding(lambda v, z: (k @ z, v - abs(v) * k * z / slip_level(fr, v)), minor)
    xd_outer, fd_outer, _ = presliding(lambda v, z: (k @ z, v - abs(v) * k * z / slip_level(fr, v)),
                                       [0.0, OUTER, -OUTER], points=600)
    assert abs(fd[4][0] - np.interp(-xd[4][0], -xd_outer[1], fd_outer[1])) > 0.1 * level


# ---- 4. identification --------------------------------------------------------------------------------------------
@pytest.mark.long
@LONG
def test_noise_free_stepped_sines_identify_every_parameter(tmp_path):
    """gms_servo measured through its FMU without noise: PSO and the polish find every identified parameter (the
    Stribeck values, sigma0; fv and the attraction are the structure's) within 1e-6."""
    import servofmu as sf
    from servofmu.identification.criterion import sine_data
    from servofmu.identification.prior import identified_mask, identified_names
    from servofmu.measurement.measure import MeasureOptions
    from servofmu.runtime import RunOptions

    plant = load_plant(MODELS / "gms_servo.toml")
    assert "sigma0" in identified_names(plant) and "attraction" not in identified_names(plant)
    data = tmp_path / "gms.h5"
    sf.measure(sf.build_fmu(plant, tmp_path / "gms.fmu"), data, options=MeasureOptions(), run=RunOptions(workers=0),
               amplitudes=[2.0, 0.6], frequencies=[0.3, 1.0, 3.0, 10.0])
    est = sf.PSOANNIdentifier(plant, method="pso", seed=1).fit(sine_data(sf.read_data_file(data)))
    truth = plant.parameter_vector()[identified_mask(plant)]
    assert np.max(np.abs(est.theta_ / truth - 1)) < 1e-6, dict(zip(est.result().names, est.theta_ / truth - 1))


# ---- 5. bad input ------------------------------------------------------------------------------------------------
BAD = [
    ({"elements": 0}, "friction.elements", "must be a whole number from 1 to 16, not 0"),
    ({"elements": 100}, "friction.elements", "must be a whole number from 1 to 16, not 100"),
    ({"elements": 2.5}, "friction.elements", "must be a whole number from 1 to 16, not 2.5"),
    ({"elements": 4.0}, "friction.elements", "must be a whole number"),
    ({"elements": "4"}, "friction.elements", "must be a whole number"),
    ({"delta": 0.0}, "friction.delta", "must be positive"),
    ({"delta": -1.0}, "friction.delta", "must not be negative"),
    ({"sigma1": 5.0}, "friction.sigma1", "unknown key"),
    ({"v_smooth": 1e-3}, "friction.v_smooth", "unknown key"),
    ({"stiffness": 1.0}, "friction.stiffness", "unknown key"),
    ({"attraction": 0.5}, "friction.attraction", "must be at least 1"),
    ({"sigma0": 0.0}, "friction.sigma0", "must be positive"),
    ({"fc_neg": 0.0}, "friction.fc_neg", "positive Coulomb friction"),
]


@pytest.mark.parametrize("changes, key, fragment", BAD)
def test_bad_keys_are_refused_naming_the_key(changes, key, fragment):
    with pytest.raises(PlantError) as info:
        plant_from_dict(gms_data(**changes), source="bad.toml")
    message = str(info.value)
    assert message.startswith(f"bad.toml: {key}: ") and fragment in message and "\n" not in message, message


def test_without_elements_the_file_is_refused():
    data = gms_data()
    del data["friction"]["elements"]
    with pytest.raises(PlantError, match=r"^bad.toml: friction.elements: missing \(required by the gms model"):
        plant_from_dict(data, source="bad.toml")


def test_elements_belong_to_gms_only():
    data = tomllib.loads((MODELS / "lugre_servo.toml").read_text())
    data["friction"]["elements"] = 4
    with pytest.raises(PlantError, match=r"^bad.toml: friction.elements: unknown key$"):
        plant_from_dict(data, source="bad.toml")


@pytest.mark.parametrize("line, fragment", [
    ("elements = 0", "friction.elements: must be a whole number from 1 to 16, not 0"),
    ("elements = 100", "friction.elements: must be a whole number from 1 to 16, not 100"),
    ("elements = 2.5", "friction.elements: must be a whole number from 1 to 16, not 2.5"),
    ("elements = 4\ndelta = 0.0", "friction.delta: must be positive"),
    ("elements = 4\nsigma1 = 5.0", "friction.sigma1: unknown key"),
    ("elements = 4\nwobble = 1.0", "friction.wobble: unknown key"),
])
def test_the_cli_refuses_a_bad_gms_friction_in_one_line_and_writes_nothing(tmp_path, line, fragment):
    from clitools import assert_one_line_error, run

    text = (MODELS / "gms_servo.toml").read_text().replace("elements = 4", line)
    plant = tmp_path / "axis.toml"
    plant.write_text(text)
    proc = run("build", plant, "-o", tmp_path / "axis.fmu")
    assert_one_line_error(proc, "servofmu build: error:", fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["axis.toml"]


# ---- selection -----------------------------------------------------------------------------------------------------
def test_gms_is_a_candidate_when_named_but_not_by_default():
    from servofmu.model.laws.registry import default_laws, get_law
    from servofmu.selection.candidates import parse_candidates

    from servofmu.selection.candidates import candidate_plant
    from servofmu.selection.estimate import LinearEstimate

    assert "gms" not in default_laws() and get_law("gms").cost > get_law("lugre").cost
    (candidate,) = parse_candidates(["gms/1"])
    plant = candidate_plant(candidate, LinearEstimate((-8.0 + 0j,), (), 12.0, 0.3, 0.25, 0.1))
    assert plant.friction.structure() == {"elements": 4} and len(plant.friction.states()) == 4
    assert plant.friction.sigma0 == 0.275 / 1e-4 and plant.friction.attraction == 50.0
    # a candidate's name chooses N (gms:2); the laws nested in it have no such choice, its own law keeps it
    from servofmu.selection.starts import nested_structures

    (two,) = parse_candidates(["gms:2+delta/2z"])
    assert two.name == "gms:2+delta/2z" and two.choices == (2,)
    plant = candidate_plant(two, LinearEstimate((-8.0 + 0j, -30.0 + 0j), (-20.0 + 0j,), 12.0, 0.3, 0.25, 0.1))
    assert plant.friction.structure() == {"elements": 2} and len(plant.friction.states()) == 2
    assert [c.name for c in nested_structures(two)] == ["stribeck+delta/2z", "coulomb/2z", "gms:2+delta/2",
                                                         "stribeck+delta/2", "coulomb/2"]
    for bad, fragment in (("gms:0/1", "elements must be a whole number from 1 to 16"),
                          ("gms:x/1", "elements must be a whole number"), ("gms:2:3/1", "takes 1 structure"),
                          ("coulomb:2/1", "the coulomb law has no structure choice")):
        with pytest.raises(UserError, match=fragment):
            parse_candidates([bad])


@pytest.mark.long
@LONG
def test_a_selection_ranks_gms_first_on_its_data_and_its_result_exports_and_back(tmp_path):
    """gms_servo measured without noise: named with lugre and stribeck, gms/1 ranks first (its fit is the truth, G
    holding fv); the fit written, exported as a plant file and an FMU, and read back with its four elements."""
    from fmpy.validation import validate_fmu

    import servofmu as sf
    from servofmu.measurement.measure import MeasureOptions
    from servofmu.runtime import RunOptions
    from servofmu.selection.select import SelectOptions

    fmu = sf.build_fmu(load_plant(MODELS / "gms_servo.toml"), tmp_path / "gms.fmu")
    data = {}
    for name, amplitudes in (("fit", [2.0, 0.6]), ("val", [1.5, 0.8])):
        data[name] = tmp_path / f"{name}.h5"
        sf.measure(fmu, data[name], options=MeasureOptions(), run=RunOptions(workers=0), amplitudes=amplitudes,
                   frequencies=[0.3, 1.0, 3.0, 10.0])
    selection = sf.select_files([data["fit"]], data["val"], tmp_path / "s.h5",
                                SelectOptions(candidates=("gms/1", "lugre/1", "stribeck/1"), iterations=20),
                                RunOptions(workers=0))
    assert [s.name for s in selection.scores] == ["gms/1", "lugre/1", "stribeck/1"]
    first = selection.scores[0].result
    assert abs(first.plant.friction.sigma0 / 1000.0 - 1) < 1e-6
    result = tmp_path / "result.h5"
    sf.write_result(result, first)
    back, _ = sf.export_result(result, tmp_path / "back.toml")
    again = sf.load_plant(back)
    assert again.friction.structure() == {"elements": 4}
    assert np.allclose(again.parameter_vector(), first.plant.parameter_vector(), rtol=1e-15)
    exported, _ = sf.export_result(result, tmp_path / "back.fmu", fmi_version=2)
    assert validate_fmu(str(exported)) == []
    control, _ = sf.export_result(result, tmp_path / "back.json", fmt="control")
    assert json.loads(control.read_text())["friction"]["elements"] == 4
