"""What every subcommand's module shares: the parser class that knows a command's inputs and outputs, the progress
bar, and the run options taken from the command line."""
from __future__ import annotations

import argparse
import sys

from ..runtime import EXIT_USER_ERROR, WORK_LIMIT_HOURS, RunOptions, show_warnings, stop_if_asked

__all__ = ["Parser", "DeprecatedAlias", "OutputFile", "ProgressBar", "float_list", "add_progress_option",
           "add_work_limit_option", "add_output_option", "add_json_option", "print_written", "run_options",
           "output_mode_of", "DATA_SUFFIXES"]

DATA_SUFFIXES = (".h5", ".hdf5")  # what a data file's name ends with (measure's and import's -o)


class Parser(argparse.ArgumentParser):
    """argparse that reports a bad command line in one line, and that knows a subcommand's files: every ``-o`` and
    every argument added with ``role="output"`` is an output (``args.outputs`` names them, ``args.output_options``
    their options; a subcommand with outputs gets ``--force``), every argument added with ``role="input"`` an input
    (``args.inputs``), so that the one output rule is applied to them together before any work."""

    def error(self, message):
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}\n")

    def parse_args(self, args=None, namespace=None):
        """As argparse's, but an unrecognised argument is reported by the subcommand it was given to (``servofmu
        identify: error: unrecognized arguments: --bogus``), not by the top parser."""
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            owner = getattr(self, "subcommands", {}).get(getattr(namespace, "command", None), self)
            owner.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace

    def add_argument(self, *flags, role: str | None = None, **kwargs):
        action = super().add_argument(*flags, **kwargs)
        if role != "folder" and ("-o" in flags or role == "output"):
            if not self.get_default("outputs"):
                super().add_argument("--force", action="store_true", help="replace an existing output")
            self.set_defaults(outputs=(*(self.get_default("outputs") or ()), action.dest),
                              output_options={**(self.get_default("output_options") or {}),
                                              action.dest: "-o" if "-o" in flags else flags[0]})
        if role == "input":
            self.set_defaults(inputs=(*(self.get_default("inputs") or ()), action.dest))
        return action


class DeprecatedAlias(argparse.Action):
    """An old spelling of an option: stores into the new option's destination and says once, on stderr, which
    spelling to use instead (``alias_of``)."""

    def __init__(self, option_strings, dest, alias_of: str = "", **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.alias_of = alias_of

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog}: warning: {option_string} is deprecated, use {self.alias_of}", file=sys.stderr)
        setattr(namespace, self.dest, values)


class OutputFile(argparse.Action):
    """``-o/--output`` of measure and import, where ``--output NAME`` once named the output variable: ``-o`` takes
    any file name, ``--output`` one that is recognisably a file (a data file's suffix, or a folder in it); any other
    value is refused with one line pointing to ``--output-variable`` (docs/cli.md)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from pathlib import Path

        if option_string == "--output" and Path(values).suffix.lower() not in DATA_SUFFIXES and "/" not in values:
            parser.error(f"--output {values}: --output is the data file to write (as -o, e.g. --output "
                         f"{values}.h5); the output variable is --output-variable {values}")
        setattr(namespace, self.dest, values)


def add_output_option(p, help: str, metavar: str = "FILE", required: bool = False, **kwargs):
    """``-o/--output``: the file (or folder, ``role="folder"``) the command writes; the same two spellings in every
    subcommand."""
    return p.add_argument("-o", "--output", metavar=metavar, required=required, help=help, **kwargs)


def add_json_option(p, help: str = "print a JSON summary of what was written (files, counts, key figures) on "
                                   "stdout instead of the text") -> None:
    """``--json``: the command's summary as one JSON object on stdout."""
    p.add_argument("--json", action="store_true", help=help)


def print_written(args, text: str, summary: dict) -> None:
    """What a command wrote: ``text`` (its lines), or with ``--json`` ``summary`` as one JSON object (numbers that
    are not finite as null; paths as strings: display.json_safe)."""
    import json

    from ..display import json_safe

    print(json.dumps(json_safe(summary), allow_nan=False) if getattr(args, "json", False) else text)


def float_list(text: str) -> list[float]:
    """A comma-separated list of numbers (``--amplitudes 2.0,0.6``)."""
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None


def add_progress_option(p: argparse.ArgumentParser) -> None:
    """``--progress``: draw the progress bar also when stderr is not a terminal (a log file, a pipe)."""
    p.add_argument("--progress", action="store_true",
                   help="show the progress bar even when stderr is not a terminal")


class ProgressBar:
    """``with ProgressBar(args, unit) as bar``: a tqdm bar on stderr driven by ``bar.update(done, total)``, drawn
    only when stderr is a terminal or ``--progress`` was given (and not with ``--json``); warnings go above it.
    ``scale``: how many of the callback's units make one ``unit`` (measure counts thousandths of an experiment).
    Every update also raises a stop signal that a finaliser swallowed (runtime.stop_if_asked)."""

    def __init__(self, args, unit: str, scale: int = 1, label: str | None = None):
        self._unit, self._scale, self._bar = unit, scale, None
        self._label = label or getattr(args, "command", None) or "servofmu"
        self.shown = not getattr(args, "json", False) and (getattr(args, "progress", False) or sys.stderr.isatty())
        self._warnings = show_warnings(self.warn)

    def __enter__(self) -> "ProgressBar":
        self._warnings.__enter__()
        return self

    def update(self, done: int, total: int) -> None:
        """The progress callback (runtime.Progress)."""
        stop_if_asked()
        if not self.shown:
            return
        total, done = (total, done) if self._scale == 1 else (total / self._scale, done / self._scale)
        if self._bar is None:  # created on first use: a run that fails early shows no bar
            from tqdm import tqdm
            self._bar = tqdm(total=total, unit=f" {self._unit}s", desc=self._label, file=sys.stderr,
                             dynamic_ncols=True, bar_format="{l_bar}{bar}| " + (
                                 "{n_fmt}/{total_fmt}" if self._scale == 1 else "{n:.2f}/{total:g}")
                             + f" {self._unit}s [{{elapsed}}<{{remaining}}]")
        self._bar.total, self._bar.n = total, done
        self._bar.refresh()

    def stage(self, label: str, unit: str | None = None, scale: int = 1):
        """A new bar for the next step of a command of several (the demo's measure, training set, training):
        ``label`` and ``unit`` name it; returns its progress callback."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        self._label, self._unit, self._scale = label, unit or self._unit, scale
        return self.update

    def label(self, text: str) -> None:
        """Name what the bar counts now (compare's current method)."""
        self._label = text
        if self._bar is not None:
            self._bar.set_description_str(text)

    def say(self, text: str) -> None:
        """One line of the command's output on stdout, above the bar."""
        if self._bar is None:
            print(text)
        else:
            self._bar.write(text, file=sys.stdout)

    def warn(self, text: str) -> None:
        """One warning line on stderr, above the bar."""
        if self._bar is None:
            print(f"warning: {text}", file=sys.stderr)
        else:
            self._bar.write(f"warning: {text}", file=sys.stderr)

    def __exit__(self, kind, value, traceback) -> None:
        self._warnings.__exit__(kind, value, traceback)
        if self._bar is not None:
            self._bar.leave = kind is None  # a failed run ends with its one error line, no bar
            self._bar.close()


def add_work_limit_option(p) -> None:
    """--work-limit: the hours a command's search may be estimated at before it is refused."""
    p.add_argument("--work-limit", type=float, default=WORK_LIMIT_HOURS, metavar="HOURS",
                   help="refuse a search estimated at more than HOURS of this machine's time (default "
                        f"{WORK_LIMIT_HOURS:g})")


def output_mode_of(args) -> str:
    """The output rule's mode (fileio.claim_output) that a command's options ask for."""
    if getattr(args, "resume", False) or getattr(args, "append", False):
        return "continue"
    return "replace" if getattr(args, "force", False) else "new"


def run_options(args, bar: ProgressBar | None = None) -> RunOptions:
    """The options of a long library call (runtime.RunOptions) from the command line: workers, scheduler, resume,
    --force, the bar's progress callback and the command line itself (provenance)."""
    return RunOptions(workers=getattr(args, "workers", None), scheduler=getattr(args, "scheduler", None),
                      resume=getattr(args, "resume", False), overwrite=getattr(args, "force", False),
                      progress=None if bar is None else bar.update, command=args.command_line)
