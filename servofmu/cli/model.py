"""`servofmu build` and `servofmu simulate`: a plant file to an FMU, an FMU run in FMPy."""
from __future__ import annotations

import sys

from ..errors import UserError
from .common import add_json_option, print_written

__all__ = ["register", "cmd_build", "cmd_simulate"]


def cmd_build(args) -> None:
    """Build the FMU of a plant file."""
    from ..fmu import build_fmu
    from ..model.plant import load_plant

    plant = load_plant(args.plant)
    output = build_fmu(plant, args.output or f"{plant.name}.fmu", fmi_version=args.fmi_version, overwrite=args.force)
    print_written(args, f"wrote {output} (FMI {args.fmi_version}.0, Model Exchange + Co-Simulation)",
                  {"written": [output], "plant": plant.name, "fmi_version": args.fmi_version,
                   "interfaces": ["ModelExchange", "CoSimulation"]})


def cmd_simulate(args) -> None:
    """Run an FMU in FMPy; the result as CSV on stdout or in a file."""
    from ..fileio import atomic_write
    from ..simulation.fmpy_runs import format_csv, read_input_csv, simulate

    if args.input and (args.amplitude is not None or args.frequency is not None):
        raise UserError("give either --input or --amplitude/--frequency, not both")
    if args.json and not args.output:
        raise UserError("--json: give -o FILE.csv (without -o the result itself is the CSV on stdout)")
    signal = read_input_csv(args.input, args.input_name) if args.input else None
    result = simulate(args.fmu, args.stop_time, interface=args.interface, amplitude=args.amplitude,
                      frequency=args.frequency, input_signal=signal, output_interval=args.output_interval,
                      relative_tolerance=args.tolerance)
    if not args.output:
        sys.stdout.write(format_csv(result))
        return
    atomic_write(args.output, format_csv(result))
    print_written(args, f"wrote {args.output} ({len(result)} rows: {', '.join(result.dtype.names)})",
                  {"written": [args.output], "rows": len(result), "columns": list(result.dtype.names),
                   "stop_time_s": args.stop_time})


def register(sub) -> None:
    """Add the subcommands build and simulate to the subparsers ``sub``."""
    p = sub.add_parser("build", help="build an FMU from a plant file")
    p.add_argument("plant", role="input", help="plant file (TOML) or the name of one in fmu_models/")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), default=3, help="FMI version (default 3)")
    add_json_option(p)
    p.add_argument("-o", "--output", help="FMU file to write (default: NAME.fmu)")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("simulate", help="run an FMU in FMPy")
    p.add_argument("fmu", role="input", help="the FMU to run")
    p.add_argument("--interface", choices=("me", "cs"), default="me",
                   help="me: Model Exchange with FMPy's solver (default), cs: Co-Simulation")
    p.add_argument("--amplitude", type=float, help="built-in sine excitation amplitude (servofmu FMUs)")
    p.add_argument("--frequency", type=float, help="built-in sine excitation frequency in Hz")
    p.add_argument("--input", role="input", help="CSV with columns time and the input (drives the input port)")
    p.add_argument("--input-name", default="u", help="input variable fed from --input (default u)")
    p.add_argument("--stop-time", type=float, required=True, help="seconds to simulate")
    p.add_argument("--output-interval", type=float, help="output interval in s (default: FMU's step size)")
    p.add_argument("--tolerance", type=float, help="relative tolerance (default: the FMU's)")
    add_json_option(p, "with -o: print a JSON summary of the file written (rows, columns) instead of the text")
    p.add_argument("-o", "--output", help="CSV to write (default: stdout)")
    p.set_defaults(func=cmd_simulate)
