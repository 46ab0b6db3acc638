"""The overwrite rule (docs/reliability.md) on every command that writes a file: an output that exists already is
refused without --force, in one line with exit status 2, before any work and without touching the file; and a run
given --force that then fails (here on an input that is not what it claims) leaves the old file as it was.  The
library's writers follow the same rule in their own words (OutputExists naming overwrite=True, and resume=True or
append=True where the writer can continue a file).

The inputs are stand-ins (a few bytes under the right name): the rule is checked before any input is read, so
each case costs one start of the command.
"""
from __future__ import annotations

import pytest
from clitools import assert_one_line_error, run

PREVIOUS = b"previous contents\n"

# command line (OUT: the existing output) per command; every input name is a stand-in file made in the test
COMMANDS = {
    "build": ["build", "g1", "-o", "OUT"],
    "simulate": ["simulate", "in.fmu", "--stop-time", "1", "-o", "OUT"],
    "measure": ["measure", "in.fmu", "--amplitudes", "2,0.6", "--frequencies", "1", "-o", "OUT"],
    "import": ["import", "in.csv", "--time", "t", "--input", "u", "--output-variable", "v", "-o", "OUT"],
    "plot": ["plot", "in.h5", "-o", "OUT"],
    "dataset": ["dataset", "g1", "--like", "in.h5", "--samples", "10", "-o", "OUT"],
    "train": ["train", "in.h5", "-o", "OUT"],
    "identify": ["identify", "in.h5", "--structure", "g1", "--method", "pso", "-o", "OUT"],
    "export": ["export", "in.h5", "--format", "toml", "-o", "OUT"],
    "compare": ["compare", "in.h5", "--structure", "g1", "-o", "OUT"],
    "validate": ["validate", "in.h5", "other.h5", "-o", "OUT"],
    "report": ["report", "in.h5", "-o", "OUT"],
    "controller": ["controller", "axis_controller", "-o", "OUT"],
    "system": ["system", "in.fmu", "other.fmu", "--reference", "in.csv", "-o", "OUT"],
    "cosim": ["cosim", "in.ssp", "-o", "OUT"],
    "compensate": ["compensate", "in.h5", "--axis", "in.ssp", "-o", "OUT"],
}
# (identify's --resume continues the results in --output-dir, never an -o file: not advised for one)
CONTINUE = {"measure": "--resume", "dataset": "--resume", "import": "--append", "cosim": "--append"}


def stand_ins(folder):
    for name in ("in.fmu", "other.fmu", "in.csv", "in.h5", "other.h5", "in.ssp"):
        (folder / name).write_bytes(b"not what the name says\n")


def argv(command, out):
    return [str(out) if a == "OUT" else a for a in COMMANDS[command]]


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_an_existing_output_is_refused_without_force(tmp_path, command):
    stand_ins(tmp_path)
    out = tmp_path / "out.file"
    out.write_bytes(PREVIOUS)
    before = out.stat().st_mtime_ns
    proc = run(*argv(command, out), cwd=tmp_path)
    words = ["out.file: exists already", "--force"]
    if command in CONTINUE:
        words.append(CONTINUE[command])  # the refusal names the way to continue it as well
    assert_one_line_error(proc, *words)
    assert out.read_bytes() == PREVIOUS and out.stat().st_mtime_ns == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("out")) == ["out.file"]  # no leftovers


@pytest.mark.parametrize("command", ["simulate", "plot", "train", "identify", "export", "report", "cosim"])
def test_force_passes_the_rule_and_a_failed_run_leaves_the_old_file(tmp_path, command):
    stand_ins(tmp_path)
    out = tmp_path / "out.file"
    out.write_bytes(PREVIOUS)
    proc = run(*argv(command, out), "--force", cwd=tmp_path)
    assert proc.returncode == 2 and "exists already" not in proc.stderr, proc.stderr  # refused for its input
    assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert out.read_bytes() == PREVIOUS
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("out")) == ["out.file"]


def test_identify_output_dir_refuses_an_existing_result(tmp_path):
    stand_ins(tmp_path)
    (tmp_path / "results").mkdir()
    existing = tmp_path / "results" / "in-result.h5"
    existing.write_bytes(PREVIOUS)
    proc = run("identify", "in.h5", "--structure", "g1", "--method", "pso", "--output-dir", "results", cwd=tmp_path)
    assert_one_line_error(proc, "in-result.h5: exists already", "--force")
    assert existing.read_bytes() == PREVIOUS


def test_demo_refuses_a_folder_that_is_not_empty(tmp_path):
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "keep.txt").write_bytes(PREVIOUS)
    proc = run("demo", "-o", tmp_path / "demo")
    assert_one_line_error(proc, "exists already", "--force")
    assert [p.name for p in (tmp_path / "demo").iterdir()] == ["keep.txt"]
    assert (tmp_path / "demo" / "keep.txt").read_bytes() == PREVIOUS


# ---- the library's writers: the same rule, in the library's words (overwrite=True, resume/append) ----------------
def api_writers():
    """name -> (call(out, **replace), continue keyword or None); ``replace`` is the writer's way of replacing."""
    import numpy as np

    from servofmu.baselines.compare import compare_files
    from servofmu.control.fmus import build_controller_fmu
    from servofmu.control.system import write_system
    from servofmu.fmu.build import build_fmu
    from servofmu.identification.criterion import SineData
    from servofmu.identification.run import identify_to_file
    from servofmu.identification.train import train_from_file
    from servofmu.identification.training_set import make_training_set
    from servofmu.measurement.measure import measure
    from servofmu.measurement.records import import_records
    from servofmu.model.controller import load_controller
    from servofmu.model.plant import load_plant
    from servofmu.output.export import export_result
    from servofmu.runtime import RunOptions

    data = SineData(amplitudes=np.array([2.0, 0.6]), frequencies=np.array([1.0, 1.0]), H=np.array([0.1j, 0.1j]),
                    dc=np.zeros(2), noisy=False, source="in.h5", skipped=0)
    t = np.linspace(0.0, 1.0, 11)
    return {
        "build_fmu": (lambda out, force: build_fmu(load_plant("g1"), out, overwrite=force), None),
        "build_controller_fmu": (lambda out, force: build_controller_fmu(load_controller("axis_controller"), out,
                                                                         overwrite=force), None),
        "measure": (lambda out, force: measure("in.fmu", out, run=RunOptions(overwrite=force, workers=0)), "resume"),
        "import_records": (lambda out, force: import_records(["in.csv"], out, "t", "u", "v",
                                                             run=RunOptions(overwrite=force)), "append"),
        "make_training_set": (lambda out, force: make_training_set(load_plant("g1"), data, 10, out,
                                                                   run=RunOptions(overwrite=force)), "resume"),
        "train_from_file": (lambda out, force: train_from_file("in.h5", out, run=RunOptions(overwrite=force)), None),
        "identify_to_file": (lambda out, force: identify_to_file("in.h5", "g1", out, run=RunOptions(overwrite=force)),
                             None),
        "export_result": (lambda out, force: export_result("in.h5", out, fmt="toml", overwrite=force), None),
        "compare_files": (lambda out, force: compare_files("in.h5", "g1", output=out, overwrite=force), None),
        "write_system": (lambda out, force: write_system("in.fmu", "other.fmu", (t, 0 * t), out, overwrite=force),
                         None),
    }


API_WRITERS = ["build_fmu", "build_controller_fmu", "measure", "import_records", "make_training_set",
               "train_from_file", "identify_to_file", "export_result", "compare_files", "write_system"]


@pytest.mark.parametrize("writer", API_WRITERS)
def test_library_writers_refuse_an_existing_output(tmp_path, monkeypatch, writer):
    from servofmu.fileio import OutputExists

    refused, can_continue = refused_over_an_old_file(tmp_path, monkeypatch, writer, False, OutputExists)
    message = str(refused)
    assert "out.file: exists already" in message and "overwrite=True" in message and "\n" not in message
    if can_continue:
        assert f"{can_continue}=True" in message


def refused_over_an_old_file(tmp_path, monkeypatch, writer: str, overwrite: bool, error) -> tuple:
    """Call the library writer ``writer`` over an old out.file (with ``overwrite``) among the stand-in inputs: it
    raises ``error`` and leaves the old file as it was, and no other out* file.  Returns (the error, the
    writer's option that continues a file, if any)."""
    monkeypatch.chdir(tmp_path)
    stand_ins(tmp_path)
    call, can_continue = api_writers()[writer]
    out = tmp_path / "out.file"
    out.write_bytes(PREVIOUS)
    with pytest.raises(error) as info:
        call(out, overwrite)
    assert out.read_bytes() == PREVIOUS
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("out")) == ["out.file"]
    return info.value, can_continue


@pytest.mark.parametrize("writer", ["measure", "train_from_file", "identify_to_file", "export_result",
                                    "write_system"])
def test_library_writers_given_overwrite_fail_on_their_input_and_leave_the_old_file(tmp_path, monkeypatch, writer):
    from servofmu.errors import UserError
    from servofmu.fileio import OutputExists

    refused, _ = refused_over_an_old_file(tmp_path, monkeypatch, writer, True, UserError)
    assert not isinstance(refused, OutputExists)  # the input's error, not the output's
