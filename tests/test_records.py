"""Import of machine records (CSV/MAT): reading, velocity from quantised position, first-harmonic analysis,
and every way a record file can be wrong."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.io import savemat

from servofmu.errors import UserError
from servofmu.measurement.measure import MeasureOptions, measure
from servofmu.measurement.records import import_records, velocity_from_position
from servofmu.simulation.fmpy_runs import simulate
from servofmu.runtime import RunOptions

M, F, FS, DURATION = 2.0, 2.0, 1000.0, 6.0
ENCODER = 1e-5  # m per count


@pytest.fixture(scope="module")
def machine(built_fmu):
    """A synthetic machine record: g1 under 2 sin(2π·2t) from rest, sampled at 1 kHz, with noisy velocity and
    force and a quantised position; plus the steady-state H measured from the FMU itself."""
    fmu = built_fmu("g1")
    res = simulate(fmu, DURATION, interface="cs", amplitude=M, frequency=F, output_interval=1 / FS,
                   relative_tolerance=1e-10, outputs=["v", "position"])
    rng = np.random.default_rng(11)
    t = np.asarray(res["time"])
    u = M * np.sin(2 * np.pi * F * t) + 0.002 * rng.standard_normal(t.size)
    v = np.asarray(res["v"]) + 0.01 * rng.standard_normal(t.size)
    x = np.round(np.asarray(res["position"]) / ENCODER) * ENCODER
    return {"t": t, "u": u, "v": v, "x": x, "v_true": np.asarray(res["v"])}


@pytest.fixture(scope="module")
def reference_h(built_fmu, tmp_path_factory):
    out = tmp_path_factory.mktemp("ref") / "ref.h5"
    data = measure(built_fmu("g1"), out, amplitudes=[M], frequencies=[F], run=RunOptions(workers=0),
                   options=MeasureOptions(samples_per_period=1024))
    return data.experiments[0].H


def write_csv(path, columns: dict, header=None):
    names = header or list(columns)
    data = np.column_stack([columns[n] for n in columns])
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.17g")
    return path


def test_velocity_record_gets_the_first_harmonic_of_the_measurement(machine, reference_h, tmp_path):
    csv = write_csv(tmp_path / "vel.csv", {"t": machine["t"], "force": machine["u"], "speed": machine["v"]})
    data = import_records([csv], tmp_path / "r.h5", time="t", input="force", output_column="speed")
    (rec,) = data.records
    a = rec.analysis
    assert rec.kind == "velocity" and rec.sample_rate == pytest.approx(FS)
    assert a.frequency == pytest.approx(F, rel=1e-5) and a.sine_fraction > 0.99
    assert a.converged and 0 < a.settling_time < 2.0  # g1 settles within a few tenths of a second
    assert a.window_start + a.window_periods / a.frequency <= DURATION + 1e-9
    assert abs(a.H - reference_h) < 2e-3 * abs(reference_h)
    assert abs(a.U1) == pytest.approx(M, rel=1e-3)
    np.testing.assert_array_equal(rec.series.v, machine["v"])
    assert rec.columns == {"time": "t", "u": "force", "v": "speed"}


def test_position_record_gets_a_zero_phase_velocity_estimate(machine, reference_h, tmp_path):
    csv = write_csv(tmp_path / "pos.csv", {"t": machine["t"], "force": machine["u"], "x": machine["x"]})
    data = import_records([csv], tmp_path / "r.h5", time="t", input="force", output_column="x", kind="position")
    (rec,) = data.records
    np.testing.assert_array_equal(rec.series.position, machine["x"])  # the raw signal is kept
    assert rec.velocity_cutoff == pytest.approx(FS / 10) and "Butterworth" in rec.velocity_estimate
    inner = slice(200, -200)
    error = rec.series.v[inner] - machine["v_true"][inner]
    assert np.sqrt(np.mean(error ** 2)) < 0.02 * np.sqrt(np.mean(machine["v_true"][inner] ** 2))
    assert abs(rec.analysis.H - reference_h) < 2e-3 * abs(reference_h)


def test_velocity_estimate_of_a_sine_has_no_phase_lag_and_tiny_gain_error():
    fs, f, cutoff = 1000.0, 8.0, 100.0
    t = np.arange(4000) / fs
    v = velocity_from_position(t, 0.05 * np.sin(2 * np.pi * f * t), cutoff)
    exact = 0.05 * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    inner = slice(500, -500)
    assert np.max(np.abs(v[inner] - exact[inner])) < 2e-5 * np.max(np.abs(exact))
    with pytest.raises(UserError, match="cutoff"):
        velocity_from_position(t, np.sin(t), 600.0)


def test_mat_files_give_the_same_record_as_csv(machine, tmp_path):
    cols = {"t": machine["t"], "force": machine["u"], "speed": machine["v"]}
    csv = write_csv(tmp_path / "rec.csv", cols)
    mat = tmp_path / "rec.mat"
    savemat(mat, {k: v.reshape(-1, 1) for k, v in cols.items()})
    a = import_records([csv], tmp_path / "a.h5", time="t", input="force", output_column="speed").records[0]
    b = import_records([mat], tmp_path / "b.h5", time="t", input="force", output_column="speed").records[0]
    assert a.analysis.H == b.analysis.H
    np.testing.assert_array_equal(a.series.v, b.series.v)


def test_several_records_and_append_make_one_data_set(machine, tmp_path):
    c1 = write_csv(tmp_path / "one.csv", {"t": machine["t"], "force": machine["u"], "speed": machine["v"]})
    c2 = write_csv(tmp_path / "two.csv", {"t": machine["t"], "force": 0.5 * machine["u"], "speed": machine["v"]})
    out = tmp_path / "r.h5"
    c3 = write_csv(tmp_path / "three.csv", {"t": machine["t"], "force": 2 * machine["u"], "speed": machine["v"]})
    import_records([c1, c2], out, time="t", input="force", output_column="speed")
    data = import_records([c3], out, time="t", input="force", output_column="speed", append=True)
    assert [r.name for r in data.records] == ["one", "two", "three"] and [r.index for r in data.records] == [0, 1, 2]


def test_a_record_without_a_sinusoid_is_kept_without_analysis(machine, tmp_path):
    rng = np.random.default_rng(3)
    steps = np.repeat(rng.choice([-1.0, 1.0], size=machine["t"].size // 250 + 1), 250)[:machine["t"].size]
    csv = write_csv(tmp_path / "prbs.csv", {"t": machine["t"], "force": steps, "speed": machine["v"]})
    rec = import_records([csv], tmp_path / "r.h5", time="t", input="force", output_column="speed").records[0]
    assert rec.analysis is None and "not a sinusoid" in rec.note
    forced = import_records([csv], tmp_path / "f.h5", time="t", input="force", output_column="speed",
                            frequency=2.0).records[0]
    assert forced.analysis is not None and forced.analysis.frequency == 2.0 and forced.analysis.sine_fraction < 0.8


def good_rows(n=20):
    return ["t,force,speed"] + [f"{i / 1000},{np.sin(i / 10)},{np.cos(i / 10)}" for i in range(n)]


@pytest.mark.parametrize("edit, kwargs, message", [
    (lambda r: r[:5] + ["0.005,nan,1"] + r[6:], {}, "line 6: column 'force' is nan"),
    (lambda r: r[:5] + ["0.005,1,inf"] + r[6:], {}, "line 6: column 'speed' is inf"),
    (lambda r: r[:5] + ["0.003,1,1"] + r[6:], {}, "line 6: t is not strictly increasing"),
    (lambda r: r[:5] + ["0.005,1,abc"] + r[6:], {}, "line 6: column 'speed' is not a number"),
    (lambda r: r[:5] + ["0.005,1"] + r[6:], {}, "line 6: has no value for column 'speed'"),
    (lambda r: ["t,force,velocity"] + r[1:], {}, "no column 'speed' \\(the header has t, force, velocity\\)"),
    (lambda r: r[:5], {}, "needs at least 10 samples"),
    (lambda r: r, {"kind": "acceleration"}, "kind must be velocity or position"),
    (lambda r: r, {"cutoff": 10.0}, "cutoff applies to position records only"),
    (lambda r: r, {"frequency": -1.0}, "frequency must be positive"),
    (lambda r: r[:3] + [f"{0.0021 + 0.0001 * i},1,1" for i in range(1, 30)], {"kind": "position"},
     "sample 2 \\(t = 0.001 s\\): 10 steps after the previous sample \\(a missing sample"),
])
def test_bad_csv_records_are_one_line_user_errors(tmp_path, edit, kwargs, message):
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(edit(good_rows(40))) + "\n")
    out = tmp_path / "out.h5"
    with pytest.raises(UserError, match=message) as info:
        import_records([path], out, time="t", input="force", output_column="speed", **kwargs)
    assert "\n" not in str(info.value) and not out.exists()


def test_bad_files_and_outputs_are_user_errors_that_keep_existing_data(machine, tmp_path):
    good = write_csv(tmp_path / "good.csv", {"t": machine["t"], "force": machine["u"], "speed": machine["v"]})
    out = tmp_path / "r.h5"
    import_records([good], out, time="t", input="force", output_column="speed")
    before = out.read_bytes()
    mat = tmp_path / "m.mat"
    savemat(mat, {"t": machine["t"], "force": machine["u"]})
    bad_mat = tmp_path / "corrupt.mat"
    bad_mat.write_bytes(b"MATLAB 5.0 MAT-file" + b"\0" * 20)
    nan_mat = tmp_path / "nan.mat"
    savemat(nan_mat, {"t": machine["t"], "force": np.where(machine["t"] > 1, np.nan, 1.0), "speed": machine["v"]})
    cases = [
        (dict(paths=[good]), "exists already"),
        (dict(paths=[mat], append=True), "no variable 'speed' \\(the file has force, t\\)"),
        (dict(paths=[nan_mat], append=True), "variable 'force': sample 1002 is NaN or Inf"),
        (dict(paths=[bad_mat], append=True), "not a readable MAT file"),
        (dict(paths=[tmp_path / "x.xlsx"], append=True), "no such file"),
        (dict(paths=[good.with_suffix(".json")], append=True), "no such file"),
        (dict(paths=[good], time="t", input="t", append=True), "three different columns"),
    ]
    (tmp_path / "x.json").write_text("{}")
    cases.append((dict(paths=[tmp_path / "x.json"], append=True), "unknown record format '.json'"))
    for kwargs, message in cases:
        args = dict(time="t", input="force", output_column="speed")
        args.update(kwargs)
        with pytest.raises(UserError, match=message):
            import_records(output=out, **args)
        assert out.read_bytes() == before


@pytest.mark.parametrize("chunk", [1 << 22, 64, 7])
def test_the_csv_scan_counts_lines_across_its_blocks(tmp_path, monkeypatch, chunk):
    """The scan of a CSV file's text (servofmu.measurement.columns) reads it in blocks: a row with a value too many
    is named by its line wherever the blocks end, and comments, blank lines, quotes, a trailing delimiter on every
    line and a last line without its newline are read as numpy reads them."""
    from servofmu.measurement import columns

    monkeypatch.setattr(columns, "_CHUNK", chunk)
    rows = good_rows(40)
    text = "# a comment\n" + "\n".join(r + "," for r in rows[:10]) + "\n\n# another\n" + \
        "\n".join(r + "," for r in rows[10:20]) + '\n"0.019",1,2,\n' + "\n".join(r + "," for r in rows[21:])
    (tmp_path / "ok.csv").write_text(text)
    cols = columns.read_columns(tmp_path / "ok.csv", ["t", "force", "speed"])
    assert cols["t"].size == 40 and cols["t"][19] == 0.019
    lines = text.split("\n")
    lines[30] = lines[30] + "5"  # line 31: a fourth value after the trailing comma
    (tmp_path / "bad.csv").write_text("\n".join(lines))
    with pytest.raises(UserError, match="bad.csv: line 31: 4 values where the header \\(line 2\\) names 3 columns"):
        columns.read_columns(tmp_path / "bad.csv", ["t", "force", "speed"])
