"""The `servofmu` command: a thin front end over the library.

This is the only place that prints, configures logging or shows progress bars.
A UserError (or an OSError) ends the command with one line on stderr and exit
status 2; no traceback.  Ctrl-C (exit 130) and SIGTERM or SIGHUP (exit 128 + the
signal's number) end it the same way, after the same clean-up: temporary folders
removed, worker processes stopped, no partial output left.

One rule for every output (docs/reliability.md): every ``-o`` of every subcommand
is checked before any work — its folder exists and is writable, and it does not
exist yet unless ``--force`` (replace it) or the subcommand's ``--resume`` or
``--append`` is given.
"""
from __future__ import annotations

import argparse
import os
import shlex
import signal
import sys
import threading
from pathlib import Path

from .errors import UserError

__all__ = ["main", "build_parser", "run"]

EXIT_USER_ERROR = 2
STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)  # what `timeout`, systemd, batch schedulers and a closed terminal send
# Commands after which the installed command skips the interpreter's teardown (see run): identify is called in
# loops over axes, records and structures, and its outputs are written whole and closed before it returns.
QUICK_EXIT = {"identify"}
_quick_exit: list[str] = []  # the command main() finished, when it is one of QUICK_EXIT


class _Parser(argparse.ArgumentParser):
    """argparse that reports a bad command line in one line, and that knows a subcommand's outputs: every ``-o``
    is one (``args.outputs`` names them), and a subcommand with outputs gets ``--force``."""

    def error(self, message):
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}\n")

    def add_argument(self, *flags, **kwargs):
        action = super().add_argument(*flags, **kwargs)
        if "-o" in flags:
            if not self.get_default("outputs"):
                super().add_argument("--force", action="store_true", help="replace an existing output")
            self.set_defaults(outputs=(*(self.get_default("outputs") or ()), action.dest))
        return action


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
    from .model.plant import load_plant

    plant = load_plant(args.plant)
    output = Path(args.output) if args.output else claim_output(args, f"{plant.name}.fmu")
    build_fmu(plant, output, fmi_version=args.fmi_version)
    print(f"wrote {output} (FMI {args.fmi_version}.0, Model Exchange + Co-Simulation)")


def cmd_simulate(args) -> None:
    from .fileio import atomic_write
    from .simulation.fmpy_runs import format_csv, read_input_csv, simulate

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
# measure / import / plot
# ---------------------------------------------------------------------------
class _ProgressBar:
    """A tqdm bar on stderr driven by progress(done, total) callbacks; warnings go above it.  ``scale``: how many
    of the callback's units make one ``unit`` (measure counts thousandths of an experiment)."""

    def __init__(self, unit: str, scale: int = 1):
        self._unit, self._scale, self._bar = unit, scale, None

    def update(self, done: int, total: int) -> None:
        _stop_if_asked()
        total, done = (total, done) if self._scale == 1 else (total / self._scale, done / self._scale)
        if self._bar is None:  # created on first use: a run that fails early shows no bar
            from tqdm import tqdm
            self._bar = tqdm(total=total, unit=self._unit, file=sys.stderr, dynamic_ncols=True,
                             bar_format=None if self._scale == 1 else
                             "{l_bar}{bar}| {n:.2f}/{total:g} [{elapsed}<{remaining}]")
        self._bar.total, self._bar.n = total, done
        self._bar.refresh()

    def warn(self, text: str) -> None:
        if self._bar is None:
            print(f"warning: {text}", file=sys.stderr)
        else:
            self._bar.write(f"warning: {text}", file=sys.stderr)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.leave = sys.exc_info()[0] is None  # a failed run ends with its one error line, no bar
            self._bar.close()


def cmd_measure(args) -> None:
    from .measurement.measure import PROGRESS_SCALE, MeasureOptions, measure

    given = {"input": args.input, "output": args.output, "tolerance": args.tolerance, "max_time": args.max_time,
             "samples_per_period": args.samples_per_period, "noise_snr_db": args.noise_snr, "seed": args.seed}
    options = MeasureOptions(**{k: v for k, v in given.items() if v is not None})
    bar = _ProgressBar("experiment", scale=PROGRESS_SCALE)
    try:
        data = measure(args.fmu, args.data, amplitudes=args.amplitudes, frequencies=args.frequencies, options=options,
                       scheduler=args.scheduler, workers=args.workers, resume=args.resume, overwrite=args.force,
                       max_steps=args.max_steps,
                       command=getattr(args, "command_line", ""), progress=bar.update, warn=bar.warn)
    finally:
        bar.close()
    unsettled = sum(not e.converged for e in data.experiments)
    print(f"wrote {args.data}: {len(data.experiments)} experiments, amplitudes "
          f"{', '.join(f'{m:g}' for m in data.plan.amplitudes)} N x frequencies "
          f"{', '.join(f'{f:g}' for f in data.plan.frequencies)} Hz"
          + (f"; {unsettled} without steady state (flagged)" if unsettled else "; all reached steady state"))


def cmd_import(args) -> None:
    import numpy as np

    from .measurement.records import import_records

    data = import_records(args.files, args.data, time=args.time, input=args.input, output_column=args.output,
                          kind=args.kind, cutoff=args.cutoff, frequency=args.frequency, append=args.append,
                          overwrite=args.force,
                          command=getattr(args, "command_line", ""), intersample=args.intersample)
    for r in data.records[-len(args.files):]:
        line = f"{r.source}: {len(r.series.time)} samples at {r.sample_rate:.6g} Hz, {r.kind}, input {r.intersample}"
        if r.analysis is not None:
            a = r.analysis
            line += (f"; sine {a.frequency:.6g} Hz, |U1| {abs(a.U1):.4g} N, H = {abs(a.H):.4g} m/(N.s) "
                     f"at {np.degrees(np.angle(a.H)):.2f} deg" + ("" if a.converged else " (not settled)"))
        elif r.note:
            line += f"; {r.note}"
        print(line)
    print(f"wrote {args.data}: {len(data.records)} records")


def cmd_plot(args) -> None:
    from .measurement.datafile import read_data_file
    from .output.plots import bode_figure, time_series_figure

    data = read_data_file(args.data)
    what = args.what or ("time" if data.kind == "records" else "bode")
    out = Path(args.output) if args.output else claim_output(args, Path(args.data).with_suffix(".png"))
    (bode_figure if what == "bode" else time_series_figure)(data, out)
    print(f"wrote {out}")


# ---------------------------------------------------------------------------
# dataset / train / identify
# ---------------------------------------------------------------------------
def cmd_dataset(args) -> None:
    from .identification.criterion import sine_data
    from .identification.training_set import make_training_set
    from .measurement.datafile import read_data_file
    from .model.plant import load_plant

    structure = load_plant(args.plant)
    data = sine_data(read_data_file(args.like))
    bar = _ProgressBar("plant")
    try:
        ts = make_training_set(structure, data, args.samples, args.output, spread=args.spread, seed=args.seed,
                               resume=args.resume, overwrite=args.force, scheduler=args.scheduler,
                               command=getattr(args, "command_line", ""), progress=bar.update)
    finally:
        bar.close()
    print(f"wrote {args.output}: {ts.done.sum()} plants like {structure.name} under the plan of {args.like} "
          f"({data.amplitudes.size} experiments); {ts.usable().sum()} with every experiment at steady state")


def cmd_train(args) -> None:
    from .identification.train import train_from_file

    bar = _ProgressBar("epoch")
    try:
        net, rows = train_from_file(args.dataset, args.output, hidden=args.hidden, seed=args.seed,
                                    progress=bar.update)
    finally:
        bar.close()
    print(f"wrote {args.output}: {net.inputs}-{net.hidden}-{net.outputs} network trained on {rows} plants "
          f"({net.optimizer}, {len(net.validation_loss)} epochs); validation RMS error {net.validation_rmse:.3g} "
          "(normalised units)")


def cmd_identify(args) -> None:
    if args.output_dir is not None or len(args.data) > 1:
        return cmd_identify_files(args)
    if args.output is None or args.scheduler or args.workers is not None or args.resume:
        raise UserError("give -o RESULT.h5 for one data file (--scheduler, --workers and --resume go with "
                        "--output-dir DIR)")
    args.data = args.data[0]
    from .identification.identifier import PSOANNIdentifier, load_identification_inputs, swarm_options
    from .identification.results import result_from_estimator, table_text, to_json_text, write_result
    from .runtime import utc_now

    method = args.method or ("pso-ann" if args.ann else "pso")
    command = getattr(args, "command_line", "")
    if args.closed_loop:
        from .identification.closed_loop import load_closed_loop_inputs

        if method != "pso" or args.ann:
            raise UserError("a closed-loop identification searches with the swarm alone (--method pso, no --ann)")
        structure, data, provenance = load_closed_loop_inputs(args.data, args.structure, args.closed_loop,
                                                              command=command, skip=args.skip)
        ann = None
    else:
        structure, data, ann, provenance = load_identification_inputs(args.data, args.structure, args.ann, method,
                                                                      command=command, skip=args.skip)
    bar = None if args.json else _ProgressBar("iteration")
    est = PSOANNIdentifier(structure, ann=ann, method=method, seed=args.seed, polish=not args.no_polish,
                           pso=swarm_options(args.iterations), progress=bar.update if bar else None)
    try:
        est.fit(data)
    finally:
        if bar:
            bar.close()
    provenance["date"] = utc_now()
    result = result_from_estimator(est, method, provenance)
    write_result(args.output, result)
    if args.json:
        print(to_json_text(result))
    else:
        print(table_text(result))
        print(f"wrote {args.output}")


def cmd_identify_files(args) -> None:
    """`identify A.h5 B.h5 ... --output-dir DIR`: one result per data file and a summary table."""
    from .identification.fleet import identify_files, outcomes_json, outcomes_table

    if args.output_dir is None:
        raise UserError(f"{len(args.data)} data files: give --output-dir DIR (one result per file), not -o")
    if args.output is not None or args.closed_loop:
        raise UserError("with --output-dir, results are named after the data files (no -o); closed-loop records "
                        "are identified one file at a time")
    bar = None if args.json else _ProgressBar("file")
    try:
        outcomes = identify_files(args.data, args.structure, args.output_dir, ann_file=args.ann,
                                  method=args.method or ("pso-ann" if args.ann else "pso"), seed=args.seed,
                                  polish=not args.no_polish, iterations=args.iterations, skip=args.skip,
                                  resume=args.resume, overwrite=args.force, scheduler=args.scheduler,
                                  workers=args.workers, command=getattr(args, "command_line", ""),
                                  progress=bar.update if bar else None)
    finally:
        if bar:
            bar.close()
    print(outcomes_json(outcomes) if args.json else outcomes_table(outcomes))
    failed = [o for o in outcomes if o.status == "failed"]
    if failed:
        why = [o.message if o.data_file in o.message else f"{o.data_file}: {o.message}" for o in failed]
        raise UserError(f"{len(failed)} of {len(outcomes)} data files not identified: " + "; ".join(why[:3])
                        + ("; ..." if len(why) > 3 else ""))


# ---------------------------------------------------------------------------
# export
# ---------------------------------------------------------------------------
def cmd_export(args) -> None:
    from .output.export import export_result

    path, fmt = export_result(args.result, args.output, fmt=args.format, fmi_version=args.fmi_version,
                              name=args.name, command=getattr(args, "command_line", ""))
    what = {"fmu": f"FMI {args.fmi_version or 3}.0 FMU, Model Exchange + Co-Simulation, provenance in its "
                   "description, annotations and documentation/index.html",
            "control": "python-control model: servofmu.output.export.load_control(path)", "mat": "MATLAB .mat",
            "json": "JSON", "toml": "plant file: servofmu build accepts it"}[fmt]
    print(f"wrote {path} ({what})")


def cmd_compare(args) -> None:
    import json

    from .fileio import atomic_write
    from .identification.identifier import load_identification_inputs
    from .identification.results import write_comparison
    from .model.plant import load_plant
    from .baselines.compare import (
        METHODS,
        NEEDS_ANN,
        check_methods,
        check_truth,
        comparison_json,
        comparison_markdown,
        run_methods,
    )

    methods = check_methods(args.methods.split(",") if args.methods else
                            [m for m in METHODS if args.ann or m not in NEEDS_ANN], bool(args.ann))
    structure, data, ann, provenance = load_identification_inputs(args.data, args.structure, args.ann,
                                                   "pso-ann" if args.ann else "pso",
                                                   command=getattr(args, "command_line", ""))
    truth = load_plant(args.truth) if args.truth else None
    if truth is not None:
        check_truth(structure, truth, args.truth)
    def report(done: int, total: int) -> None:
        if done < total:
            print(f"running {methods[done]} ...", file=sys.stderr)

    results = run_methods(structure, data, methods, ann=ann, seed=args.seed, provenance=provenance,
                          progress=None if args.json else report)
    table = comparison_markdown(results, truth)
    if args.output:
        if str(args.output).endswith(".h5"):
            write_comparison(args.output, results)
        else:
            atomic_write(args.output, table)
    if args.json:
        print(json.dumps(comparison_json(results, truth), allow_nan=True))
    else:
        print(table, end="")
        if args.output:
            print(f"wrote {args.output}")


# ---------------------------------------------------------------------------
# validate / report
# ---------------------------------------------------------------------------
def cmd_validate(args) -> None:
    import json

    from .output.validate import validate_files, validation_json, validation_text

    v = validate_files(args.result, args.data, args.output, skip=args.skip, controller=args.closed_loop)
    if args.json:
        print(json.dumps(validation_json(v), allow_nan=True))
    else:
        print(validation_text(v))
        if args.output:
            print(f"wrote {args.output}")


def cmd_report(args) -> None:
    from .output.report import make_report

    path = make_report(args.source, args.output, data=args.data, truth=args.truth, validate=args.validate)
    print(f"wrote {path} (self-contained HTML: tables and figures)")


# ---------------------------------------------------------------------------
# controller / system / cosim
# ---------------------------------------------------------------------------
def cmd_controller(args) -> None:
    from .model.controller import friction_feedforward, load_controller
    from .control.fmus import build_controller_fmu
    from .model.plant import load_plant

    spec = load_controller(args.controller)
    provenance = None
    if args.compensate:
        source = Path(args.compensate)
        if source.suffix == ".h5":
            from .identification.results import read_result
            plant = read_result(source).plant
        else:
            plant = load_plant(source)
        spec = friction_feedforward(spec, plant)
        provenance = {"friction_feedforward": f"{plant.friction.model} friction of {source.name}"}
    output = Path(args.output) if args.output else claim_output(args, f"{spec.name}.fmu")
    build_controller_fmu(spec, output, fmi_version=args.fmi_version, provenance=provenance)
    print(f"wrote {output} (FMI {args.fmi_version}.0 Co-Simulation, sampled every {spec.sample_time:g} s"
          + (f"; friction feed-forward from {args.compensate}" if args.compensate else "") + ")")


def cmd_system(args) -> None:
    from .control.fmus import read_reference_csv
    from .control.system import controller_from_fmu, write_system

    controller = controller_from_fmu(args.controller_fmu)
    changes = {k: v for k, v in (("force_noise", args.force_noise), ("noise_seed", args.seed),
                                 ("encoder_resolution", args.encoder)) if v is not None}
    controller = controller.with_values(**changes) if changes else controller
    path = write_system(args.plant_fmu, args.controller_fmu, read_reference_csv(args.reference), args.output,
                        controller=controller)
    print(f"wrote {path} (SSP: reference, controller and plant; controller parameters in resources/controller.ssv)")


def cmd_cosim(args) -> None:
    import numpy as np

    from .control.cosim import cosimulate, write_cosim_records

    result = cosimulate(args.system, args.stop_time, engine=args.engine)
    data = write_cosim_records(result, args.system, args.output, command=getattr(args, "command_line", ""),
                               append=args.append, overwrite=args.force)
    error = result["reference"] - result["position"]
    print(f"wrote {args.output}: {len(data.records)} record(s); {result.engine}, {result.time.size - 1} steps of "
          f"{result.time[1]:g} s; tracking error RMS {np.sqrt(np.mean(error ** 2)):.3g} m, peak "
          f"{np.max(np.abs(error)):.3g} m")


def cmd_compensate(args) -> None:
    import json

    from .output.compensation_report import compensate_files, compensation_json, compensation_text

    runs = compensate_files(args.result, args.axis, truth=args.truth, output=args.output, engine=args.engine)
    if args.json:
        print(json.dumps(compensation_json(runs), allow_nan=True))
    else:
        print(compensation_text(runs))
        if args.output:
            print(f"wrote {args.output}")


# ---------------------------------------------------------------------------
# demo
# ---------------------------------------------------------------------------
def cmd_demo(args) -> None:
    from .output.demo import run_demo

    out = Path(args.out)
    if out.is_dir() and any(out.iterdir()) and not args.force:
        raise UserError(f"{out}: exists already and is not empty (give --force to replace the demo's files in it)")
    run_demo(out, report=print)


def build_parser() -> argparse.ArgumentParser:
    from .baselines import BASELINE_METHODS, BASELINE_NEEDS_ANN
    from .identification.methods import METHODS as IDENTIFY_METHODS
    from .identification.methods import NEEDS_ANN as IDENTIFY_NEEDS_ANN
    from .model.signals import INTERSAMPLE
    from .measurement.excitation import MAX_STEPS
    from .output.formats import FORMATS as EXPORT_FORMATS
    from .output.formats import SUFFIX_FORMATS

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

    p = sub.add_parser("measure", help="stepped-sine measurement of an FMU into a data file (HDF5)")
    p.add_argument("fmu", help="Co-Simulation FMU with a real input and a real output")
    p.add_argument("--amplitudes", type=_float_list, help="excitation amplitudes in N (default 2.0,0.6)")
    p.add_argument("--frequencies", type=_float_list,
                   help="frequencies in Hz (default: a 1-2-5 grid around the bandwidth from a step response)")
    p.add_argument("--input", help="input variable (default u)")
    p.add_argument("--output", help="output variable (default v)")
    p.add_argument("--noise-snr", type=float, metavar="DB", help="add measurement noise to v at this SNR (stored "
                                                                 "beside the clean signal)")
    p.add_argument("--seed", type=int, help="seed of the noise (default 0)")
    p.add_argument("--tolerance", type=float, help="relative tolerance of the FMU's solver (default 1e-12)")
    p.add_argument("--max-time", type=float, help="simulated seconds before an experiment counts as not settled "
                                                  "(default 60)")
    p.add_argument("--samples-per-period", type=int, help="samples per period of the analysed window (default 8192)")
    p.add_argument("--max-steps", type=float, default=MAX_STEPS,
                   help=f"refuse a plan whose experiments could take more FMU steps each (default {MAX_STEPS:g})")
    p.add_argument("--scheduler", metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT (default: local processes)")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; 0: this process)")
    p.add_argument("--resume", action="store_true", help="continue DATA.h5 where an interrupted run stopped")
    p.add_argument("-o", dest="data", metavar="DATA.h5", required=True, help="data file to write")
    p.set_defaults(func=cmd_measure)

    p = sub.add_parser("import", help="import machine records (CSV or MAT) into a data file (HDF5)")
    p.add_argument("files", nargs="+", metavar="FILE", help="CSV (header row) or MAT files, one record each")
    p.add_argument("--time", required=True, help="time column (s)")
    p.add_argument("--input", required=True, help="input force column (N)")
    p.add_argument("--output", required=True, help="velocity (m/s) or position (m) column, see --kind")
    p.add_argument("--kind", choices=("velocity", "position"), default="velocity")
    p.add_argument("--cutoff", type=float, help="low-pass cut-off (Hz) of the velocity estimate of position "
                                                "records (default: a tenth of the sample rate)")
    p.add_argument("--frequency", type=float, help="excitation frequency (Hz), when it is not to be detected")
    p.add_argument("--intersample", choices=INTERSAMPLE, default="zoh",
                   help="the input between samples: zoh, held for one sample as a digital drive's command (default), "
                        "or foh, linear; identify and validate replay the record so")
    p.add_argument("--append", action="store_true", help="add the records to an existing records file")
    p.add_argument("-o", dest="data", metavar="DATA.h5", required=True, help="data file to write")
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("plot", help="Bode plot of a measurement, time series of records")
    p.add_argument("data", metavar="DATA.h5")
    p.add_argument("--what", choices=("bode", "time"), help="default: bode for measurements, time for records")
    p.add_argument("-o", dest="output", metavar="FIGURE.png", help="figure to write (default DATA.png)")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("dataset", help="simulate plants drawn around a structure under a data file's plan")
    p.add_argument("plant", help="the structure: plant file or name in fmu_models/")
    p.add_argument("--like", required=True, help="data file (HDF5) whose plan the plants are simulated under")
    p.add_argument("--samples", type=int, required=True, help="number of plants")
    p.add_argument("--spread", type=float, default=0.5, help="prior width: factors in [1/(1+S), 1+S] (default 0.5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scheduler", help="Dask scheduler address tcp://HOST:PORT (default: this machine)")
    p.add_argument("--resume", action="store_true", help="complete an interrupted run of the same command")
    p.add_argument("-o", "--output", required=True, help="training set to write (HDF5)")
    p.set_defaults(func=cmd_dataset)

    p = sub.add_parser("train", help="train the ANN on a training set")
    p.add_argument("dataset", help="training set (HDF5) from `servofmu dataset`")
    p.add_argument("--hidden", type=int, default=20, help="hidden neurons (default 20, the paper's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", required=True, help="network file to write (HDF5)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("identify", help="identify G(s) and the friction from a data file (or many)")
    p.add_argument("data", nargs="+", help="data file (HDF5) from `servofmu measure` or `servofmu import`; several "
                                           "with --output-dir")
    p.add_argument("--structure", required=True, help="plant file giving the structure (order, friction model)")
    p.add_argument("--ann", help="trained network (HDF5) from `servofmu train`")
    p.add_argument("--method", choices=IDENTIFY_METHODS,
                   help="pso-ann (the default with --ann), pso (the default without: no ANN), ga-ann or aga-ann (the "
                        "paper's GA comparators)")
    p.add_argument("--closed-loop", metavar="CTRL.toml", help="the records are closed-loop logs of this "
                   "controller: every candidate is simulated in the loop from the recorded reference")
    p.add_argument("--no-polish", action="store_true", help="skip the least-squares polish after the swarm")
    p.add_argument("--skip", type=float, default=0.0, metavar="SECONDS",
                   help="records: leave the first SECONDS of every record out of the fit (the model starts at rest "
                        "at the first sample; a record that does not start at rest is fitted after its initial "
                        "state has died away)")
    p.add_argument("--iterations", type=int, metavar="N",
                   help="swarm iterations (default 50, the paper's; the GA comparators get as many model evaluations); "
                        "fewer are faster, 0 polishes from the network's estimate: docs/bench-swarm-budget.md")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print the result as one JSON object (many files: an array "
                                                       "of one summary object per file)")
    p.add_argument("-o", "--output", help="result file to write (HDF5), for one data file")
    p.add_argument("--output-dir", metavar="DIR", help="many data files: write DIR/NAME-result.h5 for each NAME.h5 "
                                                       "and print a summary table")
    p.add_argument("--scheduler", metavar="ADDR", help="many data files: Dask scheduler, tcp://HOST:PORT (default: "
                                                       "local processes)")
    p.add_argument("--workers", type=int, help="many data files: local worker processes (default: one per core; 0: "
                                               "this process)")
    p.add_argument("--resume", action="store_true", help="many data files: keep the results already in DIR from the "
                                                         "same data and settings, identify the others")
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("export", help="export an identified model: FMU, python-control, MATLAB, JSON, plant TOML")
    p.add_argument("result", metavar="RESULT.h5", help="result file from `servofmu identify`")
    p.add_argument("--format", choices=EXPORT_FORMATS,
                   help=f"default: from the suffix of -o ({', '.join(SUFFIX_FORMATS)})")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), help="FMI version of an FMU (default 3)")
    p.add_argument("--name", help="model name in the export (default: the plant's name + _identified)")
    p.add_argument("-o", dest="output", metavar="FILE", required=True, help="file to write")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("compare", help="every identification method on the same data, in the paper's table layout")
    p.add_argument("data", help="data file (HDF5) from `servofmu measure`")
    p.add_argument("--structure", required=True, help="plant file giving the structure")
    p.add_argument("--ann", help="trained network (HDF5); needed by "
                                 f"{', '.join(IDENTIFY_NEEDS_ANN + BASELINE_NEEDS_ANN)}")
    p.add_argument("--truth", help="plant file of the true plant: adds the target column and relative errors")
    p.add_argument("--methods", help=f"comma-separated: {', '.join(IDENTIFY_METHODS + BASELINE_METHODS)} "
                                     "(default: all that the inputs allow)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by method")
    p.add_argument("-o", "--output", help="write the table (.md) or every result (.h5, for `servofmu report`)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("validate", help="simulate an identified model on other data: fit %% and residual tests")
    p.add_argument("result", metavar="RESULT.h5", help="result file from `servofmu identify`")
    p.add_argument("data", metavar="DATA.h5", help="data file (records or a measurement) it was not fitted to")
    p.add_argument("--skip", type=float, default=0.0, metavar="SECONDS",
                   help="leave the first SECONDS of every record out (as identify --skip)")
    p.add_argument("--closed-loop", metavar="CTRL.toml", help="closed-loop records of this controller: replayed in "
                                                              "the loop from their reference")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-o", dest="output", metavar="FILE.html|FILE.png", help="write a page or a figure")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("report", help="one self-contained HTML page of an identification: tables and figures")
    p.add_argument("source", metavar="RESULT.h5|COMPARE.h5",
                   help="result file from `servofmu identify` or comparison file from `servofmu compare`")
    p.add_argument("--data", metavar="DATA.h5", help="the data file it was identified from (default: the path "
                                                     "its provenance records, or that name beside it)")
    p.add_argument("--truth", metavar="PLANT", help="the true plant (file or name in fmu_models/), when known: "
                                                    "drawn in the friction figure, relative errors in the table")
    p.add_argument("--validate", metavar="DATA.h5", help="add the validation on another data file (fit %%, "
                                                         "residual tests; see `servofmu validate`)")
    p.add_argument("-o", dest="output", metavar="REPORT.html", required=True, help="HTML file to write")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("controller", help="a drive controller file (TOML) as a Co-Simulation FMU")
    p.add_argument("controller", metavar="CTRL.toml", help="controller file, or the name of an example "
                                                           "(axis_controller)")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), default=3)
    p.add_argument("--compensate", metavar="RESULT.h5|PLANT.toml",
                   help="feed forward the friction of an identified result or a plant file")
    p.add_argument("-o", "--output", help="FMU file to write (default: NAME.fmu)")
    p.set_defaults(func=cmd_controller)

    p = sub.add_parser("system", help="plant + controller + reference as an SSP archive")
    p.add_argument("plant_fmu", metavar="PLANT.fmu", help="plant FMU (FMI 2.0 Co-Simulation)")
    p.add_argument("controller_fmu", metavar="CTRL.fmu", help="controller FMU from `servofmu controller`")
    p.add_argument("--reference", required=True, metavar="REF.csv", help="reference trajectory: CSV with "
                                                                         "columns time (s) and position (m)")
    p.add_argument("--encoder", type=float, metavar="M", help="encoder resolution (m; default the controller's)")
    p.add_argument("--force-noise", type=float, metavar="N", help="actuator noise, standard deviation (N)")
    p.add_argument("--seed", type=int, help="seed of the actuator noise")
    p.add_argument("-o", dest="output", metavar="AXIS.ssp", required=True, help="SSP archive to write")
    p.set_defaults(func=cmd_system)

    p = sub.add_parser("cosim", help="co-simulate an SSP system on libcosim or FMPy into a records file")
    p.add_argument("system", metavar="AXIS.ssp")
    p.add_argument("--stop-time", type=float, help="seconds (default: the system's default experiment)")
    p.add_argument("--engine", choices=("libcosim", "fmpy"), default="libcosim")
    p.add_argument("--append", action="store_true", help="add the run to an existing records file")
    p.add_argument("-o", dest="output", metavar="RECORDS.h5", required=True, help="records file to write")
    p.set_defaults(func=cmd_cosim)

    p = sub.add_parser("compensate", help="the axis with and without feed-forward of the identified friction")
    p.add_argument("result", metavar="RESULT.h5", help="result file from `servofmu identify`")
    p.add_argument("--axis", required=True, metavar="AXIS.ssp", help="the axis from `servofmu system` (its "
                                                                      "reference should reverse the velocity)")
    p.add_argument("--truth", metavar="PLANT", help="the true plant, when known: a third run with its friction")
    p.add_argument("--engine", choices=("libcosim", "fmpy"), default="libcosim")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-o", dest="output", metavar="REPORT.html", help="HTML page to write")
    p.set_defaults(func=cmd_compensate)

    p = sub.add_parser("demo", help="the whole path on the paper's plants g1 and g2")
    p.add_argument("--out", default="demo-output", help="folder for the demo's files (default demo-output)")
    p.add_argument("--force", action="store_true", help="replace the demo's files in an existing --out folder")
    p.set_defaults(func=cmd_demo)
    return parser


def _version() -> str:
    from .version import __version__
    return __version__


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP: unwinds like Ctrl-C, so that the same clean-up runs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


_stop_signals: list[int] = []  # the signal that asked to stop, kept: see _stop_if_asked


def _terminate(signum, frame) -> None:
    for s in STOP_SIGNALS:  # once: the clean-up is not interrupted by a second signal
        signal.signal(s, signal.SIG_IGN)
    _stop_signals.append(signum)
    raise Terminated(signum)


def _interrupt(signum, frame) -> None:
    """Ctrl-C, as Python's own handler, but kept for _stop_if_asked."""
    _stop_signals.append(signum)
    raise KeyboardInterrupt


def _stop_if_asked(*_) -> None:
    """Raise again if a stop signal came: the handler's exception is lost when the signal arrives while Python runs
    a finaliser or a weakref callback (garbage collection), which swallow exceptions."""
    if _stop_signals:
        raise KeyboardInterrupt if _stop_signals[0] == signal.SIGINT else Terminated(_stop_signals[0])


def _raise_soon(unraisable) -> None:
    """``sys.unraisablehook`` while a command runs.  A stop signal's exception raised inside a finaliser is dropped
    by Python (with a traceback on stderr): raise it again a millisecond later, in ordinary code (SIGALRM runs
    :func:`_stop_if_asked`), instead."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and _stop_signals:
        signal.setitimer(signal.ITIMER_REAL, 0.001)
    else:
        sys.__unraisablehook__(unraisable)


def claim_output(args, path) -> Path:
    """``path`` as the output of the command ``args``: a writable folder, and no existing file unless --force (or
    the command's --resume or --append) says what to do with it."""
    from .fileio import check_output_path

    keep = [f"--{name} to {what} it" for name, what in (("resume", "continue"), ("append", "add to"))
            if hasattr(args, name)]
    if getattr(args, "force", False) or any(getattr(args, name, False) for name in ("resume", "append")):
        return check_output_path(path)
    if Path(path).exists() and not Path(path).is_dir():
        raise UserError(f"{path}: exists already (give --force to replace it{''.join(', or ' + k for k in keep)})")
    return check_output_path(path)


def main(argv: list[str] | None = None) -> int:
    _stop_signals.clear()  # the handlers first: Ctrl-C while the modules load is one line too
    handlers = {s: signal.signal(s, _terminate) for s in STOP_SIGNALS}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not where Ctrl-C is ignored
        handlers[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupt)
    handlers[signal.SIGALRM] = signal.signal(signal.SIGALRM, _stop_if_asked)
    unraisablehook, sys.unraisablehook = sys.unraisablehook, _raise_soon
    argv = sys.argv[1:] if argv is None else list(argv)
    words = [a for a in argv if not a.startswith("-")]
    who = f"servofmu {words[0]}" if words else "servofmu"  # (a stop while the modules load names it too)
    try:
        from .runtime import sweep_temporary_folders

        args = build_parser().parse_args(argv)
        who = f"servofmu {args.command}"
        args.command_line = shlex.join(["servofmu", *argv])
        sweep_temporary_folders()
        for dest in getattr(args, "outputs", ()):  # before any work (see the module's docstring)
            if getattr(args, dest):
                claim_output(args, getattr(args, dest))
        _quick_exit.clear()
        args.func(args)
        _stop_if_asked()
        if args.command in QUICK_EXIT:
            _quick_exit.append(args.command)
    except UserError as exc:
        print(f"{who}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{who}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BaseException as exc:  # a stop signal, or what it caused (a module interrupted while it loaded)
        if not isinstance(exc, KeyboardInterrupt) and not (_stop_signals and isinstance(exc, Exception)):
            raise
        signum = exc.signum if isinstance(exc, Terminated) else _stop_signals[0] if _stop_signals else signal.SIGINT
        if signum == signal.SIGINT:
            # Ctrl-C inside code that exec() runs from a string (dataclasses makes methods so while modules load)
            # marks the interpreter as ended by Ctrl-C, and it would kill itself with SIGINT at its exit instead
            # of returning 130; the next exec() of a string that ends normally clears the mark.
            exec("")
            print(f"{who}: interrupted", file=sys.stderr)
            return 130
        print(f"{who}: terminated ({signal.Signals(signum).name})", file=sys.stderr)
        return 128 + signum
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        sys.unraisablehook = unraisablehook
        for s, handler in handlers.items():
            signal.signal(s, handler)
    return 0


def run() -> None:
    """The installed `servofmu` command: :func:`main`, then the exit.  After a command of QUICK_EXIT that
    succeeded, the interpreter's teardown (tens of milliseconds spent freeing numpy, h5py and the compiled
    libraries, a tenth of a quick identify) is skipped when nothing is left to finish: every file servofmu writes
    is complete and closed when the command returns (servofmu.fileio), and no other thread or process runs."""
    code = main()
    multiprocessing = sys.modules.get("multiprocessing")
    if code == 0 and _quick_exit and threading.active_count() == 1 and not (
            multiprocessing and multiprocessing.active_children()):
        from .runtime import remove_temporary_folders

        try:
            remove_temporary_folders()
            sys.stdout.flush()
            sys.stderr.flush()
        except OSError:  # (a closed pipe): the ordinary exit reports it
            sys.exit(code)
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    run()
