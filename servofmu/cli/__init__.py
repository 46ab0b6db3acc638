"""The `servofmu` command: a thin front end over the library.

This is the only place that prints, configures logging or shows progress bars.  Each subcommand lives in the
module of its group (model, measure, broadband, identify, select, output, control, tune, demo), its arguments beside its
handler; a handler calls one library function and prints what it returned.  How a command ends — one line and exit status 2 for a
user error, 130 for Ctrl-C, 128 + n for SIGTERM or SIGHUP, no traceback, nothing partial left — is
servofmu.runtime's (run_command, finish).

One rule for every output (docs/reliability.md, servofmu.claims): all outputs of a subcommand (every ``-o``,
``--report``, ``--plant``, ...) are checked together before any work — its folder exists and is writable, no two are
one file, none is one of the command's inputs (an example's name stands for its file) nor inside servofmu's own
package, and it does not exist yet unless ``--force`` (replace it) or the subcommand's ``--resume`` or ``--append``
is given.

``servofmu`` alone prints the usage and the list of subcommands on stderr and exits with status 2, as a command
line without its subcommand is an incomplete one.
"""
from __future__ import annotations

import argparse
import shlex
import sys

from ..errors import UserError
from ..runtime import EXIT_USER_ERROR, CommandRun, finish, run_command
from . import broadband, control, demo, identify, measure, model, output, select, tune
from .common import Parser, output_mode_of

__all__ = ["main", "build_parser", "run", "flags_named", "FLAG_OF"]

GROUPS = (model, measure, broadband, identify, select, output, control, tune, demo)  # in the order of the help's list


def build_parser() -> argparse.ArgumentParser:
    """The parser of every subcommand (each group's module registers its own)."""
    from ..version import __version__

    parser = Parser(prog="servofmu", description="Servo drives with friction: FMUs, measurement, identification.")
    parser.add_argument("--version", action="version", version=f"servofmu {__version__}",
                        help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for group in GROUPS:
        group.register(sub)
    parser.subcommands = sub.choices  # an unrecognised argument is reported by its subcommand (Parser.parse_args)
    return parser


# Library arguments that the command line spells otherwise than --NAME-WITH-DASHES (the rest follow the rule).
FLAG_OF = {"relative_tolerance": "--tolerance", "noise_snr_db": "--noise-snr", "output_column": "--output-variable"}


def flags_named(text: str, parser: argparse.ArgumentParser) -> str:
    """A library message as the command line says it: the Python arguments it names (``fmi_version``) as the
    options of this subcommand that set them (``--fmi-version``)."""
    import re

    flags = {a.dest: next((o for o in a.option_strings if o.startswith("--")), a.option_strings[0])
             for a in parser._actions if a.option_strings and a.dest != "help"}
    names = {**{d: f for d, f in flags.items() if "_" in d}, **{k: v for k, v in FLAG_OF.items()
                                                                 if v in flags.values()}}
    for name, flag in names.items():
        text = re.sub(rf"(?<![\w./-]){re.escape(name)}(?![\w/.-]|=True)", flag, text)
    first = re.match(r"(\w+) must\b", text)  # "frequency must be positive": a one-word argument, at the start
    if first and first.group(1) in flags:
        text = flags[first.group(1)] + text[first.end(1):]
    return text


def _claim_outputs(args) -> None:
    """The output rule, before any work, for all of the command's outputs together (see the module's docstring):
    also no two outputs one file, and an input given by an example's name is the example file."""
    from ..claims import claim_outputs, refuse_package_data

    inputs = []
    for dest in getattr(args, "inputs", ()):
        value = getattr(args, dest)
        inputs += [_input_file(v) for v in (value if isinstance(value, list) else [value]) if v is not None]
    if hasattr(args, "default_outputs"):  # outputs a command names after another one (select's SELECT.toml)
        args.default_outputs(args)
    options = getattr(args, "output_options", {})
    outputs = {options.get(dest, f"--{dest}"): getattr(args, dest) for dest in getattr(args, "outputs", ())}
    can_continue = getattr(args, "continues_outputs", None) if hasattr(args, "continues_outputs") else \
        next((name for name in ("resume", "append") if hasattr(args, name)), None)
    claim_outputs(outputs, output_mode_of(args), inputs, can_continue)
    for dest in getattr(args, "output_folders", ()):  # identify --output-dir, demo --out
        if getattr(args, dest) is not None:
            refuse_package_data(getattr(args, dest))


def _input_file(value: str) -> str:
    """An input as the file it names: a path, or an example's name (``axis_controller``) as its file."""
    from pathlib import Path

    if Path(value).suffix or Path(value).exists():
        return value
    from ..model.plant import example_files

    return str(example_files().get(value, value))


def _command(run: CommandRun, argv: list[str]) -> None:
    from ..fileio import output_claims
    from ..runtime import show_warnings, sweep_temporary_folders

    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        raise SystemExit(EXIT_USER_ERROR)
    run.who = f"servofmu {args.command}"
    args.command_line = shlex.join(["servofmu", *argv])
    sweep_temporary_folders()
    with output_claims(), show_warnings():  # outputs held until the command ends; warnings one line each
        _claim_outputs(args)
        try:
            args.func(args)
        except UserError as exc:  # the flags, not the library's argument names
            if exc.args and isinstance(exc.args[0], str):
                exc.args = (flags_named(exc.args[0], parser.subcommands[args.command]), *exc.args[1:])
            raise
    run.quick_exit = getattr(args, "quick_exit", False)


def _main(argv: list[str] | None) -> tuple[int, CommandRun]:
    argv = sys.argv[1:] if argv is None else list(argv)
    words = [a for a in argv if not a.startswith("-")]
    run = CommandRun(who=f"servofmu {words[0]}" if words else "servofmu")  # (a stop while the modules load names it)
    code = run_command(run, lambda r: _command(r, argv))
    if run.message:
        print(run.message, file=sys.stderr)
    return code, run


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv`` (default: this process's arguments); returns the exit status."""
    return _main(argv)[0]


def run() -> None:
    """The installed `servofmu` command: :func:`main`, then the exit — quick (no interpreter teardown) after a
    command that asks for it, identify, which is called in loops over axes, records and structures
    (runtime.finish)."""
    code, command = _main(None)
    finish(code, command.quick_exit)
