"""`servofmu export`: identified models as FMUs (with provenance), python-control, MATLAB, JSON and plant TOML.

The RESULT.h5 files are made here from the plant files with perturbed parameters (an identification that is off
by 1-2 %) or with the true parameters (a perfect identification), not by the identifier.
"""
from __future__ import annotations

import functools
import hashlib
import json
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import replace

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.util import fmu_info
from fmpy.validation import validate_fmu
from reference import simulate_reference
from test_cli_build import assert_one_line_error, run
from test_importers import (
    DT,
    N_STEPS,
    STOP,
    TOL_INTEGRATORS,
    TOL_SAME_INTEGRATOR,
    libcosim_cosimulation,
    loader_cosimulation,
    loader_model_exchange,
)

from servofmu import __version__
from servofmu.errors import UserError
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.identification.results import Result, Stage, write_result
from servofmu.model.plant import load_plant
from servofmu.commands.roundtrip import ROUND_TRIP_TOLERANCE, remeasure
from servofmu.output.export import (
    FORMATS,
    export_result,
    identified_plant,
    load_control,
)
from servofmu.runtime import RunOptions
from hdf5edit import edit_hdf5

# Perturbation of the identified parameters: an identification that is off by a few per cent.
FACTORS = {"g1": 1.02, "g2": 1.01}
DATA_SHA = "0" * 64
# Plans of the round trip: g2 has a friction-induced limit cycle, so only magnitudes that quench it and
# frequencies at or below the resonance reach a steady state.
PLANS = {"g1": ((2.0, 0.6), (0.5, 2.0, 10.0)), "g2": ((4.0, 2.0), (1.0, 2.0, 5.0))}
SIM_CASE = {"g1": (0.6, 0.5), "g2": (2.0, 5.0)}  # (amplitude N, frequency Hz) of the time-domain checks


def make_result(name: str, factor: float, fitness: float, data_sha: str = DATA_SHA, intervals=None) -> Result:
    structure = load_plant(name)
    mask = identified_mask(structure)
    full = structure.parameter_vector()
    full[mask] *= factor
    theta = full[mask]
    if intervals is None:
        half = 0.01 * np.abs(theta)
        intervals = np.stack([theta - half, theta + half], axis=1)
    return Result(method="pso-ann", structure=structure, plant=structure.with_parameters(full),
                  names=tuple(identified_names(structure)), theta=theta, intervals=intervals, fitness=fitness,
                  seconds=1.5, evaluations=1234,
                  stages=(Stage("ann", None, 0.1, 0.01, 1), Stage("pso", None, 0.02, 1.0, 1000)),
                  history=np.array([0.1, 0.05, 0.02]),
                  provenance={"data_file": f"{name}.h5", "data_sha256": data_sha,
                              "command": f"servofmu identify {name}.h5 --structure {name} -o <result> & more",
                              "date": "2026-01-02T03:04:05Z"})


@pytest.fixture(scope="module")
def result_file(tmp_path_factory):
    """result_file(name): RESULT.h5 of the perturbed plant ``name`` (fitness 1.5e-3)."""
    folder = tmp_path_factory.mktemp("results")

    @functools.lru_cache(maxsize=None)
    def make(name):
        return write_result(folder / f"{name}.h5", make_result(name, FACTORS[name], 1.5e-3))

    return make


@pytest.fixture(scope="module")
def exported(tmp_path_factory, result_file):
    """exported(name, fmt, version=None): the file ``servofmu export`` writes for the perturbed plant."""
    folder = tmp_path_factory.mktemp("exported")

    @functools.lru_cache(maxsize=None)
    def make(name, fmt, version=None):
        suffix = {"fmu": ".fmu", "mat": ".mat", "toml": ".toml"}.get(fmt, ".json")
        out = folder / f"{name}_{fmt}{version or ''}{suffix}"
        path, written = export_result(result_file(name), out, fmt=fmt, fmi_version=version,
                                      command=f"servofmu export {name}.h5 -o {out.name}")
        assert written == fmt and path == out
        return out

    return make


def g_of_jw(result: Result, omega):
    """G(jω) of the identified plant from its parameters: K·∏(jω − z)/∏(jω − p), K from the DC gain."""
    p = result.plant.parameters()
    poles = [complex(p["pole1_re"], p["pole1_im"]), complex(p["pole1_re"], -p["pole1_im"]), p["pole2"]] \
        if "pole1_re" in p else [p["pole1"]]
    k = p["dc_gain"] * np.real(np.prod([-q for q in poles]))
    s = 1j * np.asarray(omega)
    return k / np.prod([s - q for q in poles], axis=0)


# ---------------------------------------------------------------------------
# The FMU: valid, provenance visible, identified values as start values
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("version", [3, 2])
def test_exported_fmu_is_valid_and_carries_provenance_and_identified_values(exported, result_file, built_fmu,
                                                                             version):
    fmu = exported("g2", "fmu", version)
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    assert md.fmiVersion == f"{version}.0" and md.modelName == "g2_identified"
    assert md.modelExchange is not None and md.coSimulation is not None
    # the same variables as the plant FMU of the structure
    plain = read_model_description(str(built_fmu("g2", version)))
    assert [(v.name, v.valueReference, v.causality, v.variability, v.unit) for v in md.modelVariables] == \
        [(v.name, v.valueReference, v.causality, v.variability, v.unit) for v in plain.modelVariables]
    result = make_result("g2", FACTORS["g2"], 1.5e-3)
    starts = {v.name: float(v.start) for v in md.modelVariables if v.causality == "parameter"}
    for name, value in result.plant.parameters().items():
        assert starts[name] == value  # exactly the identified values
    assert starts["pole2"] == -10.0 * FACTORS["g2"] and starts["fv"] == 0.0
    # provenance: in the description that `fmpy info` prints, in the annotations and in the documentation
    sha = hashlib.sha256(result_file("g2").read_bytes()).hexdigest()
    info = fmu_info(str(fmu))
    for text in ("method: pso-ann", f"data_sha256: {DATA_SHA}", "fitness: 0.0015", "intervals_95: pole1_re [",
                 "identify_date: 2026-01-02T03:04:05Z", f"package_version: {__version__}", f"result_sha256: {sha}",
                 "export_command: servofmu export g2.h5"):
        assert text in info and text in md.description
    root = ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
    holder = root.find("Annotations/Annotation[@type='servofmu.provenance']") if version == 3 else \
        root.find("VendorAnnotations/Tool[@name='servofmu']")
    entries = {e.get("name"): e.get("value") for e in holder.find("Provenance")}
    assert entries["data_sha256"] == DATA_SHA and entries["method"] == "pso-ann"
    assert entries["identify_command"].endswith("-o <result> & more")  # XML-escaped and read back intact
    assert entries["intervals_95"].startswith("pole1_re [-2.55025, -2.49975], pole1_im [31.5")
    doc = zipfile.ZipFile(fmu).read("documentation/index.html").decode()
    assert "<h2>Provenance</h2>" in doc and DATA_SHA in doc and "-o &lt;result&gt; &amp; more" in doc


@pytest.fixture(scope="module")
def fmpy_run():
    @functools.lru_cache(maxsize=None)
    def run_fmu(path, interface):
        amplitude, frequency = SIM_CASE["g2"]
        me = interface == "me"
        res = simulate_fmu(str(path), fmi_type="ModelExchange" if me else "CoSimulation", stop_time=STOP,
                           output_interval=DT, relative_tolerance=1e-12 if me else None, output=["v"],
                           start_values={"excitation_amplitude": amplitude, "excitation_frequency": frequency})
        assert np.allclose(res["time"], np.linspace(0.0, STOP, N_STEPS + 1))
        return np.asarray(res["v"])

    return run_fmu


@pytest.mark.parametrize("version", [3, 2])
def test_exported_fmu_runs_in_fmpy_and_in_a_second_importer(exported, fmpy_run, fmu_layout, version):
    fmu = exported("g2", "fmu", version)
    amplitude, frequency = SIM_CASE["g2"]
    result = make_result("g2", FACTORS["g2"], 1.5e-3)
    t = np.linspace(0.0, STOP, N_STEPS + 1)
    plant = result.plant
    v_ref = simulate_reference(plant.all_poles(), [], plant.numerator_gain(), {"model": "coulomb",
                               **plant.friction.values()}, amplitude, frequency, t, rtol=1e-11, atol=1e-13)
    nominal = load_plant("g2")
    v_nominal = simulate_reference(nominal.all_poles(), [], nominal.numerator_gain(),
                                   {"model": "coulomb", **nominal.friction.values()}, amplitude, frequency, t)
    assert np.abs(v_ref - v_nominal).max() > 1e-2  # the identified values make a visible difference
    me, cs = fmpy_run(fmu, "me"), fmpy_run(fmu, "cs")
    assert np.abs(me - v_ref).max() < TOL_INTEGRATORS
    assert np.abs(cs - v_ref).max() < TOL_INTEGRATORS
    layout = fmu_layout("g2")  # value references depend on the structure only
    v = loader_model_exchange(fmu, "g2_identified", version, layout, amplitude, frequency)
    assert np.abs(v - me).max() < TOL_INTEGRATORS
    v = loader_cosimulation(fmu, "g2_identified", version, layout, amplitude, frequency)
    assert np.abs(v - cs).max() < TOL_SAME_INTEGRATOR
    if version == 2:
        v = libcosim_cosimulation(fmu, layout, amplitude, frequency)
        assert np.abs(v - cs[1:]).max() < TOL_SAME_INTEGRATOR


def test_exported_toml_rebuilds_an_equal_fmu(exported, fmpy_run, tmp_path):
    from servofmu.fmu import build_fmu

    toml = exported("g2", "toml")
    rebuilt = build_fmu(load_plant(toml), tmp_path / "rebuilt.fmu", fmi_version=3)
    original = exported("g2", "fmu", 3)
    md_a, md_b = read_model_description(str(original)), read_model_description(str(rebuilt))
    assert md_a.modelName == md_b.modelName == "g2_identified"
    assert [(v.name, v.valueReference, v.causality, v.start) for v in md_a.modelVariables] == \
        [(v.name, v.valueReference, v.causality, v.start) for v in md_b.modelVariables]
    for interface in ("me", "cs"):
        assert np.abs(fmpy_run(rebuilt, interface) - fmpy_run(original, interface)).max() < 1e-9
    assert "# data_sha256 = " in toml.read_text()  # the provenance travels as comments


# ---------------------------------------------------------------------------
# python-control, MATLAB, JSON
# ---------------------------------------------------------------------------
def test_control_export_loads_as_transfer_function_and_state_space(exported):
    import control

    path = exported("g2", "control")
    result = make_result("g2", FACTORS["g2"], 1.5e-3)
    omega = np.logspace(-1, 3, 25)
    tf, friction = load_control(path)
    assert isinstance(tf, control.TransferFunction)
    expected = g_of_jw(result, omega)
    assert np.allclose(tf(1j * omega), expected, rtol=1e-12, atol=0)
    ss, friction_ss = load_control(path, state_space=True)
    assert isinstance(ss, control.StateSpace) and ss.nstates == 3
    assert np.allclose(ss(1j * omega), expected, rtol=1e-12, atol=0)
    assert friction == friction_ss == {"model": "coulomb", "fc_pos": 0.5 * FACTORS["g2"],
                                       "fc_neg": 0.4 * FACTORS["g2"], "fv": 0.0, "v_smooth": 1e-3}
    # the state space is the FMU's own realisation: v = xi1
    assert np.array_equal(ss.C, [[1.0, 0.0, 0.0]])
    with pytest.raises(UserError, match="not a servofmu control file"):
        load_control(exported("g2", "json"))


def test_mat_export_reads_with_scipy(exported):
    import scipy.io

    result = make_result("g1", FACTORS["g1"], 1.5e-3)
    m = scipy.io.loadmat(exported("g1", "mat"), squeeze_me=True, simplify_cells=True)
    omega = np.array([0.5, 5.0, 50.0])
    num, den = np.atleast_1d(m["num"]), np.atleast_1d(m["den"])
    assert np.allclose(np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega), g_of_jw(result, omega),
                       rtol=1e-13)
    assert m["friction"] == {"model": "coulomb", "fc_pos": 0.51, "fc_neg": 0.4 * 1.02, "fv": 0.0, "v_smooth": 1e-3}
    assert list(m["parameter_names"]) == ["pole1", "dc_gain", "fc_pos", "fc_neg"]
    assert np.array_equal(m["theta"], result.theta) and np.array_equal(m["intervals"], result.intervals)
    assert m["method"] == "pso-ann" and m["fitness"] == 1.5e-3 and m["name"] == "g1_identified"
    assert m["provenance"]["data_sha256"] == DATA_SHA


def test_json_export_is_standard_json(tmp_path):
    result = make_result("g1", FACTORS["g1"], 1.5e-3, intervals=np.full((4, 2), np.nan))
    path = write_result(tmp_path / "r.h5", result)
    out, fmt = export_result(path, tmp_path / "r.json")
    assert fmt == "json"

    def no_nan(text):
        raise AssertionError(f"non-standard JSON constant {text}")

    doc = json.loads(out.read_text(), parse_constant=no_nan)
    assert doc["format"] == "servofmu-export" and doc["name"] == "g1_identified"
    assert doc["intervals"]["pole1"] == [None, None]  # unknown intervals are null, not NaN
    assert doc["plant_parameters"] == result.plant.parameters()
    assert doc["parameters"]["poles"] == [[-10.2, 0.0]] and doc["fitness"] == 1.5e-3
    assert doc["provenance"]["data_sha256"] == DATA_SHA
    assert load_plant_text(tmp_path, doc["plant_toml"]) == identified_plant(result)


def load_plant_text(folder, text):
    path = folder / "plant.toml"
    path.write_text(text)
    return load_plant(path)


# ---------------------------------------------------------------------------
# Round trip: the exported FMU, measured with the plan of the data, reproduces it
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["g1", "g2"])
def test_round_trip_reproduces_the_data_within_the_identification_residual(built_fmu, tmp_path, name):
    """Data from the true plant's FMU.  (1) A perfect identification (the true plant, fitness 0) reproduces it
    to the measurement's accuracy.  (2) An identification off by 1-2 %, whose fitness the identifier's own
    criterion computes with the batch simulator, reproduces it with a residual equal to that fitness: the FMU
    measurement and the batch simulator agree on first harmonics to ~5e-10 relative, so the two RMS values
    agree to ROUND_TRIP_TOLERANCE (1e-8)."""
    from servofmu.identification.criterion import POLISH_RTOL, SineCriterion, rms, sine_data
    from servofmu.measurement.measure import measure
    from servofmu.simulation.batch import BatchSimulator

    amplitudes, frequencies = PLANS[name]
    data_file = tmp_path / "data.h5"
    ds = measure(built_fmu(name, 3), data_file, amplitudes=amplitudes, frequencies=frequencies, run=RunOptions(workers=0))
    assert all(e.converged for e in ds.experiments)
    sha = hashlib.sha256(data_file.read_bytes()).hexdigest()

    perfect = make_result(name, 1.0, 0.0, data_sha=sha)
    rt = remeasure(perfect, data_file, tmp_path / "perfect.fmu", tmp_path / "perfect.h5", workers=0)
    assert rt.compared == len(amplitudes) * len(frequencies) and rt.unsettled == 0
    assert rt.residual_rms <= ROUND_TRIP_TOLERANCE and rt.max_H_error <= ROUND_TRIP_TOLERANCE
    assert rt.reproduces
    assert rt.measured.plan == ds.plan and rt.measured.provenance["tolerance"] == ds.provenance["tolerance"]

    off = make_result(name, FACTORS[name], 0.0, data_sha=sha)
    criterion = SineCriterion(off.structure, sine_data(ds), BatchSimulator(off.structure, threads=1))
    fitness = float(rms(criterion.residuals(off.theta, POLISH_RTOL))[0])
    assert fitness > 1e-3  # the perturbation is visible in the data
    off = replace(off, fitness=fitness)
    rt = remeasure(off, data_file, tmp_path / "off.fmu", tmp_path / "off.h5", fmi_version=2, workers=0)
    assert abs(rt.residual_rms - fitness) <= ROUND_TRIP_TOLERANCE
    assert rt.reproduces and not replace(rt, fitness=0.0).reproduces
    assert read_model_description(str(rt.fmu)).fmiVersion == "2.0"


def test_round_trip_refuses_data_the_result_was_not_identified_from(tmp_path, built_fmu):
    from servofmu.measurement.measure import measure

    data_file = tmp_path / "data.h5"
    measure(built_fmu("g1", 3), data_file, amplitudes=(2.0,), frequencies=(1.0,), run=RunOptions(workers=0))
    with pytest.raises(UserError, match="not the data file the result was identified from"):
        remeasure(make_result("g1", 1.0, 0.0), data_file, tmp_path / "x.fmu", tmp_path / "x.h5", workers=0)
    assert not (tmp_path / "x.fmu").exists() and not (tmp_path / "x.h5").exists()


# ---------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------
def test_cli_exports_and_lists_the_library_formats(result_file, tmp_path):
    from servofmu.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["export"]
    assert next(a for a in sub._actions if a.dest == "format").choices == FORMATS
    out = tmp_path / "g1.toml"
    proc = run("export", str(result_file("g1")), "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "plant file" in proc.stdout and load_plant(out) == identified_plant(make_result("g1", 1.02, 0))


def foreign_version(path, folder):
    target = folder / "foreign.h5"
    target.write_bytes(path.read_bytes())
    return edit_hdf5(target, lambda f: f.attrs.__setitem__("schema_version", 99))


def corrupt(path, folder):
    target = folder / "corrupt.h5"
    data = path.read_bytes()
    target.write_bytes(data[: len(data) // 2])
    return target


@pytest.mark.parametrize("case, fragments", [
    ("foreign", ("foreign.h5", "schema version 99")),
    ("corrupt", ("corrupt.h5", "not a readable result file")),
    ("format", ("--format", "yaml")),
    ("suffix", ("out.xyz", "give the format")),
    ("fmi_version", ("--fmi-version applies", "format json")),  # the option, not the Python argument
])
def test_cli_bad_input_is_one_line_and_writes_nothing(result_file, tmp_path, case, fragments):
    good = result_file("g1")
    source = {"foreign": lambda: foreign_version(good, tmp_path), "corrupt": lambda: corrupt(good, tmp_path)}.get(
        case, lambda: good)()
    out = tmp_path / ("out.xyz" if case == "suffix" else "out.json")
    args = {"format": ["--format", "yaml"], "fmi_version": ["--fmi-version", "2"]}.get(case, [])
    for existing in (False, True):
        if existing:
            out.write_text("keep me")
        proc = run("export", str(source), *args, "-o", str(out), *(["--force"] if existing else []))
        assert_one_line_error(proc, *fragments)
        assert (out.read_text() == "keep me") if existing else not out.exists()
        assert {p.name for p in tmp_path.iterdir()} <= {"foreign.h5", "corrupt.h5", out.name}  # no leftovers
