"""Inputs a third probe found accepted silently or refused unclearly (its classes 7 and 8, and of class 4 a tune task
that never moves), each reproduced with a file a few kB long.  A test is named after the probe's class:
``test_c7_...`` is of class 7.  Every refusal is one line naming the file, the line or key, and the option, exit
status 2, and nothing written."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from harness import assert_one_line, run_here

IMPORT = ["--time", "time", "--input", "u", "--output-variable", "v", "-o", "out.h5"]


def record(n: int = 400) -> np.ndarray:
    """time, u, v of a short sinusoidal record (first-order response)."""
    t = np.arange(n) * 1e-3
    u = 2.0 * np.sin(2 * np.pi * 10.0 * t)
    v = np.zeros_like(t)
    for i in range(1, n):
        v[i] = v[i - 1] + 1e-3 * (-10 * v[i - 1] + 10 * u[i - 1])
    return np.column_stack([t, u, v])


def write_csv(path: Path, header: str = "time,u,v", rows: np.ndarray | None = None) -> Path:
    rows = record() if rows is None else rows
    path.write_text(header + "\n" + "\n".join(",".join(f"{x:.17g}" for x in row) for row in rows) + "\n")
    return path


def imported(folder: Path, *files, extra=()) -> tuple[int, str]:
    return run_here(["import", *files, *IMPORT, *extra], folder)


def assert_refused(folder: Path, argv, *fragments, before: set[str]) -> None:
    rc, err = run_here(argv, folder)
    assert_one_line(err, rc, 2, *fragments)
    assert {p.name for p in folder.iterdir()} == before, "a refused run wrote a file"


# ---- 7. silently accepted: CSV ---------------------------------------------------------------------------------
def test_c7_a_duplicated_header_name_is_refused(tmp_path):
    rows = record()
    write_csv(tmp_path / "dup.csv", "time,u,v,u", np.column_stack([rows, 2 * rows[:, 1]]))
    assert_refused(tmp_path, ["import", "dup.csv", *IMPORT], "dup.csv", "line 1", "'u' (--input)", "2 times",
                   "columns 2, 4", before={"dup.csv"})


def test_c7_a_row_with_an_extra_value_is_refused(tmp_path):
    lines = write_csv(tmp_path / "ragged.csv").read_text().splitlines()
    lines[5] += ",7"
    (tmp_path / "ragged.csv").write_text("\n".join(lines) + "\n")
    assert_refused(tmp_path, ["import", "ragged.csv", *IMPORT], "ragged.csv", "line 6", "4 values",
                   "names 3 columns", before={"ragged.csv"})


# ---- 7. silently accepted: MAT ---------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(40, 10), (2, 4, 50)])
def test_c7_a_mat_variable_of_more_than_one_dimension_is_refused(tmp_path, shape):
    from scipy.io import savemat

    rows = record()
    savemat(tmp_path / "m.mat", {"time": rows[:, 0], "u": rows[:, 1].reshape(shape), "v": rows[:, 2]})
    assert_refused(tmp_path, ["import", "m.mat", *IMPORT], "m.mat", "variable 'u' (--input)",
                   "×".join(map(str, shape)), before={"m.mat"})


def test_c7_a_mat_column_or_row_vector_is_read(tmp_path):
    from scipy.io import savemat

    rows = record()
    savemat(tmp_path / "m.mat", {"time": rows[:, :1], "u": rows[:, 1][None, :], "v": rows[:, 2]})
    rc, err = imported(tmp_path, "m.mat")
    assert rc == 0, err


def test_c7_a_complex_mat_variable_is_refused(tmp_path):
    from scipy.io import savemat

    rows = record()
    savemat(tmp_path / "c.mat", {"time": rows[:, 0], "u": rows[:, 1] * (1 + 1j), "v": rows[:, 2]})
    assert_refused(tmp_path, ["import", "c.mat", *IMPORT], "c.mat", "variable 'u' (--input)", "complex",
                   before={"c.mat"})


# ---- 8. unclear messages: CSV encodings, a header without values, a scale beyond the floats ---------------------
def test_c8_a_byte_order_mark_is_dropped(tmp_path):
    text = write_csv(tmp_path / "x.csv").read_text()
    (tmp_path / "bom.csv").write_text(text, encoding="utf-8-sig")
    rc, err = imported(tmp_path, "bom.csv")
    assert rc == 0, err
    from servofmu.measurement.datafile import read_data_file

    assert np.array_equal(read_data_file(tmp_path / "out.h5").records[0].series.u, record()[:, 1])


def test_c8_a_latin1_header_is_read(tmp_path):
    text = write_csv(tmp_path / "x.csv", "time,u,v µm/s").read_text()
    (tmp_path / "latin.csv").write_bytes(text.encode("latin-1"))
    rc, err = run_here(["import", "latin.csv", "--time", "time", "--input", "u", "--output-variable", "v µm/s", "-o",
                        "out.h5"], tmp_path)
    assert rc == 0, err


def test_c8_a_binary_file_named_csv_is_not_text(tmp_path):
    (tmp_path / "bin.csv").write_bytes(b"\x89HDF\r\n\x1a\n\0\0\0\0" * 10)
    assert_refused(tmp_path, ["import", "bin.csv", *IMPORT], "bin.csv", "not a text (CSV) file",
                   before={"bin.csv"})


def test_c8_a_header_only_csv_is_one_clean_line(tmp_path):
    (tmp_path / "hdr.csv").write_text("time,u,v\n")
    assert_refused(tmp_path, ["import", "hdr.csv", *IMPORT], "hdr.csv", "no values after the header (line 1)",
                   before={"hdr.csv"})


def test_c8_a_missing_column_names_its_option(tmp_path):
    write_csv(tmp_path / "x.csv", "time,u,speed")
    assert_refused(tmp_path, ["import", "x.csv", *IMPORT], "x.csv", "no column 'v'", "--output-variable",
                   before={"x.csv"})


@pytest.mark.parametrize("option", ["--input-scale", "--disturbance-scale"])
def test_c8_a_scale_beyond_the_floats_names_the_file_and_option(tmp_path, option):
    rows = record()
    write_csv(tmp_path / "log.csv", "time,u,v,d", np.column_stack([rows, rows[:, 1]]))
    assert_refused(tmp_path, ["import", "log.csv", *IMPORT, "--disturbance", "d", option, "1e308"], "log.csv",
                   option, "1e+308", before={"log.csv"})


# ---- 7. silently accepted: one measurement counted twice -------------------------------------------------------
def test_c7_a_record_appended_again_is_refused_and_the_file_kept(tmp_path):
    write_csv(tmp_path / "a.csv")
    rc, err = imported(tmp_path, "a.csv")
    assert rc == 0, err
    before = (tmp_path / "out.h5").read_bytes()
    assert_refused(tmp_path, ["import", "a.csv", *IMPORT, "--append"], "a.csv", "record 'a' of out.h5 (--append)",
                   "the same samples", before={"a.csv", "out.h5"})
    assert (tmp_path / "out.h5").read_bytes() == before


def test_c7_one_csv_given_twice_under_two_names_is_refused(tmp_path):
    write_csv(tmp_path / "a.csv")
    (tmp_path / "b.csv").write_bytes((tmp_path / "a.csv").read_bytes())
    assert_refused(tmp_path, ["import", "a.csv", "b.csv", *IMPORT], "b.csv", "the same samples as a.csv",
                   before={"a.csv", "b.csv"})


def records_files(folder: Path, *names: str) -> None:
    """NAME.h5 for each name: the record of write_csv imported (the same samples in each) — or, for a name
    ending in "still", a record whose velocity is zero throughout."""
    for name in names:
        rows = record()
        if name.endswith("still"):
            rows[:, 2] = 0.0
        write_csv(folder / f"{name}.csv", rows=rows)
        rc, err = run_here(["import", f"{name}.csv", *IMPORT[:-1], f"{name}.h5"], folder)
        assert rc == 0, err
        (folder / f"{name}.csv").unlink()


SELECT = ["--candidates", "coulomb/1", "--iterations", "2", "--workers", "0", "-o", "s.h5"]


def test_c7_one_measurement_given_twice_to_select_is_refused(tmp_path):
    records_files(tmp_path, "a", "b", "other_still")
    assert_refused(tmp_path, ["select", "a.h5", "b.h5", "--validate", "other_still.h5", *SELECT], "record 'b' of b.h5",
                   "record 'a' of a.h5", "give each measurement once", before={"a.h5", "b.h5", "other_still.h5"})


def test_c7_a_validation_file_that_is_the_fitted_data_is_refused(tmp_path):
    records_files(tmp_path, "a", "copy")
    assert_refused(tmp_path, ["select", "a.h5", "--validate", "copy.h5", *SELECT], "copy.h5 (--validate)",
                   "record 'a' of a.h5, which is fitted", before={"a.h5", "copy.h5"})


def test_c7_a_validation_record_that_never_moves_is_refused(tmp_path):
    records_files(tmp_path, "a", "still")
    assert_refused(tmp_path, ["select", "a.h5", "--validate", "still.h5", *SELECT], "still.h5 (--validate)",
                   "record 'still'", "never moves", before={"a.h5", "still.h5"})


def test_c7_identify_refuses_a_records_file_holding_one_record_twice(tmp_path):
    """A file written before imports were checked (or by another program) with one record twice."""
    from servofmu.measurement.datafile import read_data_file, write_records

    records_files(tmp_path, "a")
    write_records(tmp_path / "a.h5", [read_data_file(tmp_path / "a.h5").records[0]], {"command": "again"},
                  append=True)
    assert_refused(tmp_path, ["identify", "a.h5", "--structure", "g1", "--method", "pso", "-o", "r.h5"],
                   "record 'a' of a.h5 holds the same samples as record 'a' of a.h5", before={"a.h5"})


# ---- 8. unclear messages: a structure with nothing to identify --------------------------------------------------
def test_c8_a_structure_that_fixes_every_parameter_says_nothing_is_left(tmp_path):
    from servofmu.model.plant import example_files

    records_files(tmp_path, "a")
    (tmp_path / "all.toml").write_text('fixed = ["pole1", "dc_gain", "fc_pos", "fc_neg"]\n'
                                       + example_files()["g1"].read_text())
    for command in (["identify", "a.h5", "--structure", "all.toml", "--method", "pso", "-o", "r.h5"],
                    ["compare", "a.h5", "--structure", "all.toml", "--methods", "pso", "-o", "r.h5"]):
        assert_refused(tmp_path, command, "all.toml: fixed", "nothing is left to identify", "--structure",
                       before={"a.h5", "all.toml"})


# ---- 8. unclear messages: tune's speed beyond its loop, a selection file where one result is read -------------
def axis_files(folder: Path) -> None:
    """axis-result.h5 (the example axis at its true values) and ctrl.toml (its example controller)."""
    from servofmu.identification.prior import identified_mask, identified_names
    from servofmu.identification.results import Result, Stage, write_result
    from servofmu.model.plant import example_files, load_plant

    axis = load_plant("linear_axis")
    theta = axis.parameter_vector()[identified_mask(axis)]
    write_result(folder / "axis-result.h5", Result(
        method="pso", structure=axis, plant=axis, names=tuple(identified_names(axis)), theta=theta,
        intervals=np.column_stack([theta, theta]), fitness=0.0, seconds=0.0, evaluations=0,
        stages=(Stage("pso", None, 0.0, 0.0, 0),), history=np.zeros(1), provenance={}))
    (folder / "ctrl.toml").write_text(example_files()["axis_controller"].read_text())


TUNE = ["--particles", "4", "--iterations", "2", "-o", "T.toml"]


def test_c8_a_speed_beyond_the_loop_names_the_option(tmp_path):
    axis_files(tmp_path)
    assert_refused(tmp_path, ["tune", "axis-result.h5", "ctrl.toml", "--speed", "1e9", *TUNE], "--speed 1e+09",
                   "faster than a loop sampled every 0.001 s", before={"axis-result.h5", "ctrl.toml"})


def selection_file(folder: Path) -> Path:
    """S.h5 as select writes it, reduced to what the readers look at: a comparison of two candidates' results with
    select's ranking (/selection) beside them."""
    from hdf5edit import edit_hdf5

    from servofmu.identification.results import read_result, write_comparison

    result = read_result(folder / "axis-result.h5")
    write_comparison(folder / "S.h5", {"coulomb_1": result, "coulomb_2": result})
    return edit_hdf5(folder / "S.h5", lambda f: f.create_group("selection").attrs.update(
        {"format": "servofmu-selection", "schema_version": 1}))


@pytest.mark.parametrize("command", ["tune", "validate", "export"])
def test_c8_a_selection_file_where_one_result_is_read_says_what_it_is(tmp_path, command):
    axis_files(tmp_path)
    selection_file(tmp_path)
    records_files(tmp_path, "a")
    argv = {"tune": ["tune", "S.h5", "ctrl.toml", *TUNE], "validate": ["validate", "S.h5", "a.h5", "-o", "v.html"],
            "export": ["export", "S.h5", "-o", "e.toml"]}[command]
    assert_refused(tmp_path, argv, "S.h5: is a selection file", "S-result.h5", "--result",
                   before={"axis-result.h5", "ctrl.toml", "S.h5", "a.h5"})


def test_c8_a_log_off_the_controllers_sample_time_names_the_file(tmp_path):
    axis_files(tmp_path)
    t = np.arange(0, 1, 2e-3)
    r = 0.01 * (1 - np.cos(2 * np.pi * t))
    write_csv(tmp_path / "log.csv", "time,u,x,ref", np.column_stack([t, np.sin(2 * np.pi * t), 0.99 * r, r]))
    rc, err = run_here(["import", "log.csv", "--time", "time", "--input", "u", "--output-variable", "x", "--kind",
                        "position", "--reference", "ref", "-o", "log.h5"], tmp_path)
    assert rc == 0, err
    before = {"axis-result.h5", "ctrl.toml", "log.csv", "log.h5"}
    for argv in (["identify", "log.h5", "--structure", "linear_axis", "--closed-loop", "ctrl.toml", "-o", "r.h5"],
                 ["validate", "axis-result.h5", "log.h5", "--closed-loop", "ctrl.toml", "-o", "v.html"]):
        assert_refused(tmp_path, argv, "log.h5: record log: sample 2", "0.002 s apart",
                       "sample_time is 0.001 s (--closed-loop)", before=before)


# ---- 4. a tune task that never moves -----------------------------------------------------------------------------
def test_c4_a_tune_task_that_never_moves_is_refused_and_the_old_output_kept(tmp_path):
    axis_files(tmp_path)
    t = np.arange(0, 1.0005, 1e-3)
    np.savetxt(tmp_path / "still.csv", np.column_stack([t, 0 * t]), delimiter=",", header="time,position",
               comments="")
    (tmp_path / "T.toml").write_text("the previous output\n")
    assert_refused(tmp_path, ["tune", "axis-result.h5", "ctrl.toml", "--task", "still.csv", *TUNE, "--force",
                              "--report", "T.html"], "still.csv", "stays at 0 m", "--task",
                   before={"axis-result.h5", "ctrl.toml", "still.csv", "T.toml"})
    assert (tmp_path / "T.toml").read_text() == "the previous output\n"


def test_c7_validate_says_when_the_data_is_the_fitted_data_imported_again(tmp_path):
    """`validate` on a file whose record is one the identification fitted, imported again (other bytes, other
    name): the verdict says it shows the fit (it said so only for the very file identified from)."""
    import json
    import subprocess
    import sys

    from harness import command_env

    from servofmu.identification.inputs import identification_provenance
    from servofmu.identification.prior import identified_mask, identified_names
    from servofmu.identification.results import Result, Stage, write_result
    from servofmu.measurement.datafile import read_data_file
    from servofmu.model.plant import load_plant

    records_files(tmp_path, "a", "again")
    rows = record()
    rows[:, 1] *= 0.5
    write_csv(tmp_path / "other.csv", rows=rows)
    assert run_here(["import", "other.csv", *IMPORT[:-1], "other.h5"], tmp_path)[0] == 0
    g1 = load_plant("g1")
    theta = g1.parameter_vector()[identified_mask(g1)]
    write_result(tmp_path / "r.h5", Result(
        method="pso", structure=g1, plant=g1, names=tuple(identified_names(g1)), theta=theta,
        intervals=np.column_stack([theta, theta]), fitness=0.0, seconds=0.0, evaluations=0,
        stages=(Stage("pso", None, 0.0, 0.0, 0),), history=np.zeros(1),
        provenance=identification_provenance(read_data_file(tmp_path / "a.h5"), "g1", "identify a.h5")))
    for name, own in (("again", True), ("other", False)):
        proc = subprocess.run([sys.executable, "-m", "servofmu", "validate", "r.h5", f"{name}.h5", "--json"],
                              cwd=tmp_path, env=command_env(), capture_output=True, text=True)
        assert proc.returncode in (0, 1) and "Traceback" not in proc.stderr, proc.stderr
        assert json.loads(proc.stdout)["own_data"] is own, name
