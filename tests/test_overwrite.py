"""The overwrite rule (docs/reliability.md) on every command that writes a file: an output that exists already is
refused without --force, in one line with exit status 2, before any work and without touching the file; and a run
given --force that then fails (here on an input that is not what it claims) leaves the old file as it was.

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
CONTINUE = {"measure": "--resume", "dataset": "--resume", "import": "--append", "cosim": "--append",
            "identify": "--resume"}


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
    proc = run("demo", "--out", tmp_path / "demo")
    assert_one_line_error(proc, "exists already", "--force")
    assert [p.name for p in (tmp_path / "demo").iterdir()] == ["keep.txt"]
    assert (tmp_path / "demo" / "keep.txt").read_bytes() == PREVIOUS
