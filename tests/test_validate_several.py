"""`servofmu validate A.h5 B.h5 DATA.h5`: several models on the same data, one column each — the same fits and
verdicts as each model's own `validate`, the page's table and figures with every model, the exit status of the worst
model; and the API's compare_models on the same files giving the same table."""
from __future__ import annotations

import json

import pytest
from clitools import assert_one_line_error, run

import servofmu as sf


@pytest.fixture(scope="module")
def two_results(built_fmu, tmp_path_factory):
    folder = tmp_path_factory.mktemp("several")
    assert run("measure", built_fmu("g1"), "--amplitudes", "2,0.6", "--frequencies", "0.5,2,10", "-o",
               folder / "g1.h5").returncode == 0
    for name, seed in (("good", 0), ("rough", 3)):  # a short swarm without polish: a poorer model
        extra = () if name == "good" else ("--iterations", "4", "--no-polish")
        proc = run("identify", folder / "g1.h5", "--structure", "g1", "--seed", seed, *extra, "-o",
                   folder / f"{name}.h5")
        assert proc.returncode == 0, proc.stderr
    return folder


def test_several_results_in_one_table_with_each_ones_own_fits(two_results):
    f = two_results
    proc = run("validate", f / "good.h5", f / "rough.h5", f / "g1.h5", "--json", "-o", f / "both.html")
    table = json.loads(proc.stdout)
    assert table["models"] == ["good", "rough"]
    alone = {name: json.loads(run("validate", f / f"{name}.h5", f / "g1.h5", "--json").stdout)
             for name in ("good", "rough")}
    for name, own in alone.items():
        fits = [e["fit_percent"] for e in own["experiments"]]
        assert table["table"]["fit % (worst)"][name] == pytest.approx(min(fits), rel=1e-12)
        assert table["table"]["verdict"][name] == ("passed" if own["passed"] else "failed")
        assert table["validations"][name]["experiments"] == own["experiments"]
    assert table["table"]["fit % (mean)"]["good"] > table["table"]["fit % (mean)"]["rough"]
    assert proc.returncode == (0 if all(a["passed"] for a in alone.values()) else 1)
    assert set(table["table"]) >= {"pole1", "dc_gain", "fc_pos", "fc_neg"}
    page = (f / "both.html").read_text()
    assert page.count("<th>good</th>") == 1 and page.count("<th>rough</th>") == 1
    assert page.count("<img") >= 2
    # the API on the same files: the same table
    results = {name: sf.read_result(f / f"{name}.h5") for name in ("good", "rough")}
    api = sf.compare_models(results, f / "g1.h5").table()
    assert api["fit % (mean)"] == pytest.approx(table["table"]["fit % (mean)"], rel=1e-12)
    assert api["pole1"] == table["table"]["pole1"]


def test_a_png_of_several_and_the_errors(two_results):
    f = two_results
    proc = run("validate", f / "good.h5", f / "rough.h5", f / "g1.h5", "-o", f / "both.png")
    assert proc.returncode in (0, 1) and (f / "both.png").read_bytes()[:4] == b"\x89PNG"
    assert "fit % (mean)" in proc.stdout and "good" in proc.stdout and "rough" in proc.stdout
    assert_one_line_error(run("validate", f / "good.h5", f / "rough.h5", f / "g1.h5", "-o", f / "both.txt"),
                          "both.txt", ".html page or a .png figure")
    assert_one_line_error(run("validate", f / "good.h5", f / "nothing.h5", f / "g1.h5"), "nothing.h5")
