"""The HDF5 store: round trip, plain-h5py readability, atomic replacement, damaged and foreign files."""
from __future__ import annotations

import h5py
import numpy as np
import pytest

import servofmu.measurement.datafile as store
from servofmu.errors import UserError
from servofmu.fileio import partial_path
from servofmu.measurement.datafile import (
    ExperimentResult,
    Record,
    RecordAnalysis,
    Series,
    add_experiments,
    create_measurement,
    mark_complete,
    read_data_file,
    write_records,
)
from servofmu.measurement.excitation import Plan

PLAN = Plan((2.0, 0.6), (1.0, 5.0))
PROVENANCE = {"fmu_sha256": "ab" * 32, "tolerance": 1e-12, "command": "servofmu measure x.fmu -o d.h5", "seed": 3}


def result(index: int, rng) -> ExperimentResult:
    spec = PLAN.experiments[index]
    t = np.linspace(0, 1, 50)
    return ExperimentResult(
        index=index, amplitude=spec.amplitude, frequency=spec.frequency, excitation="builtin",
        U1=complex(spec.amplitude), V1=complex(*rng.normal(size=2)), H=complex(*rng.normal(size=2)),
        dc=float(rng.normal()), harmonics=rng.normal(size=10) + 1j * rng.normal(size=10), distortion=0.1,
        converged=index != 3, settling_time=2.5, last_change=1e-11, remaining_error=3e-12, window_start=2.5,
        window_periods=2, samples_per_period=4096, hold_error=0.0,
        transient=Series(t, np.sin(t), rng.normal(size=50)), window=Series(t + 1, np.cos(t), rng.normal(size=50),
                                                                             v_noisy=rng.normal(size=50)),
        noise_sigma=0.01, H_noisy=1 + 2j, dc_noisy=0.5)


def test_round_trip_and_plain_h5py_layout(tmp_path):
    path = tmp_path / "d.h5"
    rng = np.random.default_rng(0)
    create_measurement(path, PLAN, PROVENANCE, {"pole1": -10.0, "fc_pos": 0.5})
    written = [result(i, rng) for i in (2, 0, 3)]
    for r in written:
        add_experiments(path, [r])
    data = read_data_file(path)
    assert data.kind == "measurement" and not data.complete and data.plan == PLAN
    assert [s.index for s in data.missing()] == [1]
    assert data.parameters == {"pole1": -10.0, "fc_pos": 0.5}
    assert data.provenance["seed"] == 3 and data.provenance["tolerance"] == 1e-12
    for r in written:
        back = data.experiment(r.amplitude, r.frequency)
        for name in ("index", "H", "V1", "U1", "dc", "converged", "window_start", "window_periods", "H_noisy"):
            assert getattr(back, name) == getattr(r, name), name
        np.testing.assert_array_equal(back.harmonics, r.harmonics)
        np.testing.assert_array_equal(back.window.v_noisy, r.window.v_noisy)
        np.testing.assert_array_equal(back.transient.v, r.transient.v)
        assert back.transient.v_noisy is None
    mark_complete(path)
    assert read_data_file(path).complete

    # the same file through h5py alone, as docs/hdf5.md describes it
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "servofmu-data" and f.attrs["schema_version"] == 2
        assert f.attrs["kind"] == "measurement" and bool(f.attrs["complete"])
        np.testing.assert_array_equal(f["plan/amplitude"][()], [2.0, 2.0, 0.6, 0.6])
        np.testing.assert_array_equal(f["plan/frequency"][()], [1.0, 5.0, 1.0, 5.0])
        g = f["experiments/exp_0002"]
        assert g.attrs["H"] == written[0].H and g.attrs["amplitude"] == 0.6
        assert g["window/v"].attrs["unit"] == "m/s" and g["window/time"].attrs["unit"] == "s"
        assert f["provenance"].attrs["fmu_sha256"] == "ab" * 32
        assert f["provenance/parameters"].attrs["pole1"] == -10.0


def test_an_experiment_stored_twice_is_kept_once(tmp_path):
    path = tmp_path / "d.h5"
    rng = np.random.default_rng(1)
    create_measurement(path, PLAN, PROVENANCE, {})
    first = result(1, rng)
    add_experiments(path, [first])
    add_experiments(path, [result(1, rng)])
    data = read_data_file(path)
    assert len(data.experiments) == 1 and data.experiments[0].H == first.H


def test_a_failed_write_leaves_the_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "d.h5"
    rng = np.random.default_rng(2)
    create_measurement(path, PLAN, PROVENANCE, {})
    add_experiments(path, [result(0, rng)])
    before = path.read_bytes()

    def broken(group, series):  # dies in the middle of writing an experiment
        raise KeyboardInterrupt

    monkeypatch.setattr(store, "_write_series", broken)
    with pytest.raises(KeyboardInterrupt):
        add_experiments(path, [result(1, rng)])
    assert path.read_bytes() == before
    assert not partial_path(path).exists()
    assert len(read_data_file(path).experiments) == 1


def test_a_stale_partial_file_from_a_killed_run_is_harmless(tmp_path):
    path = tmp_path / "d.h5"
    create_measurement(path, PLAN, PROVENANCE, {})
    partial_path(path).write_bytes(b"half a file")
    add_experiments(path, [result(0, np.random.default_rng(3))])
    assert len(read_data_file(path).experiments) == 1 and not partial_path(path).exists()


@pytest.mark.parametrize("damage, message", [
    ("truncate", "not a readable data file"),
    ("text", "not a readable data file"),
    ("foreign", "not a servofmu data file"),
    ("newer", "schema version 99 is not supported"),
    ("no_kind", "damaged servofmu data file"),
    ("bad_experiment", "damaged servofmu data file"),
    ("edited", r"damaged data file \(its content does not match the digest it was written with"),
    ("missing", "no such data file"),
])
def test_damaged_or_foreign_files_are_user_errors(tmp_path, damage, message):
    path = tmp_path / "d.h5"
    create_measurement(path, PLAN, PROVENANCE, {})
    add_experiments(path, [result(0, np.random.default_rng(4))])
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:3000])
    elif damage == "text":
        path.write_text("time,u,v\n0,0,0\n")
    elif damage == "foreign":
        path.unlink()
        with h5py.File(path, "w") as f:
            f.create_dataset("x", data=[1.0])
    elif damage == "missing":
        path.unlink()
    else:
        with h5py.File(path, "r+") as f:
            if damage == "newer":
                f.attrs["schema_version"] = 99
            elif damage == "no_kind":
                del f.attrs["kind"]
            else:
                del f["experiments/exp_0000"].attrs["H"]
            if damage != "edited":  # as a file without the digest (an older servofmu's) has it: the reader's checks
                del f.attrs["content_sha256"]
    with pytest.raises(UserError, match=message) as info:
        read_data_file(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_records_file_and_append(tmp_path):
    path = tmp_path / "r.h5"
    t = np.arange(100) / 100.0
    analysis = RecordAnalysis(frequency=2.0, sine_fraction=0.99, amplitude=1.0, U1=1 + 0j, V1=0.5 - 0.2j,
                              H=0.5 - 0.2j, dc_u=0.0, dc=0.01, harmonics=np.ones(5, complex), distortion=0.02,
                              converged=True, settling_time=0.5, window_start=0.5, window_periods=1)

    def rec(name, with_analysis):
        return Record(index=0, name=name, source=f"{name}.csv", source_sha256="0" * 64, kind="position",
                      columns={"time": "t", "u": "force", "position": "x"},
                      series=Series(t, np.sin(t), np.cos(t), position=np.sin(t)), sample_rate=100.0,
                      velocity_estimate="filtered", velocity_cutoff=10.0,
                      analysis=analysis if with_analysis else None, note="" if with_analysis else "not a sine")

    write_records(path, [rec("a", True)], {"command": "import a"})
    with pytest.raises(UserError, match="exists already"):
        write_records(path, [rec("b", False)], {"command": "import b"})
    write_records(path, [rec("b", False)], {"command": "import b"}, append=True)
    data = read_data_file(path)
    assert data.kind == "records" and [r.name for r in data.records] == ["a", "b"]
    assert [r.index for r in data.records] == [0, 1]
    a, b = data.records
    for name in ("frequency", "sine_fraction", "U1", "V1", "H", "dc", "converged", "window_start", "window_periods"):
        assert getattr(a.analysis, name) == getattr(analysis, name), name
    np.testing.assert_array_equal(a.analysis.harmonics, analysis.harmonics)
    assert b.analysis is None and b.note == "not a sine"
    np.testing.assert_array_equal(a.series.position, np.sin(t))
    assert a.columns == {"time": "t", "u": "force", "position": "x"}
    assert data.provenance["appended_by"] == '["import b"]'
    # appending to a measurement file is refused and leaves it alone
    m = tmp_path / "m.h5"
    create_measurement(m, PLAN, PROVENANCE, {})
    before = m.read_bytes()
    with pytest.raises(UserError, match="records can only be appended to a records file"):
        write_records(m, [rec("c", False)], {"command": "import c"}, append=True)
    assert m.read_bytes() == before
