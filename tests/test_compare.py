"""`servofmu compare`: all methods side by side, and its refusals of bad input."""
import json

import numpy as np
import pytest
from clitools import assert_one_line_error, run

from servofmu.measurement.measure import measure
from servofmu.runtime import RunOptions


@pytest.fixture(scope="module")
def g1_data(tmp_path_factory, built_fmu):
    path = tmp_path_factory.mktemp("compare") / "g1.h5"
    measure(built_fmu("g1", 3), path, amplitudes=[2.0, 0.6], frequencies=[0.5, 2.0, 10.0], run=RunOptions(workers=0))
    return path


def test_compare_json_and_table(g1_data, tmp_path):
    out = tmp_path / "table.md"
    proc = run("compare", g1_data, "--structure", "g1", "--truth", "g1", "--methods", "pso,chen2002", "--json",
               "-o", out)
    assert proc.returncode == 0, proc.stderr
    obj = json.loads(proc.stdout)
    assert list(obj) == ["pso", "chen2002"]
    assert obj["pso"]["max_relative_error"] < 1e-6
    # Chen 2002's describing-function approximation is far less exact (the paper's column: 2-25 %)
    assert 1e-3 < obj["chen2002"]["max_relative_error"] < 0.5
    assert np.isclose(obj["pso"]["parameters"]["poles"][0][0], -10.0, rtol=1e-6)
    table = out.read_text()
    assert table.startswith("| parameter | target | pso | chen2002 |")
    assert "| max relative error |" in table and "| model evaluations |" in table


def test_truth_with_another_structure(g1_data, tmp_path):
    proc = run("compare", g1_data, "--structure", "g1", "--truth", "g2", "--methods", "pso")
    assert_one_line_error(proc, "another structure")


def test_unknown_method(g1_data):
    assert_one_line_error(run("compare", g1_data, "--structure", "g1", "--methods", "pso,simplex"),
                          "unknown method 'simplex'")


def test_chen2002_needs_two_magnitudes(tmp_path, built_fmu):
    one = tmp_path / "one.h5"
    measure(built_fmu("g1", 3), one, amplitudes=[2.0], frequencies=[0.5, 2.0], run=RunOptions(workers=0))
    assert_one_line_error(run("compare", one, "--structure", "g1", "--methods", "chen2002"), "one.h5",
                          "two or more excitation magnitudes")
