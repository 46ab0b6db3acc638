"""`servofmu measure`, `servofmu import` and `servofmu plot`: data files from an FMU or from machine records."""
from __future__ import annotations

from pathlib import Path

from ..errors import UserError
from . import broadband
from .common import (OutputFile, ProgressBar, add_json_option, add_progress_option, float_list, print_written,
                     run_options)

__all__ = ["register", "cmd_measure", "cmd_import", "cmd_plot", "MAX_STEPS", "INTERSAMPLE"]

# The library's values (servofmu.measurement.excitation.MAX_STEPS, servofmu.model.signals.INTERSAMPLE), here as
# literals so that `--help` loads no numpy (tests/test_cli_options.py checks that they agree).
MAX_STEPS = 1e8
INTERSAMPLE = ("zoh", "foh")


def cmd_measure(args) -> None:
    """Stepped-sine measurement of an FMU into a data file (broadband with --excitation)."""
    from ..measurement.measure import PROGRESS_SCALE, MeasureOptions, measure

    if args.excitation:
        return broadband.cmd_measure_broadband(args)

    given = {"input": args.input, "output": args.output_variable, "tolerance": args.tolerance,
             "max_time": args.max_time, "samples_per_period": args.samples_per_period,
             "noise_snr_db": args.noise_snr, "seed": args.seed}
    options = MeasureOptions(**{k: v for k, v in given.items() if v is not None})
    with ProgressBar(args, "experiment", scale=PROGRESS_SCALE) as bar:
        data = measure(args.fmu, args.data, amplitudes=args.amplitudes, frequencies=args.frequencies,
                       options=options, run=run_options(args, bar), max_steps=args.max_steps)
    _print_measured(args, data)


def _print_measured(args, data) -> None:
    unsettled = sum(not e.converged for e in data.experiments)
    print_written(args, f"wrote {args.data}: {len(data.experiments)} experiments, amplitudes "
                  f"{', '.join(f'{m:g}' for m in data.plan.amplitudes)} N x frequencies "
                  f"{', '.join(f'{f:g}' for f in data.plan.frequencies)} Hz"
                  + (f"; {unsettled} without steady state (flagged)" if unsettled else "; all reached steady state"),
                  {"written": [args.data], "kind": "stepped-sine", "experiments": len(data.experiments),
                   "amplitudes_N": [float(m) for m in data.plan.amplitudes],
                   "frequencies_Hz": [float(f) for f in data.plan.frequencies], "without_steady_state": unsettled})


def record_line(r) -> str:
    """One imported record in one line: samples, rate, kind, hold, and the sine found in it."""
    import numpy as np

    line = f"{r.source}: {len(r.series.time)} samples at {r.sample_rate:.6g} Hz, {r.kind}, input {r.intersample}"
    if r.time_step is not None:
        line += (f"; time stamps every {r.time_step:.9g} s, jitter RMS {r.time_jitter / r.time_step:.3g} (max "
                 f"{r.time_jitter_max / r.time_step:.3g}) of a sample")
    if r.series.reference is not None:
        line += "; closed loop (reference" + (", disturbance" if r.series.disturbance is not None else "") + ")"
    if r.analysis is not None:
        a = r.analysis
        line += (f"; sine {a.frequency:.6g} Hz, |U1| {abs(a.U1):.4g} N, H = {abs(a.H):.4g} m/(N.s) "
                 f"at {np.degrees(np.angle(a.H)):.2f} deg" + ("" if a.converged else " (not settled)"))
    elif r.note:
        line += f"; {r.note}"
    return line


def cmd_import(args) -> None:
    """Machine records (CSV or MAT) into a data file."""
    from ..measurement.records import LoopChannels, import_records

    if args.output_variable is None:
        raise UserError("give --output-variable COLUMN: the velocity or position column")
    if args.excitation is not None:
        return broadband.cmd_import_broadband(args)
    loop = LoopChannels(args.reference, args.disturbance, args.input_scale, args.disturbance_scale)
    with ProgressBar(args, "file") as bar:
        data = import_records(args.files, args.data, time=args.time, input=args.input,
                              output_column=args.output_variable, kind=args.kind, cutoff=args.cutoff,
                              frequency=args.frequency, append=args.append, intersample=args.intersample,
                              run=run_options(args, bar), loop=loop)
    new = data.records[-len(args.files):]
    print_written(args, "\n".join([*map(record_line, new), f"wrote {args.data}: {len(data.records)} records"]),
                  {"written": [args.data], "kind": "records", "records": len(data.records),
                   "imported": [{"source": str(r.source), "samples": len(r.series.time),
                                 "sample_rate_Hz": float(r.sample_rate), "kind": r.kind} for r in new]})


def cmd_plot(args) -> None:
    """A Bode plot of a measurement, the time series of records."""
    from ..measurement.datafile import read_data_file
    from ..output.plots import bode_figure, time_series_figure

    data = read_data_file(args.data)
    what = args.what or ("time" if data.kind == "records" else "bode")
    if data.kind == "broadband":
        return _plot_broadband(args, what)
    draw = bode_figure if what == "bode" else time_series_figure
    out = draw(data, args.output or Path(args.data).with_suffix(".png"), overwrite=args.force)
    print_written(args, f"wrote {out}", {"written": [out], "figure": what, "data": args.data})


def _plot_broadband(args, what: str) -> None:
    """The Bode plot of a broadband data file: its BLA per level with the ±2σ band (as `servofmu frf -o FIG`)."""
    if what != "bode":
        raise UserError(f"{args.data}: broadband data is drawn as its BLA (--what bode; `servofmu frf` for the "
                        "numbers), not as time series")
    from ..broadband.frf import frf_of_file
    from ..output.bla_plots import bla_figure

    _, levels = frf_of_file(args.data)
    out = bla_figure(levels, args.output or Path(args.data).with_suffix(".png"),
                     f"{Path(args.data).name}: BLA, ±2σ", overwrite=args.force)
    print_written(args, f"wrote {out}", {"written": [out], "figure": "bode", "data": args.data,
                                          "levels": len(levels)})


def _add_output_variable(p, what: str, required_text: str) -> None:
    p.add_argument("--output-variable", metavar="NAME", help=f"{what}{required_text}")


def _add_data_output(p) -> None:
    """-o/--output DATA.h5; ``--output NAME`` without a data file's suffix is refused, pointing to
    --output-variable (its meaning before)."""
    p.add_argument("-o", "--output", dest="data", metavar="DATA.h5", required=True, action=OutputFile,
                   help="data file to write (--output NAME without .h5 is refused: the output variable is "
                        "--output-variable)")


def register(sub) -> None:
    """Add the subcommands measure, import and plot to the subparsers ``sub``."""
    p = sub.add_parser("measure", help="stepped-sine measurement of an FMU into a data file (HDF5)")
    p.add_argument("fmu", role="input", help="Co-Simulation FMU with a real input and a real output")
    p.add_argument("--amplitudes", type=float_list, help="excitation amplitudes in N (default 2.0,0.6)")
    p.add_argument("--frequencies", type=float_list,
                   help="frequencies in Hz (default: a 1-2-5 grid around the bandwidth from a step response)")
    p.add_argument("--input", help="input variable (default u)")
    _add_output_variable(p, "output variable", " (default v)")
    p.add_argument("--noise-snr", type=float, metavar="DB", help="add measurement noise to v at this SNR (stored "
                                                                 "beside the clean signal)")
    p.add_argument("--seed", type=int, help="seed of the noise (default 0), and of a broadband plan")
    p.add_argument("--tolerance", type=float, help="relative tolerance of the FMU's solver (default 1e-12)")
    p.add_argument("--max-time", type=float, help="simulated seconds before an experiment counts as not settled "
                                                  "(default 60)")
    p.add_argument("--samples-per-period", type=int, help="samples per period of the analysed window (default 8192)")
    p.add_argument("--max-steps", type=float, default=MAX_STEPS,
                   help=f"refuse a plan whose experiments could take more FMU steps each (default {MAX_STEPS:g})")
    p.add_argument("--scheduler", metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT (default: local processes)")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; 0: this process)")
    p.add_argument("--resume", action="store_true", help="continue DATA.h5 where an interrupted run stopped")
    p.add_argument("--excitation", choices=broadband.KINDS,
                   help="broadband instead of stepped sine: the plan's options below (docs/broadband.md)")
    broadband.add_plan_options(p, seed=False)
    add_progress_option(p)
    add_json_option(p)
    _add_data_output(p)
    p.set_defaults(func=cmd_measure)

    p = sub.add_parser("import", help="import machine records (CSV or MAT) into a data file (HDF5)")
    p.add_argument("files", nargs="+", metavar="FILE", role="input", help="CSV (header row) or MAT files, one "
                                                                          "record each")
    p.add_argument("--time", required=True, help="time column (s)")
    p.add_argument("--input", required=True, help="input force column (N; a drive's total output command, see "
                                                  "--input-scale)")
    p.add_argument("--input-scale", type=float, default=1.0, metavar="K",
                   help="N per unit of the input column, e.g. the force constant in N/V (default 1)")
    _add_output_variable(p, "velocity (m/s) or position (m) column, see --kind", " (required)")
    p.add_argument("--reference", metavar="COL", help="reference position column (m) of a drive's log: a "
                                                      "closed-loop record (identify/validate --closed-loop)")
    p.add_argument("--disturbance", metavar="COL", help="column of a known signal the drive adds to its "
                                                        "controller's output after the output limit")
    p.add_argument("--disturbance-scale", type=float, default=1.0, metavar="K",
                   help="N per unit of the disturbance column (default 1)")
    p.add_argument("--kind", choices=("velocity", "position"), default="velocity",
                   help="what the output column holds (default velocity)")
    p.add_argument("--cutoff", type=float, help="low-pass cut-off (Hz) of the velocity estimate of position "
                                                "records (default: a tenth of the sample rate)")
    p.add_argument("--frequency", type=float, help="excitation frequency (Hz), when it is not to be detected")
    p.add_argument("--intersample", choices=INTERSAMPLE, default="zoh",
                   help="the input between samples: zoh, held for one sample as a digital drive's command (default), "
                        "or foh, linear; identify and validate replay the record so")
    p.add_argument("--append", action="store_true", help="add the records to an existing records file")
    p.add_argument("--excitation", metavar="SIGNAL.csv", role="input",
                   help="the log is of this signal file (`servofmu excitation`): a broadband data file of its "
                        "periods, lines and levels, with the BLA (docs/broadband.md)")
    add_progress_option(p)
    add_json_option(p)
    _add_data_output(p)
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("plot", help="Bode plot of a measurement, time series of records")
    p.add_argument("data", metavar="DATA.h5", role="input", help="data file from `servofmu measure` or `import`")
    p.add_argument("--what", choices=("bode", "time"), help="default: bode for measurements, time for records")
    add_json_option(p)
    p.add_argument("-o", "--output", metavar="FIGURE.png", help="figure to write (default DATA.png)")
    p.set_defaults(func=cmd_plot)
