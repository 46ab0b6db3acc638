"""`servofmu report` and `servofmu validate`: the HTML pages opened in headless Chromium (Debian's chromium and
chromium-driver, installed by scripts/test.sh), their tables checked against the result and data files read with
h5py, intervals with distinct bounds, measured Bode points drawn as unjoined markers (found in the SVG), residual
plots, images decoded, no console errors; the friction curve against the friction formulas of docs/model.md;
refusals of bad input; validate's verdict on a right and a wrong model (exit status 0 and 1)."""
import base64
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import replace

import h5py
import numpy as np
import pytest
from browser import chromium
from clitools import assert_one_line_error, run

from servofmu.identification.criterion import POLISH_RTOL, sine_data
from servofmu.identification.results import read_result, read_results, write_comparison, write_result
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.measure import MeasureOptions, measure
from servofmu.runtime import RunOptions
from servofmu.model.plant import load_plant
from servofmu.baselines.compare import run_methods
from servofmu.fileio import file_sha256
from servofmu.model.friction import steady_friction
from hdf5edit import edit_hdf5

PLAN = {"amplitudes": [2.0, 0.6], "frequencies": [0.5, 2.0, 10.0]}
# The "true" plant the report is given: g1 with other values, so that every relative error is large and known.
TRUTH_TOML = """name = "g1_other"
[linear]
poles = [[-11.0, 0.0]]
zeros = []
dc_gain = 1.25
[friction]
model = "coulomb"
fc_pos = 0.55
fc_neg = 0.3
"""
TRUTH = {"pole1": -11.0, "dc_gain": 1.25, "fc_pos": 0.55, "fc_neg": 0.3}


@pytest.fixture(scope="module")
def g1_result(tmp_path_factory, built_fmu):
    """g1 measured through its FMU, identified by PSO alone (RESULT.h5) and compared with Chen 2002 (COMPARE.h5);
    the files record the data file by its name."""
    folder = tmp_path_factory.mktemp("report")
    data = folder / "g1.h5"
    measure(built_fmu("g1", 3), data, run=RunOptions(workers=0), **PLAN)
    provenance = {"data_file": "g1.h5", "data_sha256": file_sha256(data), "command": "test",
                  "date": "2024-01-01T00:00:00Z"}
    results = run_methods(load_plant("g1"), sine_data(read_data_file(data)), ["pso", "chen2002"], seed=0,
                          provenance=provenance)
    write_result(folder / "g1-result.h5", results["pso"])
    write_comparison(folder / "g1-compare.h5", results)
    (folder / "truth.toml").write_text(TRUTH_TOML)
    return {"folder": folder, "data": data, "result": folder / "g1-result.h5", "compare": folder / "g1-compare.h5",
            "truth": folder / "truth.toml"}


@pytest.fixture(scope="module")
def report(g1_result, tmp_path_factory):
    """The report made by the CLI from another working folder (the data file is found beside the result)."""
    out = tmp_path_factory.mktemp("elsewhere") / "report.html"
    proc = run("report", g1_result["result"], "--truth", g1_result["truth"], "-o", out, cwd=out.parent)
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_size > 0
    return out


@pytest.fixture(scope="module")
def browser():
    with chromium() as driver:
        yield driver


def interval_bounds(text: str) -> tuple[float, float]:
    """The bounds a reader reads off an interval cell: "v ± h" or "[lo, hi]"."""
    if text.startswith("["):
        lo, hi = text.strip("[]").split(",")
        return float(lo), float(hi)
    value, half = text.split(" ± ")
    return float(value) - float(half), float(value) + float(half)


def measured_markers(src: str) -> int:
    """The number of measured points drawn in an SVG figure (a data: URI): marker elements (<use>) in the groups
    of the measured series ("measured-…").  Fails when a measured series is drawn as a line (a path with line
    segments outside the marker's definition) or has no markers."""
    assert src.startswith("data:image/svg+xml;base64,")
    root = ET.fromstring(base64.b64decode(src.split(",", 1)[1]))
    svg = "{http://www.w3.org/2000/svg}"
    groups = [g for g in root.iter(f"{svg}g") if g.get("id", "").startswith("measured-")]
    assert groups, "no measured series in the figure"
    markers = {}
    for g in groups:
        defs = {id(p) for d in g.iter(f"{svg}defs") for p in d.iter()}
        lines = [p for p in g.iter(f"{svg}path") if id(p) not in defs and re.search(r"\bL\b", p.get("d", ""))]
        assert not lines, f"{g.get('id')}: the measured points are joined by a line"
        uses = list(g.iter(f"{svg}use"))
        assert uses, f"{g.get('id')}: no markers"
        markers[g.get("id")] = len(uses)
    magnitude = sum(n for k, n in markers.items() if "-magnitude" in k)
    assert magnitude == sum(n for k, n in markers.items() if "-phase" in k)  # each point in both panels
    return magnitude


def table(driver, table_id):
    """Rows of the table as lists of the cell texts a reader sees (header row first)."""
    return driver.execute_script(
        "const t = document.getElementById(arguments[0]); if (!t) return null;"
        "return Array.from(t.rows).map(r => Array.from(r.cells).map(c => c.innerText.trim()));", table_id)


def test_report_renders_in_chromium(report, browser, g1_result):
    browser.get(report.as_uri())
    assert browser.execute_script("return document.readyState") == "complete"
    with h5py.File(g1_result["result"], "r") as f:
        names = [n.decode() for n in f["names"][()]]
        theta, intervals = f["theta"][()], f["intervals"][()]
        stages = [(n.decode(), fit) for n, fit in zip(f["stages/name"][()], f["stages/fitness"][()])]
        fitness = f.attrs["fitness"]

    # identified parameters, their units, intervals (value ± half-width, bounds distinct), truth, relative errors
    rows = table(browser, "parameters")
    assert rows[0] == ["parameter", "unit", "identified", "95 % interval", "true", "relative error"]
    assert [r[0] for r in rows[1:]] == names == list(TRUTH)
    assert {r[0]: r[1] for r in rows[1:]} == {"pole1": "rad/s", "dc_gain": "m/(N·s)", "fc_pos": "N", "fc_neg": "N"}
    for r, value, (lo, hi) in zip(rows[1:], theta, intervals):
        assert float(r[2]) == pytest.approx(value, rel=1e-7, abs=0)
        low, high = interval_bounds(r[3])
        assert low < high, r[3]                                    # distinct as the reader sees them
        half = (hi - lo) / 2
        assert low == pytest.approx(lo, abs=0.06 * half) and high == pytest.approx(hi, abs=0.06 * half), (r[3], lo, hi)
        true = TRUTH[r[0]]
        assert float(r[4]) == true
        assert float(r[5]) == pytest.approx(abs(value - true) / abs(true), rel=1e-3)
    assert float(rows[1][5]) == pytest.approx(1 / 11, rel=1e-3)  # pole -10 identified, "true" -11

    # G(s) written out: the identified pole and gain, the DC gain with the unit of |H|
    formula = browser.find_element("css selector", "div.formula").text
    k = theta[names.index("dc_gain")] * -theta[names.index("pole1")]
    assert "G(s) =" in formula and f"(s + {-theta[names.index('pole1')]:.8g})" in formula, formula
    assert f"K = {k:.8g} m/(N·s²)" in formula and "DC gain G(0) = " in formula and "m/(N·s)" in formula, formula

    # the comparators' references named: author, title, year
    refs = browser.execute_script("return Array.from(document.querySelectorAll('#references li')).map(l => l.innerText)")
    assert [r.split("]")[0] for r in refs] == ["[31", "[2", "[35"]
    assert "Chen" in refs[1] and "Frequency-domain identification algorithms" in refs[1] and "2002" in refs[1]
    assert "Kiran" in refs[0] and "2011" in refs[0] and "Kiran" in refs[2] and "2013" in refs[2]

    # the paper's layout, beside its published Table II (g1 is the paper's plant)
    paper = {r[0]: r for r in table(browser, "paper")}
    assert float(paper["pole"][1]) == pytest.approx(-10, rel=1e-6)
    assert float(paper["constant"][1]) == pytest.approx(10, rel=1e-6)
    assert "-10.0006" in paper["pole"] and "10.0000" in paper["constant"]  # the paper's PSO-ANN column

    # every experiment: the measured first harmonics as stored, the identified model reproducing them
    with h5py.File(g1_result["data"], "r") as f:
        measured = sorted((g.attrs["amplitude"], g.attrs["frequency"], g.attrs["H"], g.attrs["dc"])
                          for g in f["experiments"].values())
    rows = table(browser, "experiments")
    assert len(rows) == 1 + len(measured) == 7
    shown = sorted(tuple(map(float, r)) for r in rows[1:])
    for r, (m, freq, H, dc) in zip(shown, measured):
        assert r[:2] == (m, freq)
        assert r[2] == pytest.approx(abs(H), rel=1e-7)
        assert r[3] == pytest.approx(np.degrees(np.angle(H)), abs=2e-6)
        assert r[4] == pytest.approx(dc, rel=1e-5)
        assert r[5] == pytest.approx(abs(H), rel=1e-6)  # model |H|
        assert r[8] < 1e-8                               # |ΔH|/|H|
    # the fitness recomputed from the page's own simulations is the identification's, within the simulations'
    # tolerance (a noise-free fit ends at that level: two runs to the same orbit differ by about as much)
    refit = browser.find_element("id", "refit").text
    assert float(refit.split(":")[1].split()[0]) == pytest.approx(fitness, rel=0.05, abs=POLISH_RTOL), refit

    rows = table(browser, "stages")
    assert [(r[0], float(r[1])) for r in rows[1:-1]] == [(n, pytest.approx(fit, rel=1e-3)) for n, fit in stages]
    provenance = {r[0]: r[1] for r in table(browser, "provenance")}
    assert provenance["data_sha256"] == file_sha256(g1_result["data"])

    # five figures (one Bode plot per magnitude, all magnitudes against G: SVG; friction, PSO: PNG), decoded
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.getAttribute('src'), i.complete, i.naturalWidth, "
        "i.naturalHeight]);")
    assert len(images) == 5
    assert [src.split(";")[0] for src, *_ in images] == ["data:image/svg+xml"] * 3 + ["data:image/png"] * 2
    for src, complete, width, height in images:
        assert src.split(",")[0].endswith(";base64")
        assert complete and width > 0 and height > 0
    # the measured first harmonics are markers, one per experiment, never joined by a line
    per_magnitude = len(PLAN["frequencies"])
    for (src, *_), points in zip(images[:3], [per_magnitude, per_magnitude, per_magnitude * len(PLAN["amplitudes"])]):
        assert measured_markers(src) == points
    # self-contained: nothing was fetched, and the console stayed clean
    assert browser.execute_script("return performance.getEntriesByType('resource').length") == 0
    errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    assert errors == []


def page_fits(driver, width: int = 1280) -> dict:
    """At a ``width`` px wide window: the page's height, the tables wider than their container (the reader would
    have to scroll them sideways) and whether the page itself scrolls sideways."""
    size = driver.get_window_size()
    driver.set_window_size(width, 900)
    try:
        return driver.execute_script(
            "return {height: document.documentElement.scrollHeight,"
            " wide: Array.from(document.querySelectorAll('table')).filter(t => t.scrollWidth > "
            "t.parentElement.clientWidth + 1).map(t => t.id),"
            " sideways: document.documentElement.scrollWidth > document.documentElement.clientWidth};")
    finally:
        driver.set_window_size(size["width"], size["height"])


def svg_text(src: str) -> str:
    """The text of an SVG figure (a data: URI): its titles and legend."""
    root = ET.fromstring(base64.b64decode(src.split(",", 1)[1]))
    return " ".join(t.text or "" for t in root.iter("{http://www.w3.org/2000/svg}text"))


def test_comparison_side_by_side(g1_result, browser, tmp_path):
    """A COMPARE.h5 of two methods: one row per method in the parameter table, the methods overlaid in the same
    figures as a single result's report, tables within a 1280 px page; seven methods: still five figures."""
    out = tmp_path / "compare.html"
    proc = run("report", g1_result["compare"], "-o", out)
    assert proc.returncode == 0, proc.stderr
    browser.get(out.as_uri())
    with h5py.File(g1_result["compare"], "r") as f:
        theta = {m: f[f"methods/{m}/theta"][()] for m in ("pso", "chen2002")}
    rows = table(browser, "parameters")
    assert rows[0] == ["result", "pole1 [rad/s]", "dc_gain [m/(N·s)]", "fc_pos [N]", "fc_neg [N]"]
    assert [r[0] for r in rows[1:]] == ["pso", "chen2002"]
    for r in rows[1:]:
        assert [float(cell.splitlines()[0]) for cell in r[1:]] == pytest.approx(theta[r[0]], rel=1e-7)
        assert all(cell.splitlines()[1].startswith(("± ", "[")) for cell in r[1:])  # the interval beneath
    assert abs(theta["chen2002"][0] / theta["pso"][0] - 1) > 1e-6  # two different answers side by side
    # the same five figures as for one result: both methods on shared axes
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.getAttribute('src'), i.complete ? i.naturalWidth : 0]);")
    assert len(images) == 5 and min(w for _, w in images) > 0
    for src, _ in images[:2]:
        assert "pso at" in svg_text(src) and "chen2002 at" in svg_text(src)
    # G with the band from each covariance (Chen 2002's result has intervals but no covariance: no band)
    assert "pso (95% band)" in svg_text(images[2][0]) and "chen2002 (no covariance" in svg_text(images[2][0])
    two = page_fits(browser)
    assert two["wide"] == [] and not two["sideways"], two
    assert [e for e in browser.get_log("browser") if e["level"] == "SEVERE"] == []

    # seven methods (the CasADi and Chen columns among them) on one page: no figure more, no table scrolled
    results = read_results(g1_result["compare"])
    for k, name in enumerate(["pso-ann", "ga-ann", "aga-ann", "casadi-nls-ann", "casadi-nls"]):
        results[name] = replace(results["pso"], method=name)
    write_comparison(tmp_path / "seven.h5", results)
    (tmp_path / "g1.h5").write_bytes(g1_result["data"].read_bytes())
    proc = run("report", tmp_path / "seven.h5", "--truth", g1_result["truth"], "-o", tmp_path / "seven.html")
    assert proc.returncode == 0, proc.stderr
    browser.get((tmp_path / "seven.html").as_uri())
    assert len(table(browser, "parameters")) == 1 + 7 + 1  # a row per method and the truth
    assert browser.execute_script("return document.images.length") == 5
    seven = page_fits(browser)
    assert seven["wide"] == [] and not seven["sideways"], seven
    assert seven["height"] < 1.5 * two["height"], (seven, two)


@pytest.mark.parametrize("name", ["g1", "stribeck_servo", "lugre_servo"])
def test_friction_curve_follows_the_model_formulas(name):
    """F(v) at constant velocity against docs/model.md, written out here: g±(v) = fc± + (fs± − fc±)·exp(−(v/vs)²);
    coulomb/stribeck F = g+·max(t, 0) + g−·min(t, 0) + fv·v with t = tanh(v/v_smooth); LuGre at rest (dz/dt = 0)
    z = sign(v)·g(v)/sigma0, so F = sign(v)·g(v) + fv·v."""
    plant = load_plant(name)
    p = plant.parameters()
    v = np.concatenate([-np.geomspace(1e-5, 3, 200)[::-1], np.geomspace(1e-5, 3, 200)])

    def g(side):
        if plant.friction.model == "coulomb":
            return p[f"fc_{side}"]
        return p[f"fc_{side}"] + (p[f"fs_{side}"] - p[f"fc_{side}"]) * np.exp(-(v / p["vs"]) ** 2)

    if plant.friction.model == "lugre":
        expected = np.where(v > 0, g("pos"), -g("neg")) + p["fv"] * v
    else:
        t = np.tanh(v / p["v_smooth"])
        expected = g("pos") * np.maximum(t, 0) + g("neg") * np.minimum(t, 0) + p["fv"] * v
    assert np.allclose(steady_friction(plant, v), expected, rtol=1e-12, atol=1e-14)


def test_report_refuses_bad_input_in_one_line(g1_result, tmp_path):
    out = tmp_path / "report.html"
    out.write_text("an earlier report")
    result, data = g1_result["result"], g1_result["data"]
    # a data file, a comparison file of a format it does not know, a file that is not HDF5
    assert_one_line_error(run("report", data, "-o", out, "--force"), str(data), "servofmu-data")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f.attrs["format"] = "something-else"
    assert_one_line_error(run("report", foreign, "-o", out, "--force"), str(foreign), "something-else")
    assert_one_line_error(run("report", g1_result["truth"], "-o", out, "--force"), "truth.toml", "not a readable")
    # data other than the result was identified from
    other = tmp_path / "other.h5"
    other.write_bytes(data.read_bytes())
    edit_hdf5(other, lambda f: f.attrs.__setitem__("note", "changed"))
    assert_one_line_error(run("report", result, "--data", other, "-o", out, "--force"), str(other), "SHA-256")
    # the data file cannot be found: the result alone in another folder
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "r.h5").write_bytes(result.read_bytes())
    assert_one_line_error(run("report", alone / "r.h5", "-o", out, "--force", cwd=tmp_path), "g1.h5",
                          "give the data file")
    # ... and given with --data it is found
    proc = run("report", alone / "r.h5", "--data", data, "-o", tmp_path / "ok.html", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "<table id=\"parameters\">" in (tmp_path / "ok.html").read_text()
    assert_one_line_error(run("report", result, "--truth", "no_such_plant", "-o", out, "--force"), "no_such_plant")
    assert out.read_text() == "an earlier report"  # nothing written by a failed run


# ---------------------------------------------------------------------------
# servofmu validate: the verdict and its page
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def held_out(g1_result, built_fmu):
    """Another run of g1 with measurement noise (20 dB SNR), and the identified plant with its Coulomb friction 3×
    too low (the new user's wrong model) as a result file."""
    folder = g1_result["folder"]
    noisy = folder / "g1-noisy.h5"
    measure(built_fmu("g1", 3), noisy, options=MeasureOptions(noise_snr_db=20, seed=1), run=RunOptions(workers=0),
            **PLAN)
    right = read_result(g1_result["result"])
    plant = right.plant
    low = plant.with_parameters([v / 3 if n in ("fc_pos", "fc_neg") else v
                                 for n, v in zip(plant.parameter_names(), plant.parameter_vector())])
    wrong = folder / "g1-wrong.h5"
    write_result(wrong, replace(right, plant=low, theta=np.array([low.parameters()[n] for n in right.names])))
    return {"noisy": noisy, "wrong": wrong}


def test_validate_passes_the_right_model_and_fails_the_wrong_one(g1_result, held_out):
    """On held-out noisy data the identified model passes (exit 0); the model with 3× too little friction fails
    (exit 1, "passed": false) — on noisy data by fit and residual tests, on noise-free data by its fit alone."""
    proc = run("validate", g1_result["result"], held_out["noisy"], "--json")
    assert proc.returncode == 0, proc.stderr
    right = json.loads(proc.stdout)
    assert right["passed"] and right["min_fit_percent"] == 80 and not right["own_data"] and right["warnings"] == []
    assert all(e["passed"] and e["residual_test"]["passed"] and e["fit_percent"] > 85 for e in right["experiments"])

    proc = run("validate", held_out["wrong"], held_out["noisy"], "--json")
    assert proc.returncode == 1, proc.stderr
    wrong = json.loads(proc.stdout)
    assert wrong["passed"] is False and wrong["failures"]
    assert not any(e["residual_test"]["passed"] for e in wrong["experiments"])
    assert min(e["fit_percent"] for e in wrong["experiments"]) < 80

    proc = run("validate", held_out["wrong"], g1_result["data"])  # noise-free: nothing to test but the fit
    assert proc.returncode == 1, proc.stderr
    assert "verdict: FAILED" in proc.stdout and proc.stderr == ""
    # a lower bar is the user's to set: the residual tests still fail it on noisy data, not on noise-free data
    assert run("validate", held_out["wrong"], held_out["noisy"], "--min-fit", "-1000").returncode == 1
    assert run("validate", held_out["wrong"], g1_result["data"], "--min-fit", "-1000").returncode == 0


def test_validation_page_in_chromium(g1_result, held_out, browser, tmp_path):
    """The page of a validation on the identification's own data: verdict, the warning that the data is the
    fitting data, residual plots decoded; and the page of the wrong model: verdict failed, its failures listed."""
    page = tmp_path / "own.html"
    proc = run("validate", g1_result["result"], g1_result["data"], "-o", page)
    assert proc.returncode == 0, proc.stderr
    assert "warning: g1.h5 is the data the model was identified from" in proc.stdout
    browser.get(page.as_uri())
    assert browser.find_element("id", "verdict").text.startswith("Verdict: passed.")
    assert "identified from" in browser.find_element("id", "own-data-warning").text
    rows = table(browser, "validation-experiments")
    assert len(rows) == 7 and rows[0][-2:] == ["residual tests", "verdict"]
    assert all(r[-1] == "passed" for r in rows[1:])
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.alt, i.complete ? i.naturalWidth : 0]);")
    assert dict(images).get("residuals", 0) > 0, images  # the residual plot, decoded
    assert all(width > 0 for _, width in images)

    page = tmp_path / "wrong.html"
    assert run("validate", held_out["wrong"], held_out["noisy"], "-o", page).returncode == 1
    browser.get(page.as_uri())
    assert browser.find_element("id", "verdict").text.startswith("Verdict: failed.")
    assert len(browser.find_elements("css selector", "#failures li")) == len(PLAN["frequencies"]) * 2
    assert browser.find_elements("id", "own-data-warning") == []
    images = browser.execute_script("return Array.from(document.images).map(i => [i.alt, i.naturalWidth]);")
    assert dict(images).get("residuals", 0) > 0
    assert [e for e in browser.get_log("browser") if e["level"] == "SEVERE"] == []
