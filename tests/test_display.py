"""Objects that show themselves: every public object (each class of ``servofmu.__all__`` and what the public
functions return) has a short repr (at most 300 characters, its type named, its figures with units) and an HTML
table; the loop's margins in dB, deg and Hz."""
from __future__ import annotations

import inspect
import math
import re
from dataclasses import replace
from html.parser import HTMLParser

import numpy as np
import pytest

import servofmu as sf
from servofmu.display import REPR_LIMIT, Figure, Shown, format_interval, short_repr
from servofmu.identification.identifier import PsoOptions
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.identification.restarts import RestartOptions
from servofmu.identification.results import Result, Stage
from servofmu.model.controller import PARAMETERS, load_controller
from servofmu.runtime import RunOptions

UNIT = re.compile(r"[\d—] (dB|deg|Hz|N|s|m|m/s|rad/s|N·s/m|N/m|%|m/\(N·s\))(?![\w/])")


class Tags(HTMLParser):
    """The tags of an HTML text, checking that every opened tag is closed in order."""

    def __init__(self):
        super().__init__()
        self.seen, self.open = [], []

    def handle_starttag(self, tag, attrs):
        self.seen.append(tag)
        self.open.append(tag)

    def handle_endtag(self, tag):
        assert self.open and self.open[-1] == tag, f"</{tag}> closes <{self.open[-1] if self.open else None}>"
        self.open.pop()


def assert_shows_itself(obj, unit: bool = True):
    text = repr(obj)
    assert len(text) <= REPR_LIMIT, (len(text), text)
    assert type(obj).__name__ in text and "\n" not in text, text
    if unit:
        assert UNIT.search(text), f"no unit in {text}"
    page = obj._repr_html_()
    tags = Tags()
    tags.feed(page)
    tags.close()
    assert "table" in tags.seen and not tags.open, page
    return text, page


def fake_result(plant, spread=2e-3):
    theta = plant.parameter_vector()[identified_mask(plant)]
    intervals = np.stack([theta - spread * np.abs(theta), theta + spread * np.abs(theta)], axis=1)
    return Result("pso", plant, plant, tuple(identified_names(plant)), theta, intervals, 1.5e-6, 2.0, 40,
                  (Stage("pso", None, 1e-3, 1.5, 30), Stage("polish", theta, 1.5e-6, 0.5, 10)), np.zeros(3), {})


@pytest.fixture(scope="module")
def data(built_fmu, tmp_path_factory):
    """A measurement of 2 amplitudes × 2 frequencies and a file of one imported record."""
    folder = tmp_path_factory.mktemp("display")
    measured = sf.measure(built_fmu("g1"), folder / "g1.h5", amplitudes=[1.0, 2.0], frequencies=[2.0, 5.0],
                          run=RunOptions(workers=0))
    csv = folder / "r.csv"
    csv.write_text("time,force,speed\n" + "".join(f"{k * 1e-3},{(-1) ** (k // 50)},{0.01 * k}\n" for k in range(400)))
    records = sf.import_records([csv], folder / "r.h5", time="time", input="force", output_column="speed")
    return measured, records


def tuning():
    """A Tuning built from its fields (a real one takes minutes): the example drive on linear_axis."""
    from servofmu.tuning.check import Figures
    from servofmu.tuning.run import ModelRun, Tuning
    from servofmu.tuning.task import stroke_task

    plant, c = sf.load_plant("linear_axis"), load_controller("axis_controller")
    task = stroke_task(0.02, 0.05, c.sample_time)
    run = ModelRun(c, sf.analyse_loop(plant, c, points=400), 1.8, 2e-5, Figures(1e-5, 3e-5, 0.1, 0.02, 1e-3, 0.0),
                   task.position, task.position, task.position)
    return Tuning(fake_result(plant), task, task, "rule", sf.TuneOptions(), False, {"given": run, "rule": run}, 2.5,
                  None, None, 3.0)


def selection():
    from servofmu.selection.candidates import parse_candidates
    from servofmu.selection.select import CandidateScore
    from servofmu.selection.store import Selection

    plant = sf.load_plant("g1")
    first, second = parse_candidates(["coulomb", "stribeck"], orders=(1,))[:2]
    scores = (CandidateScore(first, "fitted", result=fake_result(plant), parameters=4, samples=12, bic=-120.0,
                             validation_fit={"v": 97.5}, rank=1),
              CandidateScore(second, "fitted", parameters=7, samples=12, bic=-110.0, validation_fit={"v": 96.0},
                             rank=2))
    return Selection(scores, ("g1.h5",), "g1-val.h5", "stepped-sine", sf.SelectOptions(), {})


def validation(measured):
    from servofmu.validation.replay import validate

    return validate(fake_result(sf.load_plant("g1")), measured)


def comparison(measured):
    from servofmu.api.workflow import ModelComparison

    return ModelComparison({"g1": validation(measured), "g1 again": validation(measured)})


def training_set(tmp_path):
    from servofmu.identification.training_set import TrainingSet

    n, e = 5, 4
    return TrainingSet(tmp_path / "DS.h5", sf.load_plant("g1"), np.ones(e), np.linspace(1, 10, e), np.ones((n, 4)),
                       np.ones((n, e), complex), np.zeros((n, e)), np.ones((n, e), bool), np.ones(n, bool), {})


def ann_model():
    from servofmu.identification.ann import AnnModel, FeatureLayout, Network

    net = Network(np.zeros((8, 6)), np.zeros(8), np.zeros((4, 8)), np.zeros(4), np.zeros(6), np.ones(6), np.zeros(4),
                  np.ones(4), "tanh", "standard", np.ones(20), np.ones(20), 12)
    layout = FeatureLayout(tuple(f"f{i}" for i in range(6)), tuple(identified_names(sf.load_plant("g1"))),
                           np.ones((2, 3)))
    return AnnModel(net, layout, "ann.npz")


def bla():
    rng = np.random.default_rng(0)
    u = rng.standard_normal((3, 2, 256))
    y = 0.5 * u + 0.01 * rng.standard_normal(u.shape)
    return sf.estimate_bla(u, y, np.arange(3, 60, 2), 1000.0, detection=np.arange(4, 60, 8))


def fitted_identifier(measured):
    est = sf.PSOANNIdentifier(sf.load_plant("g1"), method="pso", pso=PsoOptions(particles=4, iterations=2),
                              polish=False, threads=1, restarts=RestartOptions(restarts=0))
    return est.fit(sf.sine_data(measured))


# What each public class's instance is built from, and the object each public function returns (the functions that
# return a path, an array or a tuple of files are named with what they return: they have nothing to show).
CLASSES = {
    "Plant": lambda d, tmp: sf.load_plant("inclined_axis"),
    "MeasureOptions": lambda d, tmp: sf.MeasureOptions(max_time=5.0),
    "BroadbandPlan": lambda d, tmp: sf.BroadbandPlan("multisine", (0.5, 1.0), (1.0, 100.0), 1000.0),
    "PSOANNIdentifier": lambda d, tmp: fitted_identifier(d[0]),
    "SelectOptions": lambda d, tmp: sf.SelectOptions(skip=0.5),
    "TuneOptions": lambda d, tmp: sf.TuneOptions(),
    "Records": lambda d, tmp: sf.Records(d[1].records, "r"),
}
RETURNS = {
    "load_plant": lambda d, tmp: sf.load_plant("g1"),
    "measure": lambda d, tmp: d[0],
    "import_records": lambda d, tmp: d[1],
    "read_data_file": lambda d, tmp: sf.read_data_file(d[0].path),
    "estimate_bla": lambda d, tmp: bla(),
    "h1_estimate": lambda d, tmp: sf.h1_estimate(*np.random.default_rng(1).standard_normal((2, 2048)), 1000.0),
    "sine_data": lambda d, tmp: sf.sine_data(d[0]),
    "make_training_set": lambda d, tmp: training_set(tmp),
    "load_ann": lambda d, tmp: ann_model(),
    "read_result": lambda d, tmp: fake_result(sf.load_plant("g2")),
    "fit_casadi_nls": lambda d, tmp: baseline(),
    "fit_chen2002": lambda d, tmp: baseline(),
    "select_files": lambda d, tmp: selection(),
    "select_with_report": lambda d, tmp: selection(),
    "analyse_loop": lambda d, tmp: sf.analyse_loop(sf.load_plant("linear_axis"), load_controller("axis_controller")),
    "tune_axis": lambda d, tmp: tuning(),
    "identify": lambda d, tmp: fake_result(sf.load_plant("g1")),
    "select": lambda d, tmp: selection(),
    "tune": lambda d, tmp: tuning(),
    "compare_models": lambda d, tmp: comparison(d[0]),
    "control_loops": lambda d, tmp: sf.control_loops(sf.load_plant("linear_axis"), load_controller("axis_controller")),
}
NOTHING_TO_SHOW = {"build_fmu": "a path", "simulate": "an array", "export_result": "(path, text)",
                   "train_from_file": "(Network, epochs)", "write_result": "None", "bode": "a matplotlib Figure",
                   "friction_curve": "a matplotlib Figure", "validation_overlay": "a matplotlib Figure",
                   "residual_tests": "a matplotlib Figure"}
# objects the public ones hold and hand out
PARTS = {
    "Friction": lambda d, tmp: sf.load_plant("lugre_servo").friction,
    "Load": lambda d, tmp: sf.load_plant("inclined_axis").load,
    "ExperimentResult": lambda d, tmp: d[0].experiments[0],
    "Record": lambda d, tmp: d[1].records[0],
    "Stage": lambda d, tmp: fake_result(sf.load_plant("g1")).stages[0],
    "ControllerSpec": lambda d, tmp: load_controller("axis_controller"),
    "ModelRun": lambda d, tmp: tuning().runs["rule"],
    "Task": lambda d, tmp: tuning().task,
    "Figures": lambda d, tmp: tuning().runs["rule"].figures,
    "CandidateScore": lambda d, tmp: selection().scores[0],
    "Validation": lambda d, tmp: validation(d[0]),
    "Network": lambda d, tmp: ann_model().network,
    "AnnModel": lambda d, tmp: ann_model(),
    "unfitted PSOANNIdentifier": lambda d, tmp: sf.PSOANNIdentifier(sf.load_plant("g1"), method="pso"),
}


# objects without a physical figure: a network, the search's settings
WITHOUT_UNITS = {"TuneOptions", "load_ann", "Network", "AnnModel", "unfitted PSOANNIdentifier"}


def baseline():
    from servofmu.baselines import BaselineResult

    plant = sf.load_plant("g1")
    return BaselineResult("chen2002", tuple(identified_names(plant)), plant.parameter_vector()[identified_mask(plant)],
                          1e-4, 0.2, 0, 12, True, "direct solution")


def test_every_public_class_and_function_is_covered():
    public = {n: getattr(sf, n) for n in sf.__all__}
    classes = {n for n, v in public.items() if inspect.isclass(v) and not issubclass(v, BaseException)}
    functions = {n for n, v in public.items() if inspect.isfunction(v)}
    assert classes == set(CLASSES), "a public class without an instance in CLASSES"
    assert functions == set(RETURNS) | set(NOTHING_TO_SHOW), "a public function neither in RETURNS nor NOTHING_TO_SHOW"


@pytest.mark.parametrize("name", [*CLASSES, *RETURNS, *PARTS])
def test_every_public_object_shows_itself_briefly_with_units(name, data, tmp_path):
    build = {**CLASSES, **RETURNS, **PARTS}[name]
    obj = build(data, tmp_path)
    assert_shows_itself(obj, unit=name not in WITHOUT_UNITS)


def test_the_data_file_says_what_it_holds(data):
    measured, records = data
    assert repr(measured).startswith("<DataFile 'g1.h5': measurement, 4 stepped-sine experiments (2 amplitudes × "
                                     "2 frequencies), 0 records")
    assert "amplitudes 1–2 N" in repr(measured) and "frequencies 2–5 Hz" in repr(measured)
    assert repr(records).startswith("<DataFile 'r.h5': records, 1 record")
    assert "#0 1 N at 2 Hz: |H|" in measured._repr_html_()
    big = replace(measured, experiments=measured.experiments * 100)  # a file of 400 experiments: still a glance
    text, page = assert_shows_itself(big)
    assert "400 stepped-sine experiments" in text and page.count("<tr>") < 25 and "388 more" in page


def test_the_loop_shows_its_margins_in_db_deg_and_hz():
    """The example drive on linear_axis: the tune page's 11.9 dB and 32.2 Hz, not the stored factor 3.9 and
    202 rad/s."""
    loop = sf.analyse_loop(sf.load_plant("linear_axis"), load_controller("axis_controller"))
    text, page = assert_shows_itself(loop)
    assert loop.stable and math.isfinite(loop.gain_margin)
    gain_db, crossover_hz = 20 * math.log10(loop.gain_margin), loop.crossover / (2 * math.pi)
    shown = {k: float(v) for k, v in re.findall(r"(gain margin|crossover|phase margin) (-?[\d.e+-]+)", text)}
    assert shown["gain margin"] == pytest.approx(gain_db, abs=0.05) and f"gain margin {gain_db:.3g} dB" in text
    assert shown["crossover"] == pytest.approx(crossover_hz, rel=5e-3) and f"crossover {crossover_hz:.3g} Hz" in text
    assert f"phase margin {loop.phase_margin:.3g} deg" in text
    assert "gain margin 11.9 dB" in text and "crossover 32.2 Hz" in text
    assert f"{loop.gain_margin:.4g}" not in text and f"{loop.crossover:.3g}" not in text
    assert ">dB<" in page and ">Hz<" in page and ">deg<" in page
    assert f">{gain_db:.3g}<" in page and f">{crossover_hz:.3g}<" in page


def test_the_controller_names_its_gains_with_units():
    text, page = assert_shows_itself(load_controller("axis_controller"))
    assert re.search(r"kp_velocity [\d.e+-]+ N·s/m", text) and re.search(r"ki_velocity [\d.e+-]+ N/m", text)
    assert page.count("<tr>") == 1 + len(PARAMETERS) == 1 + 25  # the head and every parameter


def test_a_result_shows_its_parameters_with_units_and_intervals():
    result = fake_result(sf.load_plant("g1"))
    text, page = assert_shows_itself(result)
    assert "fc_pos 0.5000 ± 0.0010 N" in text and "dc_gain 1.0000 ± 0.0020 m/(N·s)" in text
    assert "95 % interval" in page and format_interval(0.5, 0.499, 0.501) in page


def test_a_tuning_shows_the_chosen_controller_and_its_margins():
    run = tuning()
    text, _ = assert_shows_itself(run)
    assert "rule" in text and "dB" in text and "Hz" in text and "kp_velocity" in text


def test_the_repr_leaves_out_what_does_not_fit_and_says_so():
    many = [Figure(f"p{i}", float(i), "N") for i in range(200)]
    text = short_repr("Thing", "head", many)
    assert len(text) <= REPR_LIMIT and text.endswith(", …>") and text.startswith("<Thing head: p0 0 N, p1 1 N")
    assert len(short_repr("Thing", "x" * 1000)) <= REPR_LIMIT
    assert Shown("Thing", "a", (Figure("b", 1.0, "m/(N.s^2)"),)).repr() == "<Thing a: b 1 m/(N·s²)>"


def test_html_is_escaped():
    page = Shown("Thing", "<script>", (Figure("a&b", "<i>", "N"),)).html()
    assert "<script>" not in page and "&lt;script&gt;" in page and "a&amp;b" in page and "&lt;i&gt;" in page
