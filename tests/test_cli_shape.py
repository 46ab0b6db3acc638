"""The command line reads well and stays thin: help on every option, the old spelling of a renamed option still
working, a bare `servofmu` listing the commands, an output that is one of the run's inputs refused before any work;
and the shape of the package measured (function and module lengths, handler lengths)."""
from __future__ import annotations

import argparse
import ast
from pathlib import Path

import pytest
from clitools import assert_one_line_error, run

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "servofmu"
MAX_FUNCTION, MAX_HANDLER, MAX_MODULE = 80, 20, 500


def subcommands():
    from servofmu.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, sub.choices


def test_every_option_of_every_subcommand_has_help(capsys):
    parser, choices = subcommands()
    assert len(choices) >= 17
    for name, p in [("servofmu", parser), *choices.items()]:
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue
            assert action.help and action.help != argparse.SUPPRESS, (name, action.option_strings or action.dest)
        with pytest.raises(SystemExit) as exit_:
            parser.parse_args([name, "--help"] if name != "servofmu" else ["--help"])
        assert exit_.value.code == 0
        assert "usage:" in capsys.readouterr().out


def test_a_bare_servofmu_prints_the_usage_and_the_commands_with_status_2():
    proc = run()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("usage: servofmu")
    for command in ("build", "measure", "identify", "export", "controller", "demo"):
        assert f"    {command} " in proc.stderr or f"    {command}\n" in proc.stderr, command


def test_building_a_controller_file_as_a_plant_points_to_the_controller_command(tmp_path):
    proc = run("build", "axis_controller", "-o", tmp_path / "x.fmu")
    assert_one_line_error(proc, "axis_controller", "controller file", "servofmu controller")
    assert "unknown key" not in proc.stderr


def test_the_old_spelling_output_variable_is_refused_in_one_line_and_output_is_the_data_file(tmp_path):
    """`--output` is the file written in every command (docs/cli.md); in import (and measure), where it once named
    the output variable, `--output NAME` says to use --output-variable, and `--output FILE.h5` is the data file."""
    csv = tmp_path / "r.csv"
    csv.write_text("time,force,speed\n" + "".join(f"{k * 1e-3},{(-1) ** (k // 50)},{0.01 * k}\n"
                                                  for k in range(400)))
    old = run("import", csv, "--time", "time", "--input", "force", "--output", "speed", "-o", tmp_path / "old.h5")
    assert_one_line_error(old, "servofmu import: error: --output speed:", "--output-variable speed")
    assert not (tmp_path / "old.h5").exists()
    long = run("import", csv, "--time", "time", "--input", "force", "--output-variable", "speed",
               "--output", tmp_path / "long.h5")
    new = run("import", csv, "--time", "time", "--input", "force", "--output-variable", "speed",
              "-o", tmp_path / "new.h5")
    assert long.returncode == 0 and new.returncode == 0, (long.stderr, new.stderr)
    assert long.stderr == new.stderr == ""
    assert long.stdout.replace("long.h5", "new.h5") == new.stdout


@pytest.mark.parametrize("argv", [
    ["identify", "in.h5", "--structure", "g1", "--method", "pso", "--force", "-o", "in.h5"],
    ["measure", "in.fmu", "--frequencies", "1", "--force", "-o", "in.fmu"],
    ["export", "in.h5", "--format", "toml", "--force", "-o", "in.h5"],
    ["train", "in.h5", "--force", "-o", "in.h5"],
    ["dataset", "g1", "--like", "in.h5", "--samples", "10", "--force", "-o", "in.h5"],
    ["import", "in.csv", "--time", "t", "--input", "u", "--output-variable", "v", "--force", "-o", "in.csv"],
])
def test_an_output_that_is_one_of_the_inputs_is_refused_before_any_work(tmp_path, argv):
    for name in ("in.h5", "in.fmu", "in.csv"):
        (tmp_path / name).write_bytes(b"the input\n")
    proc = run(*argv, cwd=tmp_path)
    assert_one_line_error(proc, f"{argv[-1]}: is also an input of this run")
    assert (tmp_path / argv[-1]).read_bytes() == b"the input\n"


def test_the_library_refuses_the_same_file_under_another_name(tmp_path):
    from servofmu.errors import UserError
    from servofmu.fileio import claim_output

    (tmp_path / "a.h5").write_bytes(b"x")
    (tmp_path / "b.h5").symlink_to(tmp_path / "a.h5")
    with pytest.raises(UserError, match="is also an input"):
        claim_output(tmp_path / "b.h5", "replace", inputs=[tmp_path / "a.h5"])
    assert claim_output(tmp_path / "c.h5", "new", inputs=[tmp_path / "a.h5"]) == tmp_path / "c.h5"


def test_a_stop_signal_while_an_output_is_claimed_leaves_no_probe_behind(tmp_path, monkeypatch):
    import os

    from servofmu import fileio

    close = os.close

    def interrupted_close(fd):  # Ctrl-C right after the probe file was made
        close(fd)
        raise KeyboardInterrupt

    monkeypatch.setattr(fileio.os, "close", interrupted_close)
    with pytest.raises(KeyboardInterrupt):
        fileio.claim_output(tmp_path / "a.h5", "new")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_the_library_and_the_command_line_refuse_an_existing_output_in_the_same_words(tmp_path):
    from servofmu.fileio import OutputExists, claim_output

    (tmp_path / "a.h5").write_bytes(b"x")
    with pytest.raises(OutputExists) as refused:
        claim_output(tmp_path / "a.h5", "new", can_continue="resume")
    assert str(refused.value).endswith("a.h5: exists already (give overwrite=True to replace it, or resume=True to "
                                       "continue it)")
    assert refused.value.command_line_text().endswith("a.h5: exists already (give --force to replace it, or "
                                                      "--resume to continue it)")
    assert claim_output(tmp_path / "a.h5", "replace") == tmp_path / "a.h5"
    assert claim_output(tmp_path / "a.h5", "continue") == tmp_path / "a.h5"


# ---------------------------------------------------------------------------
# The shape of the package
# ---------------------------------------------------------------------------
def functions(path: Path):
    """(name, lines without the docstring) of every function and method in ``path``."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            signature = body[0].lineno - node.lineno or 1  # the def line(s) count
            if isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                body = body[1:]
            yield node.name, signature + ((body[-1].end_lineno - body[0].lineno + 1) if body else 0)


def lines_of_code(path: Path):
    """(name, lines of code) of every function and method in ``path``: its lines from the def to its end, the
    docstring's included, blank lines and lines holding only a comment left out."""
    text = path.read_text()
    lines = text.splitlines()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node.name, sum(1 for line in lines[node.lineno - 1:node.end_lineno]
                                 if line.strip() and not line.strip().startswith("#"))


def package_modules():
    return sorted(PACKAGE.rglob("*.py"))


def test_the_package_is_every_python_file_below_servofmu():
    """The length checks read every module of the package, its stages' subpackages included."""
    found = {p.relative_to(PACKAGE).parts[0] for p in package_modules()}
    assert {"commands", "measurement", "cli", "output", "model"} <= found


@pytest.mark.parametrize("path", package_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_function_is_longer_than_80_lines(path):
    """No function has more than 80 lines of code, its signature and docstring included (issue 44's rule)."""
    long = [(name, n) for name, n in lines_of_code(path) if n > MAX_FUNCTION]
    assert not long, f"{path.relative_to(ROOT)}: {long}"


def test_the_length_check_counts_the_docstring_and_not_blank_lines(tmp_path):
    """A def line, a 10-line docstring and 70 statements are 81 lines of code; blank and comment lines add none."""
    body = "\n".join(f"    x{i} = {i}" for i in range(70))
    probe = tmp_path / "probe.py"
    probe.write_text('def f():\n    """' + "\n".join(["doc"] * 10) + '"""\n\n    # why\n' + body + "\n")
    assert dict(lines_of_code(probe)) == {"f": 81}
    probe.write_text("def g():\n" + body + "\n\n    # why\n\n")
    assert dict(lines_of_code(probe)) == {"g": 71}


@pytest.mark.parametrize("path", package_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_is_longer_than_500_lines_unless_its_docstring_says_why(path):
    lines = len(path.read_text().splitlines())
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    assert lines <= MAX_MODULE or "500 lines" in doc, f"{path.relative_to(ROOT)}: {lines} lines"


def test_every_command_line_handler_is_short_and_the_cli_is_one_module_per_group():
    handlers = {}
    for path in sorted((PACKAGE / "cli").glob("*.py")):
        handlers.update({f"{path.stem}.{name}": n for name, n in functions(path) if name.startswith("cmd_")})
    assert len(handlers) >= 18, handlers
    long = {name: n for name, n in handlers.items() if n > MAX_HANDLER}
    assert not long, long
    assert not (PACKAGE / "cli.py").exists()
