"""One meaning per option across the command line (docs/cli.md): `-o/--output` is the file written, `--json` on
every command that writes results, `--progress` on every long one; errors name the subcommand and the option;
`--help` loads no numerical package; the API refuses a wrong argument by name."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np
import pytest
from clitools import assert_one_line_error, run

# Every subcommand writes a file (or, for demo, a folder): all of them take -o/--output and --json.  simulate's
# -o is optional (without it the CSV goes to stdout, and --json asks for -o).
WRITES = ("build", "simulate", "measure", "import", "plot", "excitation", "frf", "dataset", "train", "identify",
          "compare", "select", "validate", "report", "export", "controller", "system", "cosim", "compensate", "tune",
          "demo")
# Commands that can run longer than a few seconds: they simulate many experiments, plants, candidates, methods or
# co-simulation steps, read many files, train a network or run the whole demo.  build, export, controller and
# system compile or zip one model (seconds); plot, excitation, frf and report read or draw one file.
LONG = ("measure", "import", "dataset", "train", "identify", "compare", "select", "validate", "cosim", "compensate",
        "tune", "demo")
HEAVY = ("numpy", "h5py", "scipy", "casadi", "torch")


def subcommands() -> dict[str, argparse.ArgumentParser]:
    from servofmu.cli import build_parser

    parser = build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def options(p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {o: a for a in p._actions for o in a.option_strings}


def test_the_lists_name_every_subcommand():
    assert set(WRITES) == set(subcommands()) and set(LONG) <= set(WRITES)


@pytest.mark.parametrize("name", WRITES)
def test_o_and_output_are_the_one_file_written(name):
    p = subcommands()[name]
    o = options(p)
    assert o["-o"] is o["--output"], name  # the same option, two spellings
    written = (*(p.get_default("outputs") or ()), *(p.get_default("output_folders") or ()))
    assert o["-o"].dest in written, (name, o["-o"].dest, written)
    assert not any(a.dest == "output_variable" for a in p._actions if "--output" in a.option_strings)


@pytest.mark.parametrize("name", WRITES)
def test_json_on_every_command_that_writes(name):
    assert "--json" in options(subcommands()[name])


@pytest.mark.parametrize("name", LONG)
def test_progress_on_every_long_command(name):
    assert "--progress" in options(subcommands()[name])


def test_help_loads_no_numerical_package():
    """`servofmu --help`, then every `servofmu CMD --help`, in one fresh process (sys.modules only grows, so the
    first help that loads a package is the one named)."""
    code = ("import runpy, sys\nfor argv in [[], *([c] for c in sys.argv[1:])]:\n"
            "    sys.argv = ['servofmu', *argv, '--help']\n    try:\n"
            "        runpy.run_module('servofmu', run_name='__main__')\n    except SystemExit:\n        pass\n"
            f"    print(argv, sorted(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)\n")
    proc = subprocess.run([sys.executable, "-c", code, *WRITES], capture_output=True, text=True)
    lines = [line for line in proc.stderr.splitlines() if line.startswith("[")]
    assert len(lines) == len(WRITES) + 1, proc.stderr[-2000:]
    assert all(line.endswith(" []") for line in lines), lines


def test_the_literal_defaults_of_the_command_line_are_the_librarys():
    from servofmu.cli import measure, tune
    from servofmu.measurement.excitation import MAX_STEPS
    from servofmu.model.signals import INTERSAMPLE
    from servofmu.tuning.task import DEFAULT_SPEED, DEFAULT_STROKE
    from servofmu.tuning.run import METHODS

    assert (measure.MAX_STEPS, measure.INTERSAMPLE) == (MAX_STEPS, INTERSAMPLE)
    assert (tune.DEFAULT_STROKE, tune.DEFAULT_SPEED, tune.METHODS) == (DEFAULT_STROKE, DEFAULT_SPEED, METHODS)
    from servofmu.tuning.search import TuneOptions

    assert tune.OPTION_DEFAULTS == {k: getattr(TuneOptions(), k) for k in tune.OPTION_DEFAULTS}


def test_an_unrecognised_argument_is_reported_by_its_subcommand():
    assert_one_line_error(run("build", "g1", "extra", "--bogus"),
                          "servofmu build: error: unrecognized arguments: extra --bogus")


def test_an_export_error_names_the_option_not_the_python_argument(tmp_path):
    (tmp_path / "r.h5").write_bytes(b"x")
    proc = run("export", tmp_path / "r.h5", "--format", "toml", "--fmi-version", "2", "-o", tmp_path / "p.toml")
    assert_one_line_error(proc, "servofmu export: error: --fmi-version applies to FMU export only")
    assert "fmi_version" not in proc.stderr


@pytest.mark.parametrize("option, value", [("--frequency", "-1"), ("--stop-time", "-1"), ("--tolerance", "0"),
                                           ("--output-interval", "-1")])
def test_a_simulate_error_names_the_option(option, value):
    argv = {"--stop-time": "1", "--amplitude": "1", option: value}
    proc = run("simulate", "no.fmu", *[x for item in argv.items() for x in item])
    assert_one_line_error(proc, f"servofmu simulate: error: {option} must be a positive number")


def test_flags_named_maps_only_this_commands_arguments():
    from servofmu.cli import build_parser, flags_named

    export = build_parser().subcommands["export"]
    assert flags_named("fmi_version must be 2 or 3; see out/fmi_version.txt", export) \
        == "--fmi-version must be 2 or 3; see out/fmi_version.txt"
    assert flags_named("relative_tolerance must be positive", export) == "relative_tolerance must be positive"


def test_an_existing_identify_output_is_advised_an_option_identify_accepts(tmp_path):
    (tmp_path / "r.h5").write_bytes(b"old")
    proc = run("identify", "g1.h5", "--structure", "g1", "-o", tmp_path / "r.h5")
    assert_one_line_error(proc, "r.h5: exists already (give --force to replace it)")
    assert "--resume" not in proc.stderr
    assert (tmp_path / "r.h5").read_bytes() == b"old"


def test_demo_takes_o_and_its_old_out_with_one_line(tmp_path):
    from servofmu.cli import build_parser

    parser = build_parser()
    assert parser.parse_args(["demo", "-o", "d"]).output == "d"
    assert parser.parse_args(["demo"]).output == "demo-output"
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "keep").write_text("x")
    proc = run("demo", "--out", tmp_path / "d")  # a folder that is not empty: refused before any work
    assert proc.returncode == 2 and proc.stderr.splitlines()[0] == \
        "servofmu demo: warning: --out is deprecated, use -o/--output"
    assert "exists already" in proc.stderr.splitlines()[1] and len(proc.stderr.splitlines()) == 2
    assert [f.name for f in (tmp_path / "d").iterdir()] == ["keep"]


def test_json_prints_what_was_written(tmp_path):
    proc = run("excitation", "multisine", "--band", "1,20", "--realisations", "1", "--json", "-o",
               tmp_path / "s.csv")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["written"] == [str(tmp_path / "s.csv")] and summary["kind"] == "multisine"
    assert summary["lines"] > 0 and (tmp_path / "s.csv").stat().st_size > 0


def test_simulate_json_asks_for_o(tmp_path):
    assert_one_line_error(run("simulate", "g1.fmu", "--stop-time", "1", "--json"), "servofmu simulate: error:",
                          "--json", "-o")


def test_the_progress_bar_names_the_command_and_its_unit(capsys, monkeypatch):
    from servofmu.cli.common import ProgressBar

    args = argparse.Namespace(command="measure", progress=True)
    with ProgressBar(args, "experiment", scale=1000) as bar:
        bar.update(1000, 2000)
    with ProgressBar(args, "step", label="demo") as bar:
        bar.stage("g1: train", "epoch")(3, 10)
    err = capsys.readouterr().err
    assert "measure:" in err and "1.00/2 experiments" in err
    assert "g1: train:" in err and "3/10 epochs" in err


@pytest.mark.parametrize("kwargs, name", [
    ({"input_signal": np.zeros((10, 2))}, "input_signal"),
    ({"input_signal": [[0.0, 0.0], [1.0, 1.0]]}, "input_signal"),
    ({"output_interval": "x"}, "output_interval"),
    ({"outputs": "v"}, "outputs"),
    ({"start_values": [1]}, "start_values"),
    ({"relative_tolerance": "x"}, "relative_tolerance"),
    ({"relative_tolerance": -1.0}, "relative_tolerance"),
    ({"stop_time": "10"}, "stop_time"),
])
def test_simulate_refuses_a_wrong_argument_by_name(kwargs, name):
    import servofmu

    kwargs = {"stop_time": 10, **kwargs}
    with pytest.raises(servofmu.UserError, match=rf"^(simulate\(\): )?{name} must"):
        servofmu.simulate("no-such.fmu", kwargs.pop("stop_time"), interface="cs", **kwargs)


@pytest.mark.parametrize("call, name", [
    (lambda sf: sf.load_plant(42), "plant"),
    (lambda sf: sf.build_fmu("g1", "x.fmu"), "plant"),
    (lambda sf: sf.measure(42, "x.h5"), "fmu"),
    (lambda sf: sf.read_data_file(42), "path"),
    (lambda sf: sf.sine_data("g1.h5"), "data"),
    (lambda sf: sf.read_result(42), "path"),
    (lambda sf: sf.write_result("w.h5", 42), "result"),
    (lambda sf: sf.export_result(42, "x.toml"), "result_file"),
    (lambda sf: sf.train_from_file(42, "n.h5"), "training_set"),
])
def test_public_functions_refuse_an_argument_of_the_wrong_type_by_name(call, name, tmp_path, monkeypatch):
    import servofmu

    monkeypatch.chdir(tmp_path)
    with pytest.raises(servofmu.UserError, match=rf"^\w+\(\): {name} must be "):
        call(servofmu)
    assert list(tmp_path.iterdir()) == []


def test_the_argument_check_leaves_what_it_does_not_know_to_the_function():
    from servofmu.api_checks import argument_problem

    from servofmu.runtime import Progress, RunOptions

    assert argument_problem("run", "RunOptions | None", 3, {"RunOptions": RunOptions}) == \
        "run must be a RunOptions or None, not int 3"

    assert argument_problem("x", "Progress | None", lambda d, t: None, {"Progress": Progress}) is None  # a protocol
    assert argument_problem("x", "np.ndarray", [1], {}) is None and argument_problem("x", "list[str]", 3, {}) is None
    assert argument_problem("x", "str | Path | None", None, {}) is None
    assert argument_problem("x", "float", True, {}) == "x must be a number, not bool True"


def test_the_demo_draws_a_bar_per_long_step_under_its_lines(tmp_path, monkeypatch, capsys):
    """The demo's CLI hands each long step (here a stand-in training) a labelled bar and prints its lines above."""
    from servofmu.cli import main
    from servofmu.commands import demo

    def fake_demo(out, report, overwrite=False, stage=None):
        report("built g1.fmu")
        train = stage("g1: train", "epoch")
        for epoch in range(1, 11):
            train(epoch, 10)
        report("trained g1-ann.h5")
        return {}

    monkeypatch.setattr(demo, "run_demo", fake_demo)
    assert main(["demo", "-o", str(tmp_path / "d"), "--progress"]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines() == ["built g1.fmu", "trained g1-ann.h5"]
    assert "g1: train: 100%" in err and "10/10 epochs" in err


def test_every_public_function_checks_its_arguments():
    import inspect

    import servofmu

    functions = [getattr(servofmu, n) for n in servofmu.__all__ if inspect.isfunction(getattr(servofmu, n))]
    assert len(functions) >= 15
    unchecked = [f.__name__ for f in functions if f"check_arguments({f.__name__}, locals())" not in inspect.getsource(f)]
    # the comparators refuse records (RecordData for their SineData) with their own, better message: stepped-sine only
    assert sorted(unchecked) == ["fit_casadi_nls", "fit_chen2002"]


@pytest.mark.parametrize("command", ["measure", "import"])
def test_output_in_measure_and_import_is_the_data_file_or_a_line_pointing_to_output_variable(command, capsys):
    from servofmu.cli import build_parser

    parser = build_parser()
    head = [command, "in.fmu"] if command == "measure" else [command, "in.csv", "--time", "t", "--input", "u"]
    for spelling in ("-o", "--output"):
        for value in ("g1.h5", "G1.HDF5", "out/g1"):
            assert parser.parse_args([*head, spelling, value]).data == value
    assert parser.parse_args([*head, "-o", "g1.data"]).data == "g1.data"  # -o takes any name
    with pytest.raises(SystemExit) as exit_:
        parser.parse_args([*head, "--output", "v", "-o", "g1.h5"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == (f"servofmu {command}: error: --output v: --output is the data file to write "
                                       "(as -o, e.g. --output v.h5); the output variable is --output-variable v\n")
