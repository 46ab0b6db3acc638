"""`servofmu select`: which friction law and which order of G(s) — candidate structures fitted and ranked."""
from __future__ import annotations

import argparse

from ..model.laws.registry import default_laws, law_names
from .common import ProgressBar, add_progress_option, add_work_limit_option, run_options

__all__ = ["register", "cmd_select"]


def _orders(text: str) -> tuple[int, ...]:
    """``--orders 1,2,3``: whole numbers (their range is the library's to check)."""
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma-separated list of whole numbers: {text!r}") from None


def cmd_select(args) -> None:
    """Fit every candidate structure, rank them on the validation file, write SELECT.h5, the plant file, the page."""
    import json

    from ..commands.select import select_with_report
    from ..selection.summary import selection_json, selection_text
    from ..selection.select import SelectOptions

    options = SelectOptions(candidates=tuple(args.candidates.split(",")) if args.candidates else None,
                            orders=args.orders, seed=args.seed, iterations=args.iterations, skip=args.skip,
                            closed_loop=args.closed_loop, work_limit=args.work_limit,
                            **({} if args.budget is None else {"budget": args.budget}))
    with ProgressBar(args, "candidate") as bar:
        selection = select_with_report(args.data, args.validate, args.output, options, run_options(args, bar),
                                       args.plant, args.result, args.report)
    print(json.dumps(selection_json(selection), allow_nan=True) if args.json else selection_text(selection))


def register(sub) -> None:
    """Add the subcommand select to the subparsers ``sub``."""
    p = sub.add_parser("select", help="which friction law and order of G(s): candidate structures fitted and ranked")
    p.add_argument("data", nargs="+", role="input", help="data of one axis (HDF5): stepped-sine measurements or "
                                                         "records, fitted jointly")
    p.add_argument("--validate", required=True, role="input", metavar="OTHER.h5",
                   help="data of the same axis and signals that no candidate is fitted to; the ranking uses it")
    p.add_argument("--closed-loop", metavar="CTRL.toml", role="input",
                   help="the records are closed-loop logs of this controller")
    laws, default = law_names(), default_laws()
    p.add_argument("--candidates", metavar="LIST", help=f"comma-separated: a law with terms ({', '.join(laws)}, "
                   f"{laws[0]}+offset, stribeck+delta, {laws[0]}+fv_asym, …; tried at every order, with and without a "
                   f"zero) or LAW[+TERM…]/ORDER[z] ({laws[-1]}/2z); default: the laws {', '.join(default)} at every "
                   "order, then the load and friction terms on the one ranked first")
    p.add_argument("--orders", type=_orders, default=(1, 2, 3), metavar="1,2,3",
                   help="orders of G(s) tried (default 1,2,3)")
    p.add_argument("--skip", type=float, default=0.0, metavar="SECONDS",
                   help="records: leave the first SECONDS of every record out (as identify --skip)")
    p.add_argument("--iterations", type=int, metavar="N", help="swarm iterations per candidate (default 50)")
    p.add_argument("--seed", type=int, default=0, help="seed of every candidate's swarm (default 0)")
    p.add_argument("--budget", type=float, metavar="SECONDS", help="seconds a candidate's swarm may take before "
                   "its polish goes on from its best (default 60; the candidate's row says where it was cut)")
    add_work_limit_option(p)
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core; 0: this process)")
    p.add_argument("--scheduler", metavar="ADDR", help="Dask scheduler, tcp://HOST:PORT (default: local processes)")
    p.add_argument("--json", action="store_true", help="print the ranking as one JSON object")
    add_progress_option(p)
    p.add_argument("-o", "--output", required=True, help="SELECT.h5 to write: every candidate's result and the "
                                                         "ranking")
    p.add_argument("--plant", metavar="CHOSEN.toml", role="output", help="the chosen structure's plant file (default: SELECT.toml)")
    p.add_argument("--result", metavar="CHOSEN.h5", role="output", help="the chosen structure's result (default: "
                                                          "SELECT-result.h5)")
    p.add_argument("--report", metavar="PAGE.html", role="output", help="also write the HTML page: the ranking and the best "
                                                         "candidates' fits side by side")
    p.set_defaults(func=cmd_select, default_outputs=_default_outputs, quick_exit=True)


def _default_outputs(args) -> None:
    """SELECT.toml and SELECT-result.h5 where --plant and --result are not given: claimed with the others."""
    from ..selection.run import selection_outputs

    outputs = selection_outputs(args.output, args.plant, args.result)
    args.plant, args.result = str(outputs["plant"]), str(outputs["result"])
