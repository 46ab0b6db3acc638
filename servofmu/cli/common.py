"""What every subcommand's module shares: the parser class that knows a command's inputs and outputs, the progress
bar, and the run options taken from the command line."""
from __future__ import annotations

import argparse
import sys

from ..runtime import EXIT_USER_ERROR, WORK_LIMIT_HOURS, RunOptions, show_warnings, stop_if_asked

__all__ = ["Parser", "DeprecatedAlias", "ProgressBar", "float_list", "add_progress_option", "add_work_limit_option", "run_options",
           "output_mode_of"]


class Parser(argparse.ArgumentParser):
    """argparse that reports a bad command line in one line, and that knows a subcommand's files: every ``-o`` and
    every argument added with ``role="output"`` is an output (``args.outputs`` names them, ``args.output_options``
    their options; a subcommand with outputs gets ``--force``), every argument added with ``role="input"`` an input
    (``args.inputs``), so that the one output rule is applied to them together before any work."""

    def error(self, message):
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}\n")

    def add_argument(self, *flags, role: str | None = None, **kwargs):
        action = super().add_argument(*flags, **kwargs)
        if "-o" in flags or role == "output":
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

    def __init__(self, args, unit: str, scale: int = 1):
        self._unit, self._scale, self._bar = unit, scale, None
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
            self._bar = tqdm(total=total, unit=self._unit, file=sys.stderr, dynamic_ncols=True,
                             bar_format=None if self._scale == 1 else
                             "{l_bar}{bar}| {n:.2f}/{total:g} [{elapsed}<{remaining}]")
        self._bar.total, self._bar.n = total, done
        self._bar.refresh()

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
