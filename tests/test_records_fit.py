"""Records of a machine identified without bias and validated on held-out data.

The records are made the way a digital drive makes them: FMPy runs a plant FMU in Co-Simulation with the force
applied through its input port, held for one sample (zero-order hold) — or, for the first-order-hold case, by
scipy's Radau on the equations with the input linear between samples.  The truth is the plant file.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from fmpy import simulate_fmu

import servofmu as sf
from servofmu.identification.criterion import RecordCriterion, RecordData, RecordSeries, record_data
from servofmu.identification.prior import identified_mask
from servofmu.measurement.datafile import read_data_file
from servofmu.simulation.batch import BatchSimulator
from servofmu.simulation.fmpy_runs import hold_table, replay_record
from servofmu.runtime import RunOptions
from hdf5edit import edit_hdf5

DT = 0.01  # 100 Hz, as a drive's log


def truth(name: str) -> np.ndarray:
    plant = sf.load_plant(name)
    return plant.parameter_vector()[identified_mask(plant)]


def drive_input(t: np.ndarray, m1: float, m2: float) -> np.ndarray:
    """The issue's excitation: m1 at 1 Hz for 5 s, then m2 at 2 Hz."""
    return np.where(t < 5, m1 * np.sin(2 * np.pi * t), m2 * np.sin(4 * np.pi * t))


def fmpy_record(fmu, t, u, outputs=("v", "position")):
    """The plant FMU in FMPy's Co-Simulation, u applied through the input port at every sample."""
    res = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=float(t[-1]), output_interval=DT,
                       input=hold_table(t, u, "zoh"), output=list(outputs))
    assert np.allclose(res["time"], t)
    return res


def write_csv(path, columns: dict) -> None:
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=",", header=",".join(columns), comments="")


@pytest.fixture(scope="module")
def records(built_fmu, tmp_path_factory):
    """Per plant: an estimation record (the issue's signal) and a held-out one (other magnitudes), noise-free."""
    folder = tmp_path_factory.mktemp("records")
    t = np.arange(0.0, 10.0 + DT / 2, DT)
    out = {}
    for name, (m1, m2), held_out in (("g1", (2.0, 0.6), (1.4, 0.9)), ("g2", (4.0, 2.0), (3.0, 2.5)),
                                     ("stribeck_servo", (2.0, 0.6), (1.5, 0.8))):
        fmu = built_fmu(name)
        for role, (a, b) in (("est", (m1, m2)), ("val", held_out)):
            u = drive_input(t, a, b)
            res = fmpy_record(fmu, t, u)
            write_csv(folder / f"{name}-{role}.csv", {"t": t, "u": u, "v": res["v"], "x": res["position"]})
        out[name] = folder
    return out


def import_csv(csv, h5, *extra):
    proc = run("import", csv, "--time", "t", "--input", "u", "--output-variable", "v", *extra, "-o", h5)
    assert proc.returncode == 0, proc.stderr
    return h5


@pytest.mark.parametrize("name", ["g1", "g2", "stribeck_servo"])
def test_zoh_records_from_fmpy_are_identified_to_1e6(records, tmp_path, name):
    """The issue's record, imported with the defaults (zero-order hold): every parameter within 1e-6, and
    identify reports the fit beside the fitness."""
    data = import_csv(records[name] / f"{name}-est.csv", tmp_path / "rec.h5")
    assert read_data_file(data).records[0].intersample == "zoh"
    proc = run("identify", data, "--structure", name, "--method", "pso", "-o", tmp_path / "r.h5")
    assert proc.returncode == 0, proc.stderr
    assert "fit (%" in proc.stdout
    result = sf.read_result(tmp_path / "r.h5")
    assert np.max(np.abs(result.theta / truth(name) - 1)) < 1e-6
    assert result.fit_percent[f"{name}-est"] > 99.9999


def test_foh_records_are_identified_to_1e6(tmp_path):
    """A record whose input is linear between samples (scipy's Radau on the equations), imported as foh."""
    from reference import simulate_reference_input

    t = np.arange(0.0, 4.0, 5e-3)
    u = 1.5 * np.sin(2 * np.pi * 0.7 * t) + 0.8 * np.sin(2 * np.pi * 3.1 * t + 1) + 0.3 * np.sin(2 * np.pi * 9.3 * t)
    v = simulate_reference_input([-10.0], [], 10.0, {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}, t, u,
                                 rtol=1e-12, atol=1e-14)
    write_csv(tmp_path / "rec.csv", {"t": t, "u": u, "v": v})
    data = import_csv(tmp_path / "rec.csv", tmp_path / "rec.h5", "--intersample", "foh")
    proc = run("identify", data, "--structure", "g1", "--method", "pso", "--json", "-o", tmp_path / "r.h5")
    assert proc.returncode == 0, proc.stderr
    assert np.max(np.abs(sf.read_result(tmp_path / "r.h5").theta / truth("g1") - 1)) < 1e-6
    # the same record taken as held is a different input: the fit is off by far more
    held = import_csv(tmp_path / "rec.csv", tmp_path / "held.h5")
    run("identify", held, "--structure", "g1", "--method", "pso", "--json", "-o", tmp_path / "h.h5")
    assert np.max(np.abs(sf.read_result(tmp_path / "h.h5").theta / truth("g1") - 1)) > 1e-3


def fit_records(structure: str, series: list[RecordSeries], seed: int = 0):
    est = sf.PSOANNIdentifier(sf.load_plant(structure), method="pso", seed=seed).fit(RecordData(tuple(series), "test"))
    return est


def test_quantised_encoder_position_is_fitted_without_bias(records):
    """A 1e-6 m encoder with an arbitrary zero: the raw position is fitted (its zero projected out), so the
    estimate is unbiased — inside its 95 % intervals, which are narrow.  The zero-phase velocity estimate of the
    same counts, fitted as if measured, is biased beyond its intervals, by a hundred times the position fit's
    error: the preprocessing that the position fit avoids."""
    d = np.loadtxt(records["g1"] / "g1-est.csv", delimiter=",", skiprows=1)
    t, u, x = d[:, 0], d[:, 1], d[:, 3]
    counts = np.round((x + 0.0123457) / 1e-6) * 1e-6
    csv = records["g1"] / "g1-encoder.csv"
    write_csv(csv, {"t": t, "u": u, "x": counts})
    h5 = csv.with_suffix(".h5")
    proc = run("import", csv, "--time", "t", "--input", "u", "--output-variable", "x", "--kind", "position", "-o", h5)
    assert proc.returncode == 0, proc.stderr
    (position,) = record_data(read_data_file(h5)).records
    assert position.output == "position"
    est = fit_records("g1", [position])
    true = truth("g1")
    assert np.all((est.intervals_[:, 0] <= true) & (true <= est.intervals_[:, 1]))
    assert np.max(np.abs(est.theta_ / true - 1)) < 1e-5
    velocity = RecordSeries("v", t, u, read_data_file(h5).records[0].series.v, "v", "zoh", np.ones(t.size, bool))
    biased = fit_records("g1", [velocity])
    assert not np.all((biased.intervals_[:, 0] <= true) & (true <= biased.intervals_[:, 1]))
    assert np.max(np.abs(biased.theta_ / true - 1)) > 100 * np.max(np.abs(est.theta_ / true - 1))


def test_several_records_are_weighted_by_their_noise(records):
    """Two records of one plant with noise levels 10x apart: fitted jointly, each record's weight comes from its
    own residuals (close to its noise level), and the estimate stays inside its intervals."""
    rng = np.random.default_rng(5)
    series = []
    for role, sigma in (("est", 0.002), ("val", 0.02)):
        d = np.loadtxt(records["g1"] / f"g1-{role}.csv", delimiter=",", skiprows=1)
        y = d[:, 2] + sigma * rng.standard_normal(d.shape[0])
        series.append(RecordSeries(role, d[:, 0], d[:, 1], y, "v", "zoh", np.ones(d.shape[0], bool)))
    est = fit_records("g1", series)
    crit = RecordCriterion(sf.load_plant("g1"), RecordData(tuple(series), "test"), BatchSimulator(sf.load_plant("g1")))
    crit.reweight(est.theta_[None], 1e-10)
    np.testing.assert_allclose(crit.scales, [0.002, 0.02], rtol=0.1)
    true = truth("g1")
    assert np.all((est.intervals_[:, 0] <= true) & (true <= est.intervals_[:, 1]))
    assert np.max(np.abs(est.theta_ / true - 1)) < 5e-3


def test_skip_leaves_out_the_start_of_a_record_that_is_not_at_rest(built_fmu, tmp_path):
    """A log that begins while the axis moves: the model starts at rest at the first sample, so without --skip the
    fit is biased; with the first 1.5 s skipped (the initial state has died away) it is exact again."""
    t = np.arange(0.0, 12.0 + DT / 2, DT)
    u = drive_input(t - 2.0, 2.0, 0.6)
    res = fmpy_record(built_fmu("g1"), t, u, outputs=("v",))
    keep = t >= 2.0
    write_csv(tmp_path / "late.csv", {"t": t[keep], "u": u[keep], "v": res["v"][keep]})
    data = import_csv(tmp_path / "late.csv", tmp_path / "late.h5")
    for skip, bound in ((0.0, None), (1.5, 1e-6)):
        proc = run("identify", data, "--structure", "g1", "--method", "pso", "--skip", skip, "--json",
                   "-o", tmp_path / f"r{skip}.h5")
        assert proc.returncode == 0, proc.stderr
        error = np.max(np.abs(sf.read_result(tmp_path / f"r{skip}.h5").theta / truth("g1") - 1))
        assert error < bound if bound else error > 1e-4


# ---------------------------------------------------------------------------
# servofmu validate
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def g1_identified(records, tmp_path_factory):
    folder = tmp_path_factory.mktemp("identified")
    est = import_csv(records["g1"] / "g1-est.csv", folder / "est.h5")
    val = import_csv(records["g1"] / "g1-val.csv", folder / "val.h5")
    proc = run("identify", est, "--structure", "g1", "--method", "pso", "-o", folder / "r.h5")
    assert proc.returncode == 0, proc.stderr
    return {"result": folder / "r.h5", "est": est, "val": val, "folder": folder}


def test_validate_on_held_out_noise_free_records(g1_identified, tmp_path):
    proc = run("validate", g1_identified["result"], g1_identified["val"], "--json")
    assert proc.returncode == 0, proc.stderr
    obj = json.loads(proc.stdout)
    (record,) = obj["records"]
    assert record["fit_percent"] >= 99.9 and obj["passed"]
    test = record["residual_test"]  # noise-free: tested only where the residuals exceed the simulation's precision
    assert test["passed"] is True if test["applies"] else test["passed"] is None and "do not apply" in obj["verdict"]
    # a page and a figure
    for name in ("v.html", "v.png"):
        proc = run("validate", g1_identified["result"], g1_identified["val"], "-o", tmp_path / name)
        assert proc.returncode == 0, proc.stderr
    assert "validation-records" in (tmp_path / "v.html").read_text()
    assert (tmp_path / "v.png").read_bytes()[:4] == b"\x89PNG"
    # the report of the identification gains the same section
    proc = run("report", g1_identified["result"], "--data", g1_identified["est"], "--validate",
               g1_identified["val"], "-o", tmp_path / "report.html")
    assert proc.returncode == 0, proc.stderr
    assert "Validation on val.h5" in (tmp_path / "report.html").read_text()


def test_exported_fmu_replays_the_record_with_its_hold(g1_identified, tmp_path):
    """The identified model exported as an FMU and driven through its input port with the record's hold
    reproduces the held-out record."""
    proc = run("export", g1_identified["result"], "-o", tmp_path / "id.fmu")
    assert proc.returncode == 0, proc.stderr
    rec = read_data_file(g1_identified["val"]).records[0]
    replay = replay_record(tmp_path / "id.fmu", rec.series.time, rec.series.u, rec.intersample)
    v = rec.series.v
    assert 100 * (1 - np.linalg.norm(replay["v"] - v) / np.linalg.norm(v - v.mean())) > 99.9999


def test_residual_tests_tell_a_wrong_friction_structure(records, tmp_path):
    """Stribeck-plant records with 40 dB output noise: the Stribeck structure's residuals on a held-out record are
    white and independent of the input; a Coulomb structure (same linear part) fitted to the same record leaves
    correlated residuals outside the bounds."""
    rng = np.random.default_rng(7)
    files = {}
    for role in ("est", "val"):
        d = np.loadtxt(records["stribeck_servo"] / f"stribeck_servo-{role}.csv", delimiter=",", skiprows=1)
        v = d[:, 2] + np.std(d[:, 2]) / 100 * rng.standard_normal(d.shape[0])
        write_csv(tmp_path / f"{role}.csv", {"t": d[:, 0], "u": d[:, 1], "v": v})
        files[role] = import_csv(tmp_path / f"{role}.csv", tmp_path / f"{role}.h5")
    coulomb = tmp_path / "coulomb.toml"
    coulomb.write_text('name = "coulomb2"\n[linear]\npoles = [[-5.0, 0.0], [-40.0, 0.0]]\ndc_gain = 2.0\n'
                       '[friction]\nmodel = "coulomb"\nfc_pos = 0.3\nfc_neg = 0.25\nfv = 0.1\n')
    verdicts = {}
    for structure in ("stribeck_servo", coulomb):
        out = tmp_path / f"{getattr(structure, 'stem', structure)}.h5"
        assert run("identify", files["est"], "--structure", structure, "--method", "pso", "-o", out).returncode == 0
        proc = run("validate", out, files["val"], "--json")
        assert proc.returncode == (0 if structure == "stribeck_servo" else 1), proc.stderr  # 1: the model failed
        verdicts[str(structure)] = json.loads(proc.stdout)["records"][0]["residual_test"]
    assert verdicts["stribeck_servo"]["passed"]
    wrong = verdicts[str(coulomb)]
    assert not wrong["passed"] and wrong["max_autocorrelation_over_bound"] > 1.5


def test_validate_refuses_bad_input_in_one_line(g1_identified, records, built_fmu, tmp_path):
    # a result whose structure does not match the plant a measurement was made on
    measured = tmp_path / "g2.h5"
    sf.measure(built_fmu("g2"), measured, amplitudes=[4.0, 2.0], frequencies=[1.0], run=RunOptions(workers=0))
    assert_one_line_error(run("validate", g1_identified["result"], measured), "does not match")
    # a records file whose record has no input
    broken = tmp_path / "no-input.h5"
    broken.write_bytes(g1_identified["val"].read_bytes())
    edit_hdf5(broken, lambda f: f["records/rec_0000"].__delitem__("u"))
    out = tmp_path / "out.html"
    assert_one_line_error(run("validate", g1_identified["result"], broken, "-o", out), "no-input.h5", "'u'")
    assert not out.exists()
    # an output that is neither a page nor a figure
    assert_one_line_error(run("validate", g1_identified["result"], g1_identified["val"], "-o", tmp_path / "x.txt"),
                          "x.txt")
    # an unknown intersample behaviour at import
    new = tmp_path / "new.h5"
    assert_one_line_error(run("import", records["g1"] / "g1-est.csv", "--time", "t", "--input", "u", "--output-variable", "v",
                              "--intersample", "cubic", "-o", new), "--intersample", "cubic")
    assert not new.exists()


def test_files_of_schema_version_1_are_read_as_foh_and_upgraded_on_append(g1_identified, records, tmp_path):
    old = tmp_path / "old.h5"
    old.write_bytes(g1_identified["val"].read_bytes())
    def version_1(f):  # what servofmu wrote before records had an intersample behaviour (and a digest)
        f.attrs["schema_version"] = 1
        del f["records/rec_0000"].attrs["intersample"]

    edit_hdf5(old, version_1, digest=False)
    assert read_data_file(old).records[0].intersample == "foh"
    import_csv(records["g1"] / "g1-est.csv", old, "--append")
    upgraded = read_data_file(old)
    assert upgraded.schema_version == 2
    assert [r.intersample for r in upgraded.records] == ["foh", "zoh"]


def test_a_measured_signal_that_does_not_vary_has_no_fit_percent():
    """MATLAB's fit divides by the signal's spread: for a constant signal it is no number, and validate's JSON says
    so with null (JSON has no NaN or infinity) and its verdict names why."""
    import json

    from servofmu.identification.criterion import fit_percent
    from servofmu.display import json_safe

    assert np.isnan(fit_percent(np.zeros(10), np.ones(10)))
    assert fit_percent(np.arange(10.0), np.zeros(10)) == 100.0
    assert json.loads(json.dumps(json_safe({"fit": float("nan"), "r": [1.0, float("inf")]}), allow_nan=False)) == \
        {"fit": None, "r": [1.0, None]}
