"""The `servofmu` command: a thin front end over the library.

This is the only place that prints, configures logging or shows progress bars.
A UserError (or an OSError) ends the command with one line on stderr and exit
status 2; no traceback.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .errors import UserError

EXIT_USER_ERROR = 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports a bad command line in one line."""

    def error(self, message):
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}\n")


def _float_list(text: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of numbers: {text!r}") from None


# ---------------------------------------------------------------------------
# build / simulate
# ---------------------------------------------------------------------------
def cmd_build(args) -> None:
    from .fmu import build_fmu
    from .plant import load_plant

    plant = load_plant(args.plant)
    output = Path(args.output) if args.output else Path(f"{plant.name}.fmu")
    build_fmu(plant, output, fmi_version=args.fmi_version)
    print(f"wrote {output} (FMI {args.fmi_version}.0, Model Exchange + Co-Simulation)")


def cmd_simulate(args) -> None:
    from .fileio import atomic_write, check_output_path
    from .simulate import format_csv, read_input_csv, simulate

    if args.output:
        check_output_path(args.output)
    if args.input and (args.amplitude is not None or args.frequency is not None):
        raise UserError("give either --input or --amplitude/--frequency, not both")
    signal = read_input_csv(args.input, args.input_name) if args.input else None
    result = simulate(args.fmu, args.stop_time, interface=args.interface, amplitude=args.amplitude,
                      frequency=args.frequency, input_signal=signal, output_interval=args.output_interval,
                      relative_tolerance=args.tolerance)
    text = format_csv(result)
    if args.output:
        atomic_write(args.output, text)
        print(f"wrote {args.output} ({len(result)} rows: {', '.join(result.dtype.names)})")
    else:
        sys.stdout.write(text)


# ---------------------------------------------------------------------------
# demo
# ---------------------------------------------------------------------------
def cmd_demo(args) -> None:
    from .demo import run_demo

    run_demo(Path(args.out), report=print)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="servofmu", description="Servo drives with friction: FMUs, measurement, identification.")
    parser.add_argument("--version", action="version", version=f"servofmu {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("build", help="build an FMU from a plant file")
    p.add_argument("plant", help="plant file (TOML) or the name of one in fmu_models/")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), default=3)
    p.add_argument("-o", "--output", help="FMU file to write (default: NAME.fmu)")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("simulate", help="run an FMU in FMPy")
    p.add_argument("fmu")
    p.add_argument("--interface", choices=("me", "cs"), default="me")
    p.add_argument("--amplitude", type=float, help="built-in sine excitation amplitude (servofmu FMUs)")
    p.add_argument("--frequency", type=float, help="built-in sine excitation frequency in Hz")
    p.add_argument("--input", help="CSV with columns time and the input (drives the input port)")
    p.add_argument("--input-name", default="u", help="input variable fed from --input (default u)")
    p.add_argument("--stop-time", type=float, required=True)
    p.add_argument("--output-interval", type=float, help="output interval in s (default: FMU's step size)")
    p.add_argument("--tolerance", type=float, help="relative tolerance (default: the FMU's)")
    p.add_argument("-o", "--output", help="CSV to write (default: stdout)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("demo", help="the whole path on the paper's plants g1 and g2")
    p.add_argument("--out", default="demo-output", help="folder for the demo's files (default demo-output)")
    p.set_defaults(func=cmd_demo)
    return parser


def _version() -> str:
    from . import __version__
    return __version__


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except UserError as exc:
        print(f"servofmu {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"servofmu {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(f"servofmu {args.command}: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
