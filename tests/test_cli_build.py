"""`servofmu build` and `servofmu simulate` from the command line: outputs and one-line errors."""
import zipfile

import numpy as np
import pytest
from clitools import assert_one_line_error, run

G1_TEXT = """name = "p"
[linear]
poles = [[-10.0, 0.0]]
zeros = []
dc_gain = 1.0
[friction]
model = "coulomb"
fc_pos = 0.5
fc_neg = 0.4
"""


def test_build_then_simulate_csv(tmp_path):
    fmu = tmp_path / "g1.fmu"
    proc = run("build", "g1", "--fmi-version", "2", "-o", str(fmu))
    assert proc.returncode == 0, proc.stderr
    assert zipfile.is_zipfile(fmu)
    names = zipfile.ZipFile(fmu).namelist()
    assert "sources/buildDescription.xml" in names and "documentation/index.html" in names
    out = tmp_path / "out.csv"
    proc = run("simulate", str(fmu), "--interface", "cs", "--amplitude", "2", "--frequency", "1",
               "--stop-time", "2", "--output-interval", "0.01", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data.dtype.names == ("time", "v", "position", "friction_force")
    assert len(data) == 201 and np.abs(data["v"]).max() > 0.5
    # position is the integral of v
    assert np.isclose(data["position"][-1], np.trapezoid(data["v"], data["time"]), atol=1e-3)


def test_simulate_from_input_csv(tmp_path):
    fmu = tmp_path / "g1.fmu"
    assert run("build", "g1", "-o", str(fmu)).returncode == 0
    table = tmp_path / "u.csv"
    table.write_text("time,u\n0,1.0\n5,1.0\n")
    out = tmp_path / "out.csv"
    proc = run("simulate", str(fmu), "--input", str(table), "--stop-time", "5", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    data = np.genfromtxt(out, delimiter=",", names=True)
    # a constant force 1.0 against Coulomb 0.5 settles at v = G(0)·(1 − 0.5) = 0.5
    assert np.isclose(data["v"][-1], 0.5, atol=1e-6)


@pytest.mark.parametrize("text, key", [
    (G1_TEXT.replace("fc_neg = 0.4", "fc_neg = 0.4\nmu = 1"), "friction.mu"),
    (G1_TEXT.replace("[[-10.0, 0.0]]", "[[-1.0, 2.0]]"), "linear.poles"),
    (G1_TEXT.replace("[[-10.0, 0.0]]", "[[10.0, 0.0]]"), "linear.poles"),
    (G1_TEXT.replace("zeros = []", "zeros = [[-1.0, 0.0]]"), "linear.zeros"),
    (G1_TEXT.replace("fc_pos = 0.5", "fc_pos = -0.5"), "friction.fc_pos"),
    (G1_TEXT.replace('"coulomb"', '"stribeck"') + "fs_pos = 0.1\nfs_neg = 0.5\nvs = 0.1\n", "friction.fs_pos"),
])
def test_build_rejects_bad_plant_file(tmp_path, text, key):
    plant = tmp_path / "bad.toml"
    plant.write_text(text)
    proc = run("build", str(plant), "-o", str(tmp_path / "x.fmu"))
    assert_one_line_error(proc, "bad.toml", key)
    assert not (tmp_path / "x.fmu").exists()


def test_build_without_compiler(tmp_path):
    proc = run("build", "g1", "-o", str(tmp_path / "x.fmu"), env={"CC": "/nonexistent/cc"})
    assert_one_line_error(proc, "no C compiler")
    assert not (tmp_path / "x.fmu").exists()


def test_build_into_missing_folder(tmp_path):
    proc = run("build", "g1", "-o", str(tmp_path / "missing" / "x.fmu"))
    assert_one_line_error(proc, "does not exist")


def test_failed_build_keeps_existing_file(tmp_path):
    target = tmp_path / "x.fmu"
    target.write_bytes(b"precious")
    proc = run("build", "g1", "-o", str(target), env={"CC": "/nonexistent/cc"})
    assert proc.returncode != 0 and target.read_bytes() == b"precious"


def test_simulate_rejects_non_zip(tmp_path):
    bogus = tmp_path / "model.fmu"
    bogus.write_text("not a zip")
    assert_one_line_error(run("simulate", str(bogus), "--stop-time", "1"), "model.fmu", "not an FMU")


@pytest.mark.parametrize("table, fragment", [
    ("time,u\n0,1\n1,nan\n", "NaN or Inf"),
    ("time,u\n0,1\n1,1\n0.5,1\n", "not strictly increasing"),
    ("t,u\n0,1\n1,1\n", "missing column 'time'"),
])
def test_simulate_rejects_bad_input_table(tmp_path, table, fragment):
    fmu = tmp_path / "g1.fmu"
    assert run("build", "g1", "-o", str(fmu)).returncode == 0
    path = tmp_path / "u.csv"
    path.write_text(table)
    assert_one_line_error(run("simulate", str(fmu), "--input", str(path), "--stop-time", "1"), "u.csv", fragment)


def test_bad_option_is_one_line():
    assert_one_line_error(run("build", "g1", "--fmi-version", "4"), "--fmi-version")
