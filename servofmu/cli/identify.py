"""`servofmu dataset`, `train`, `identify` and `compare`: the PSO-ANN identification and its comparators."""
from __future__ import annotations

import sys

from ..errors import UserError
from .common import (ProgressBar, add_json_option, add_progress_option, add_work_limit_option, print_written,
                     run_options)

__all__ = ["register", "cmd_dataset", "cmd_train", "cmd_identify", "cmd_compare"]


def cmd_dataset(args) -> None:
    """Simulate plants around a structure under a data file's plan: the training set."""
    from ..identification.training_set import make_training_set, training_data
    from ..model.plant import load_plant

    structure, data = load_plant(args.plant), training_data(args.like)
    with ProgressBar(args, "plant") as bar:
        ts = make_training_set(structure, data, args.samples, args.output, spread=args.spread, seed=args.seed,
                               run=run_options(args, bar))
    count, broadband = ts.amplitudes.size, bool(ts.attributes.get("broadband_plan"))
    what = (f"{count} bands of its levels' BLA); {ts.usable().sum()} simulated to the end" if broadband
            else f"{count} experiments); {ts.usable().sum()} with every experiment at steady state")
    print_written(args, f"wrote {args.output}: {ts.done.sum()} plants like {structure.name} under the plan of "
                  f"{args.like} ({what}", {"written": [args.output], "structure": structure.name,
                                         "plants": int(ts.done.sum()), "usable": int(ts.usable().sum()),
                                         "experiments": int(count)})


def cmd_train(args) -> None:
    """Train the network on a training set."""
    from ..identification.train import train_from_file

    with ProgressBar(args, "epoch") as bar:
        net, rows = train_from_file(args.dataset, args.output, hidden=args.hidden, seed=args.seed,
                                    run=run_options(args, bar))
    print_written(args, f"wrote {args.output}: {net.inputs}-{net.hidden}-{net.outputs} network trained on {rows} "
                  f"plants ({net.optimizer}, {len(net.validation_loss)} epochs); validation RMS error "
                  f"{net.validation_rmse:.3g} (normalised units)",
                  {"written": [args.output], "layers": [net.inputs, net.hidden, net.outputs], "plants": rows,
                   "optimizer": net.optimizer, "epochs": len(net.validation_loss),
                   "validation_rmse": float(net.validation_rmse)})


def identify_options(args):
    """The identification's settings (identification.run.IdentifyOptions) from the command line."""
    from ..identification.run import IdentifyOptions

    return IdentifyOptions(method=args.method, seed=args.seed, polish=not args.no_polish,
                           iterations=args.iterations, skip=args.skip, closed_loop=args.closed_loop,
                           work_limit=args.work_limit)


def cmd_identify(args) -> None:
    """Identify one data file into a result file (or many into a folder: :func:`cmd_identify_files`)."""
    if args.output_dir is not None or len(args.data) > 1:
        return cmd_identify_files(args)
    if args.output is None or args.scheduler or args.workers is not None or args.resume:
        raise UserError("give -o RESULT.h5 for one data file (--scheduler, --workers and --resume go with "
                        "--output-dir DIR)")
    from ..identification.results import table_text, to_json_text
    from ..identification.run import identify_to_file

    with ProgressBar(args, "iteration") as bar:
        result = identify_to_file(args.data[0], args.structure, args.output, args.ann, identify_options(args),
                                  run_options(args, bar))
    from ..identification.broadband_identify import frequency_lines
    from ..identification.closed_loop import clock_lines

    print(to_json_text(result) if args.json
          else "\n".join([table_text(result), *clock_lines(result.provenance), *frequency_lines(result.provenance),
                          f"wrote {args.output}"]))


def cmd_identify_files(args) -> None:
    """`identify A.h5 B.h5 ... --output-dir DIR`: one result per data file and a summary table."""
    from ..identification.fleet import identify_files, outcomes_json, outcomes_table

    if args.output_dir is None or args.output is not None:
        raise UserError(f"{len(args.data)} data files: give --output-dir DIR (one result per file, named after "
                        "the data files), not -o")
    with ProgressBar(args, "file") as bar:
        outcomes = identify_files(args.data, args.structure, args.output_dir, args.ann, identify_options(args),
                                  run_options(args, bar))
    print(outcomes_json(outcomes) if args.json else outcomes_table(outcomes))
    failed = [o.message if o.data_file in o.message else f"{o.data_file}: {o.message}"
              for o in outcomes if o.status == "failed"]
    if failed:
        raise UserError(f"{len(failed)} of {len(outcomes)} data files not identified: " + "; ".join(failed[:3])
                        + ("; ..." if len(failed) > 3 else ""))


def cmd_compare(args) -> None:
    """Every identification method on the same data, in the paper's table layout."""
    import json

    from ..baselines.compare import compare_files, comparison_json, comparison_markdown

    with ProgressBar(args, "method") as bar:
        results, truth = compare_files(args.data, args.structure, args.ann, args.truth,
                                       args.methods.split(",") if args.methods else None, args.seed, args.output,
                                       command=args.command_line, overwrite=args.force, progress=bar.update,
                                       announce=_announce(args, bar))
    if args.json:
        print(json.dumps(comparison_json(results, truth), allow_nan=True))
        return
    print(comparison_markdown(results, truth), end="")
    if args.output:
        print(f"wrote {args.output}")


def _announce(args, bar):
    """compare's "running METHOD ...": the bar's label when there is a bar, else a line on stderr (none with
    --json)."""
    if bar.shown:
        return lambda method: bar.label(f"compare: {method}")
    return None if args.json else lambda method: print(f"running {method} ...", file=sys.stderr)


def register(sub) -> None:
    """Add the subcommands dataset, train, identify and compare to the subparsers ``sub``."""
    _register_dataset_train(sub)
    _register_identify(sub)
    _register_compare(sub)


def _register_dataset_train(sub) -> None:
    p = sub.add_parser("dataset", help="simulate plants drawn around a structure under a data file's plan")
    p.add_argument("plant", help="the structure: plant file or name in fmu_models/")
    p.add_argument("--like", required=True, role="input",
                   help="data file (HDF5) whose plan the plants are simulated under (stepped sines, or a "
                        "broadband file's whole plan: docs/broadband.md)")
    p.add_argument("--samples", type=int, required=True, help="number of plants")
    p.add_argument("--spread", type=float, default=0.5, help="prior width: factors in [1/(1+S), 1+S] (default 0.5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the prior draw (default 0)")
    p.add_argument("--scheduler", metavar="ADDR", help="Dask scheduler address tcp://HOST:PORT (default: this "
                                                       "machine)")
    p.add_argument("--resume", action="store_true", help="complete an interrupted run of the same command")
    add_progress_option(p)
    add_json_option(p)
    p.add_argument("-o", "--output", required=True, help="training set to write (HDF5)")
    p.set_defaults(func=cmd_dataset)

    p = sub.add_parser("train", help="train the ANN on a training set")
    p.add_argument("dataset", role="input", help="training set (HDF5) from `servofmu dataset`")
    p.add_argument("--hidden", type=int, default=20, help="hidden neurons (default 20, the paper's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the validation split and initial weights (default 0)")
    add_progress_option(p)
    add_json_option(p)
    p.add_argument("-o", "--output", required=True, help="network file to write (HDF5)")
    p.set_defaults(func=cmd_train)


def _register_identify(sub) -> None:
    from ..identification.methods import METHODS

    p = sub.add_parser("identify", help="identify G(s) and the friction from a data file (or many)")
    p.add_argument("data", nargs="+", role="input", help="data file (HDF5) from `servofmu measure` or `servofmu "
                                                         "import`; several with --output-dir")
    p.add_argument("--structure", required=True, role="input",
                   help="plant file giving the structure (order, friction model)")
    p.add_argument("--ann", role="input", help="trained network (HDF5) from `servofmu train`")
    p.add_argument("--method", choices=METHODS,
                   help="pso-ann (the default with --ann), pso (the default without: no ANN), ga-ann or aga-ann (the "
                        "paper's GA comparators)")
    p.add_argument("--closed-loop", metavar="CTRL.toml", role="input", help="the records are closed-loop logs of "
                   "this controller: every candidate is simulated in the loop from the recorded reference")
    p.add_argument("--no-polish", action="store_true", help="skip the least-squares polish after the swarm")
    p.add_argument("--skip", type=float, default=0.0, metavar="SECONDS",
                   help="records: leave the first SECONDS of every record out of the fit (the model starts at rest "
                        "at the first sample; a record that does not start at rest is fitted after its initial "
                        "state has died away)")
    p.add_argument("--iterations", type=int, metavar="N",
                   help="swarm iterations (default 50, the paper's; the GA comparators get as many model evaluations); "
                        "fewer are faster, 0 polishes from the network's estimate: docs/bench-swarm-budget.md")
    p.add_argument("--seed", type=int, default=0, help="seed of the swarm (default 0)")
    add_work_limit_option(p)
    p.add_argument("--json", action="store_true", help="print the result as one JSON object (many files: an array "
                                                       "of one summary object per file)")
    add_progress_option(p)
    p.add_argument("-o", "--output", help="result file to write (HDF5), for one data file")
    p.add_argument("--output-dir", metavar="DIR", help="many data files: write DIR/NAME-result.h5 for each NAME.h5 "
                                                       "and print a summary table")
    p.add_argument("--scheduler", metavar="ADDR", help="many data files: Dask scheduler, tcp://HOST:PORT (default: "
                                                       "local processes)")
    p.add_argument("--workers", type=int, help="many data files: local worker processes (default: one per core; 0: "
                                               "this process)")
    p.add_argument("--resume", action="store_true", help="many data files: keep the results already in DIR from the "
                                                         "same data and settings, identify the others")
    # --resume continues the results in --output-dir, never an -o file: an existing -o is advised --force only
    p.set_defaults(func=cmd_identify, quick_exit=True, output_folders=("output_dir",), continues_outputs=None)


def _register_compare(sub) -> None:
    from ..baselines import BASELINE_METHODS, BASELINE_NEEDS_ANN
    from ..identification.methods import METHODS, NEEDS_ANN

    p = sub.add_parser("compare", help="every identification method on the same data, in the paper's table layout")
    p.add_argument("data", role="input", help="data file (HDF5) from `servofmu measure`")
    p.add_argument("--structure", required=True, role="input", help="plant file giving the structure")
    p.add_argument("--ann", role="input", help=f"trained network (HDF5); needed by "
                                               f"{', '.join(NEEDS_ANN + BASELINE_NEEDS_ANN)}")
    p.add_argument("--truth", role="input",
                   help="plant file of the true plant: adds the target column and relative errors")
    p.add_argument("--methods", help=f"comma-separated: {', '.join(METHODS + BASELINE_METHODS)} "
                                     "(default: all that the inputs allow)")
    p.add_argument("--seed", type=int, default=0, help="seed of every method (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object keyed by method")
    add_progress_option(p)
    p.add_argument("-o", "--output", help="write the table (.md) or every result (.h5, for `servofmu report`)")
    p.set_defaults(func=cmd_compare)
