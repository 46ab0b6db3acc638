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
