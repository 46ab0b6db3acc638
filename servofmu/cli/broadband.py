"""`servofmu excitation` (a broadband signal file for a drive), `servofmu frf` (the BLA of a broadband data file)
and the options `servofmu measure --excitation` adds (docs/broadband.md)."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import UserError
from .common import add_json_option, float_list, print_written

__all__ = ["register", "add_plan_options", "cmd_excitation", "cmd_frf", "cmd_measure_broadband",
           "cmd_import_broadband"]

KINDS = ("multisine", "chirp", "prbs")  # servofmu.broadband.signals.KINDS, here without loading numpy
GRIDS = ("full", "odd", "odd-random")
FIGURE_SUFFIXES, FRF_SUFFIXES = (".png", ".svg", ".pdf"), (".h5", ".hdf5")


def _plan(args, kind: str):
    from ..broadband.signals import BroadbandPlan

    if args.band is None:
        raise UserError("--band: give the band f_min,f_max in Hz (e.g. --band 0.2,50)")
    given = {"period": args.period, "periods": args.periods, "transient_periods": args.transient_periods,
             "realisations": args.realisations, "grid": args.grid, "group": args.group,
             "seed": args.seed, "crest_iterations": args.crest_iterations}
    return BroadbandPlan(kind, tuple(args.levels or (2.0, 0.6)), tuple(args.band), args.rate,
                         **{k: v for k, v in given.items() if v is not None})


def _describe(plan) -> str:
    from ..broadband.signals import crest_factor

    crest = max(crest_factor(plan.realisation(r)) for r in range(plan.realisations))
    free = f", {plan.detection_lines.size} odd detection lines" if plan.detection_lines.size else ""
    return (f"{plan.kind}, levels {', '.join(f'{x:g}' for x in plan.levels)} N RMS x {plan.realisations} "
            f"realisations x ({plan.transient_periods} + {plan.periods}) periods of {plan.period:.9g} s at "
            f"{plan.rate:g} Hz; {plan.lines.size} lines in [{plan.frequencies[0]:.6g}, {plan.frequencies[-1]:.6g}] "
            f"Hz ({plan.grid if plan.kind == 'multisine' else 'full'} grid{free}); crest factor {crest:.3g}")


def cmd_excitation(args) -> None:
    """A broadband signal (time, force) as CSV with its plan on the first line."""
    from ..broadband.store import write_excitation_csv

    plan = _plan(args, args.kind)
    write_excitation_csv(args.output, plan, overwrite=args.force)
    print_written(args, f"wrote {args.output}: {_describe(plan)}", {"written": [args.output], **_plan_json(plan)})


def _plan_json(plan) -> dict:
    return {"kind": plan.kind, "levels_N_rms": list(plan.levels), "realisations": plan.realisations,
            "periods": plan.periods, "transient_periods": plan.transient_periods, "period_s": plan.period,
            "rate_Hz": plan.rate, "lines": int(plan.lines.size)}


def cmd_frf(args) -> None:
    """The BLA per level of a broadband data file (a summary, --json, or -o FRF.h5 | FIG.png), or the frequency
    response of the records of a records file (direct, and from the reference with --closed-loop)."""
    from ..measurement.datafile import read_data_file

    suffix = Path(args.output).suffix.lower() if args.output else None
    if suffix is not None and suffix not in FIGURE_SUFFIXES + FRF_SUFFIXES:
        raise UserError(f"-o {args.output}: give an FRF file (.h5) or a figure ({', '.join(FIGURE_SUFFIXES)})")
    if read_data_file(args.data).kind != "broadband":
        return _frf_of_records(args, suffix)
    _frf_of_broadband(args, suffix)


def _frf_of_broadband(args, suffix) -> None:
    """`frf BROADBAND.h5`: the BLA per level, printed, as JSON, an FRF file or a figure."""
    from ..broadband.frf import frf_json, frf_of_file, write_frf

    if args.closed_loop:
        raise UserError(f"{args.data}: broadband data is open loop (the plant driven by the excitation): leave out "
                        "--closed-loop")
    data, levels = frf_of_file(args.data)
    if suffix in FRF_SUFFIXES:
        write_frf(args.output, data, levels, args.command_line, overwrite=args.force)
    elif suffix is not None:
        from ..output.bla_plots import bla_figure
        bla_figure(levels, args.output, f"{Path(args.data).name}: BLA, ±2σ", overwrite=args.force)
    if args.json:
        print(json.dumps(frf_json(data, levels)))
        return
    for level, b in levels:
        print(_frf_line(level, b))
    if args.output:
        print(f"wrote {args.output}")


def _frf_of_records(args, suffix) -> None:
    """`frf RECORDS.h5 [--closed-loop]`: per record the direct estimate and the one from the reference."""
    import math

    import numpy as np

    from ..broadband.records_frf import TRUSTED_COHERENCE, records_frf, records_frf_json

    if suffix in FRF_SUFFIXES:
        raise UserError(f"-o {args.output}: records give --json or a figure ({', '.join(FIGURE_SUFFIXES)}), not an "
                        "FRF file")
    if args.external is not None and not args.closed_loop:
        raise UserError(f"--external {args.external}: the external signal of a log in its loop; add --closed-loop")
    data, estimates = records_frf(args.data, args.closed_loop, external=args.external or "reference")
    if suffix is not None:
        from ..output.bla_plots import records_frf_figure
        records_frf_figure(estimates, args.output, f"{Path(args.data).name}: frequency response, bands shaded",
                           overwrite=args.force)
    if args.json:
        print(json.dumps(records_frf_json(data, estimates)))
        return
    for e in estimates:
        line = (f"record {e.name}: {e.samples} samples at {e.rate:g} Hz; direct S_uy/S_uu at "
                f"{e.direct.frequencies.size} frequencies, median coherence {float(np.median(e.direct.coherence)):.3g}")
        if e.closed_loop is not None:
            good = int((e.closed_loop.coherence_ru >= TRUSTED_COHERENCE).sum())
            dev = e.direct_deviation()
            line += (f"; from the {e.external} S_ry/S_ru: {good} of {e.closed_loop.frequencies.size} frequencies with "
                     f"γ²_ru ≥ {TRUSTED_COHERENCE}" + (f", where the direct estimate is off by "
                                                      f"{100 * dev:.3g} % (median)" if math.isfinite(dev) else ""))
        print(line)
    if args.output:
        print(f"wrote {args.output}")


def _frf_line(level: float, b) -> str:
    import numpy as np

    return (f"level {level:g} N RMS: {b.frequencies.size} lines {b.frequencies[0]:.4g}..{b.frequencies[-1]:.4g} "
            f"Hz, min coherence {np.min(b.coherence):.4f}; distortion {b.relative_distortion_db:.1f} dB re the linear "
            f"part, {b.distortion_to_noise_db:.1f} dB (total "
            f"{b.total_to_noise_db:.1f} dB) over the noise; odd/even detection lines "
            f"{b.detection_to_noise_db('odd'):.1f}/{b.detection_to_noise_db('even'):.1f} dB over the noise"
            + ("" if b.periodic else
               f"\n  not periodic: a component at {b.nonsynchronous_frequency:.4g} Hz between the period's lines, "
               f"{b.nonsynchronous_re_response_db:.1f} dB re the response and {b.nonsynchronous_over_floor_db:.1f} dB "
               "over the noise floor there (a limit cycle, an unfinished transient or a disturbance): the noise level "
               "above holds it, and the distortion level is not the friction's alone"))


def cmd_import_broadband(args) -> None:
    """`import --excitation SIGNAL.csv`: a drive's log of that signal into a broadband data file."""
    from ..broadband.importing import import_broadband
    from .common import run_options

    if len(args.files) != 1:
        raise UserError(f"--excitation {args.excitation}: give the one log of that signal, not {len(args.files)} "
                        "files")
    for option, value in (("--append", args.append), ("--reference", args.reference),
                          ("--disturbance", args.disturbance), ("--frequency", args.frequency)):
        if value not in (None, False):
            raise UserError(f"{option}: not with --excitation (a broadband log is an open-loop record of its own "
                            "kind)")
    if args.intersample != "zoh":
        raise UserError("--intersample: a drive plays the excitation held for one sample (zoh)")
    data = import_broadband(args.files[0], args.data, args.excitation, time=args.time, input=args.input,
                            output_column=args.output_variable, kind=args.kind, cutoff=args.cutoff,
                            input_scale=args.input_scale, run=run_options(args))
    _print_broadband(args, data)


def _print_broadband(args, data) -> None:
    """What `measure --excitation` and `import --excitation` wrote: the plan and the BLA per level."""
    print_written(args, "\n".join([f"wrote {args.data}: {_describe(data.plan)}",
                                   *(_frf_line(lv.level, lv.bla) for lv in data.levels)]),
                  {"written": [args.data], **_plan_json(data.plan),
                   "bla_levels": [{"level_N_rms": float(lv.level), "lines": int(lv.bla.frequencies.size),
                                   "min_coherence": float(min(lv.bla.coherence))} for lv in data.levels]})


def cmd_measure_broadband(args) -> None:
    """`measure --excitation`: the FMU driven with a broadband plan, records and BLA into a data file."""
    from ..broadband.measure import PROGRESS_SCALE, measure_broadband
    from ..measurement.measure import MeasureOptions
    from .common import ProgressBar, run_options

    for name in ("amplitudes", "frequencies", "max_time", "samples_per_period", "resume"):
        if getattr(args, name, None) not in (None, False):
            raise UserError(f"--{name.replace('_', '-')}: a stepped-sine option, not for --excitation "
                            f"{args.excitation}")
    given = {"input": args.input, "output": args.output_variable, "tolerance": args.tolerance,
             "noise_snr_db": args.noise_snr, "seed": args.seed}
    options = MeasureOptions(**{k: v for k, v in given.items() if v is not None})
    plan = _plan(args, args.excitation)
    with ProgressBar(args, "signal", scale=PROGRESS_SCALE) as bar:
        data = measure_broadband(args.fmu, args.data, plan, options, run_options(args, bar))
    _print_broadband(args, data)


def add_plan_options(p, seed: bool = True) -> None:
    """The options of a broadband plan (``excitation`` and ``measure --excitation``)."""
    p.add_argument("--levels", type=float_list, help="RMS levels of the force in N (default 2.0,0.6)")
    p.add_argument("--band", type=float_list, metavar="FMIN,FMAX", help="excited band in Hz")
    p.add_argument("--period", type=float, metavar="S", help="period in s, a whole number of samples (default "
                   "1/f_min; a PRBS's follows from the band)")
    p.add_argument("--periods", type=int, metavar="P", help="analysed periods per realisation (default 2)")
    p.add_argument("--transient-periods", type=int, metavar="T", help="leading periods left out (default 1)")
    p.add_argument("--realisations", type=int, metavar="M", help="independent random-phase realisations (default 4)")
    p.add_argument("--rate", type=float, default=1000.0, metavar="HZ", help="sample rate in Hz (default 1000)")
    p.add_argument("--grid", choices=GRIDS, help="multisine lines: full, odd or odd-random (default)")
    p.add_argument("--group", type=int, help="odd-random: one detection line per GROUP odd lines (default 4)")
    p.add_argument("--crest-iterations", type=int, help="clipping iterations lowering the multisine's crest "
                                                        "factor (default 100; 0: plain random phases)")
    if seed:
        p.add_argument("--seed", type=int, help="seed of the phases, detection lines and shifts (default 0)")


def register(sub) -> None:
    """Add the subcommands excitation and frf to the subparsers ``sub``."""
    p = sub.add_parser("excitation", help="a broadband excitation (multisine, chirp, PRBS) as CSV for a drive")
    p.add_argument("kind", choices=KINDS, help="multisine (periodic, random phases), chirp or prbs")
    add_plan_options(p)
    p.add_argument("-o", "--output", metavar="SIGNAL.csv", required=True,
                   help="signal file: time (s), force (N), the plan on its first line")
    add_json_option(p)
    p.set_defaults(func=cmd_excitation)

    p = sub.add_parser("frf", help="best linear approximation with noise and distortion levels of broadband data")
    p.add_argument("data", metavar="DATA.h5", role="input", help="data file of `servofmu measure --excitation` "
                   "(or `import --excitation`), or a records file")
    p.add_argument("--closed-loop", action="store_true", help="records of a drive's log with its reference: the "
                   "plant's response from the reference (S_ry/S_ru) beside the direct estimate")
    p.add_argument("--external", choices=("reference", "disturbance"), help="with --closed-loop: the external "
                   "signal r of S_ry/S_ru, the log's reference (default) or the disturbance injected into the drive's "
                   "output (a test signal)")
    p.add_argument("--json", action="store_true", help="print the BLA per level as JSON (docs/broadband.md)")
    p.add_argument("-o", "--output", metavar="FRF.h5|FIG.png", help="write the BLA (HDF5) or its Bode plot")
    p.set_defaults(func=cmd_frf)
