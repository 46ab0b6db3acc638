"""`servofmu tune`: the drive's gains for an identified axis (servofmu.tuning.run.tune_files, the page in
output.tune_report)."""
from __future__ import annotations

__all__ = ["register", "cmd_tune", "DEFAULT_STROKE", "DEFAULT_SPEED", "METHODS", "OPTION_DEFAULTS"]

# The library's values (servofmu.tuning.task.DEFAULT_STROKE and DEFAULT_SPEED, servofmu.tuning.run.METHODS,
# servofmu.tuning.search.TuneOptions' defaults), here as literals so that `--help` loads neither numpy nor h5py
# (tests/test_cli_options.py checks that they agree); the options left out reach the library as its defaults.
DEFAULT_STROKE, DEFAULT_SPEED = 0.1, 0.15
METHODS = ("pso", "rule")
OPTION_DEFAULTS = {"max_sensitivity": 1.7, "seed": 0, "particles": 16, "iterations": 30}


def cmd_tune(args) -> None:
    """Tune a controller file for an identified axis; write the tuned controller file (and its page)."""
    import json

    from ..output.tune_report import tune_json, tune_text

    tuning = _tune_with_page(args)
    if args.json:
        print(json.dumps(tune_json(tuning), allow_nan=True))
        return
    print(tune_text(tuning))
    print(f"wrote {args.output}" + (f" and {args.report}" if args.report else ""))


def _tune_with_page(args):
    """The tuning (servofmu.tuning.run.tune_files) and its page: the controller file and the page, or neither."""
    from pathlib import Path

    from ..fileio import all_or_none, atomic_write
    from ..output.tune_report import tune_html
    from ..tuning.run import tune_files
    from ..tuning.search import TuneOptions
    from .common import ProgressBar

    options = TuneOptions(**{k: getattr(args, k) for k in OPTION_DEFAULTS if getattr(args, k) is not None},
                          keep=args.keep, work_limit=args.work_limit)
    with ProgressBar(args, "iteration") as bar, all_or_none((args.output, args.report)):
        tuning = tune_files(args.result, args.controller, args.output, task=args.task, stroke=args.stroke,
                            speed=args.speed, options=options, compensate=args.compensate, method=args.method,
                            axis=args.axis, engine=args.engine, overwrite=args.force, progress=bar.update)
        if args.report:
            atomic_write(args.report, tune_html(tuning, Path(args.result).name, Path(args.controller).name))
    return tuning


def register(sub) -> None:
    """Add the subcommand tune to the subparsers ``sub``."""
    from .common import add_progress_option, add_work_limit_option

    p = sub.add_parser("tune", help="tune a drive's gains for an identified axis (particle swarm, robustness bound)")
    p.add_argument("result", metavar="RESULT.h5", role="input", help="result file of the axis (`servofmu identify`)")
    p.add_argument("controller", metavar="CTRL.toml", role="input",
                   help="the drive's controller file, or the name of an example (axis_controller)")
    p.add_argument("--task", metavar="REF.csv", role="input",
                   help="the motion to tune for: CSV with columns time (s) and position (m), one row per sample")
    p.add_argument("--stroke", type=float, metavar="M",
                   help=f"or a reversing stroke of M metres (default {DEFAULT_STROKE:g})")
    p.add_argument("--speed", type=float, metavar="V", help=f"at a peak speed of V m/s (default {DEFAULT_SPEED:g})")
    p.add_argument("--max-sensitivity", type=float, metavar="MS", help="bound on the sensitivity peak of the loop "
                   f"linearised about motion (default {OPTION_DEFAULTS['max_sensitivity']:g})")
    p.add_argument("--compensate", action="store_true", help="feed forward the identified friction")
    p.add_argument("--method", choices=METHODS, default="pso",
                   help="pso: the particle swarm (default); rule: the reference rule alone")
    p.add_argument("--axis", metavar="AXIS.ssp", role="input",
                   help="check on this axis: co-simulate the given, rule and tuned gains on it (libcosim)")
    p.add_argument("--engine", choices=("libcosim", "fmpy"), default="libcosim",
                   help="co-simulation engine of the check (default libcosim)")
    p.add_argument("--seed", type=int, help=f"seed of the swarm and the uncertainty draws (default "
                                           f"{OPTION_DEFAULTS['seed']})")
    p.add_argument("--particles", type=int, help=f"particles of the swarm (default {OPTION_DEFAULTS['particles']})")
    p.add_argument("--iterations", type=int, help=f"iterations of the swarm (default {OPTION_DEFAULTS['iterations']})")
    p.add_argument("--keep", type=lambda text: tuple(n.strip() for n in text.split(",") if n.strip()), default=(),
                   metavar="NAME[,NAME]", help="parameters the data left undetermined, taken at their identified "
                                               "values (without it such a result is refused)")
    add_work_limit_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-o", "--output", metavar="TUNED.toml", required=True, help="controller file to write")
    p.add_argument("--report", metavar="TUNE.html", role="output", help="HTML page of the tuning to write")
    add_progress_option(p)
    p.set_defaults(func=cmd_tune)
