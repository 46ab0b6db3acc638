"""`servofmu controller`, `system`, `cosim` and `compensate`: the axis in its drive's loop."""
from __future__ import annotations

__all__ = ["register", "cmd_controller", "cmd_system", "cmd_cosim", "cmd_compensate"]

from .common import ProgressBar, add_json_option, add_progress_option, print_written

ENGINES = ("libcosim", "fmpy")


def cmd_controller(args) -> None:
    """A controller file as a Co-Simulation FMU (with the friction feed-forward of a result or plant file)."""
    from ..control.fmus import controller_fmu_from_file

    output, spec = controller_fmu_from_file(args.controller, args.output, args.fmi_version, args.compensate,
                                            overwrite=args.force)
    print_written(args, f"wrote {output} (FMI {args.fmi_version}.0 Co-Simulation, sampled every "
                  f"{spec.sample_time:g} s" + (f"; friction feed-forward from {args.compensate}" if args.compensate
                                               else "") + ")",
                  {"written": [output], "fmi_version": args.fmi_version, "sample_time_s": spec.sample_time,
                   "compensate": args.compensate})


def cmd_system(args) -> None:
    """Plant FMU, controller FMU and a reference as an SSP archive."""
    from ..control.fmus import read_disturbance_csv, read_reference_csv
    from ..control.system import controller_from_fmu, write_system

    changes = {k: v for k, v in (("force_noise", args.force_noise), ("noise_seed", args.seed),
                                 ("encoder_resolution", args.encoder)) if v is not None}
    controller = controller_from_fmu(args.controller_fmu).with_values(**changes)
    disturbance = read_disturbance_csv(args.disturbance) if args.disturbance else None
    path = write_system(args.plant_fmu, args.controller_fmu, read_reference_csv(args.reference), args.output,
                        controller=controller, overwrite=args.force, disturbance=disturbance)
    print_written(args, f"wrote {path} (SSP: reference, {'disturbance, ' if disturbance else ''}controller and "
                  "plant; controller parameters in resources/controller.ssv)",
                  {"written": [path], "plant_fmu": args.plant_fmu, "controller_fmu": args.controller_fmu,
                   "disturbance": disturbance is not None})


def cmd_cosim(args) -> None:
    """Co-simulate an SSP system into a records file."""
    import numpy as np

    from ..control.cosim import cosimulate, write_cosim_records
    from .common import run_options

    with ProgressBar(args, "step") as bar:  # communication steps of the co-simulation
        result = cosimulate(args.system, args.stop_time, engine=args.engine, progress=bar.update)
    data = write_cosim_records(result, args.system, args.output, append=args.append, run=run_options(args))
    error = result["reference"] - result["position"]
    rms, peak = float(np.sqrt(np.mean(error ** 2))), float(np.max(np.abs(error)))
    print_written(args, f"wrote {args.output}: {len(data.records)} record(s); {result.engine}, {result.time.size - 1} "
                  f"steps of {result.time[1]:g} s; tracking error RMS {rms:.3g} m, peak {peak:.3g} m",
                  {"written": [args.output], "records": len(data.records), "engine": result.engine,
                   "steps": int(result.time.size - 1), "step_s": float(result.time[1]),
                   "tracking_error_rms_m": rms, "tracking_error_peak_m": peak})


def cmd_compensate(args) -> None:
    """The axis with and without the feed-forward of the identified friction."""
    import json

    from ..control.compensation import compensate_files
    from ..output.compensation_report import compensation_json, compensation_page, compensation_text

    with ProgressBar(args, "run") as bar:  # (the page claimed with the command's outputs, before the runs)
        compensation = compensate_files(args.result, args.axis, truth=args.truth, engine=args.engine,
                                        progress=bar.update)
    if args.output:
        from ..fileio import atomic_write

        atomic_write(args.output, compensation_page(compensation))
    runs = compensation.runs
    if args.json:
        print(json.dumps(compensation_json(runs), allow_nan=True))
        return
    print(compensation_text(runs))
    if args.output:
        print(f"wrote {args.output}")


def register(sub) -> None:
    """Add the subcommands controller, system, cosim and compensate to the subparsers ``sub``."""
    p = sub.add_parser("controller", help="a drive controller file (TOML) as a Co-Simulation FMU")
    p.add_argument("controller", metavar="CTRL.toml", role="input",
                   help="controller file, or the name of an example (axis_controller)")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), default=3, help="FMI version (default 3)")
    p.add_argument("--compensate", metavar="RESULT.h5|PLANT.toml", role="input",
                   help="feed forward the friction of an identified result or a plant file")
    add_json_option(p)
    p.add_argument("-o", "--output", help="FMU file to write (default: NAME.fmu)")
    p.set_defaults(func=cmd_controller)

    p = sub.add_parser("system", help="plant + controller + reference as an SSP archive")
    p.add_argument("plant_fmu", metavar="PLANT.fmu", role="input", help="plant FMU (FMI 2.0 Co-Simulation)")
    p.add_argument("controller_fmu", metavar="CTRL.fmu", role="input",
                   help="controller FMU from `servofmu controller`")
    p.add_argument("--reference", required=True, metavar="REF.csv", role="input",
                   help="reference trajectory: CSV with columns time (s) and position (m)")
    p.add_argument("--disturbance", metavar="DIST.csv", role="input",
                   help="a known disturbance the drive adds after its output limit: CSV with columns time (s) and "
                        "force (N, applied from each time on; 0 at the first two samples)")
    p.add_argument("--encoder", type=float, metavar="M", help="encoder resolution (m; default the controller's)")
    p.add_argument("--force-noise", type=float, metavar="N", help="actuator noise, standard deviation (N)")
    p.add_argument("--seed", type=int, help="seed of the actuator noise")
    add_json_option(p)
    p.add_argument("-o", "--output", metavar="AXIS.ssp", required=True, help="SSP archive to write")
    p.set_defaults(func=cmd_system)

    p = sub.add_parser("cosim", help="co-simulate an SSP system on libcosim or FMPy into a records file")
    p.add_argument("system", metavar="AXIS.ssp", role="input", help="SSP archive from `servofmu system`")
    p.add_argument("--stop-time", type=float, help="seconds (default: the system's default experiment)")
    p.add_argument("--engine", choices=ENGINES, default="libcosim", help="co-simulation engine (default libcosim)")
    p.add_argument("--append", action="store_true", help="add the run to an existing records file")
    add_json_option(p)
    add_progress_option(p)
    p.add_argument("-o", "--output", metavar="RECORDS.h5", required=True, help="records file to write")
    p.set_defaults(func=cmd_cosim)

    p = sub.add_parser("compensate", help="the axis with and without feed-forward of the identified friction")
    p.add_argument("result", metavar="RESULT.h5", role="input", help="result file from `servofmu identify`")
    p.add_argument("--axis", required=True, metavar="AXIS.ssp", role="input",
                   help="the axis from `servofmu system` (its reference should reverse the velocity)")
    p.add_argument("--truth", metavar="PLANT", help="the true plant, when known: a third run with its friction")
    p.add_argument("--engine", choices=ENGINES, default="libcosim", help="co-simulation engine (default libcosim)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_progress_option(p)
    p.add_argument("-o", "--output", metavar="REPORT.html", help="HTML page to write")
    p.set_defaults(func=cmd_compensate)
