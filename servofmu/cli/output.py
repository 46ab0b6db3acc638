"""`servofmu validate`, `report` and `export`: an identified model checked, shown and handed to other tools."""
from __future__ import annotations

from .common import ProgressBar, add_json_option, add_progress_option, print_written

__all__ = ["register", "cmd_validate", "cmd_report", "cmd_export"]


def cmd_validate(args) -> None:
    """Simulate one result (or several, side by side: a column each) on other data: fit % and residual tests;
    exit status 1 when a model's verdict is "failed"."""
    import json

    out, as_json, as_text, passed = _validate_with_page(args)
    if args.json:
        print(json.dumps(as_json(out), allow_nan=False))
    else:
        print(as_text(out))
        if args.output:
            print(f"wrote {args.output}")
    if not passed(out):
        raise SystemExit(1)  # a model failed: not a user error (2), the files are written


def _validation(args):
    """(run, write the page, to JSON, to text, passed) of one result's validation or of several results' side by
    side."""
    if len(args.result) > 1:
        from ..output.model_comparison import comparison_json, comparison_text, write_comparison
        from ..validation.run import validate_several

        return (lambda **kw: validate_several(args.result, **kw),
                lambda output, pairs: write_comparison(output, pairs, args.data), comparison_json, comparison_text,
                lambda pairs: all(v.passed for _, v in pairs))
    from ..output.validation_report import write_validation
    from ..validation.replay import validation_json, validation_text
    from ..validation.run import validate_files

    return (lambda **kw: validate_files(args.result[0], **kw),
            lambda output, v: write_validation(output, v, args.result[0], args.data), validation_json,
            validation_text, lambda v: v.passed)


def _validate_with_page(args):
    """The validation (servofmu.validation.run) and its page or figure: (validation(s), to JSON, to text, passed)."""
    run, write, as_json, as_text, passed = _validation(args)
    if args.output:  # (claimed with the command's outputs already; its kind checked before any work)
        from ..output.validation_report import check_page_suffix

        check_page_suffix(args.output)
    with ProgressBar(args, "step") as bar:  # a step per model simulated on the data, and the page written
        pages = 1 if args.output else 0
        out = run(data_path=args.data, skip=args.skip, controller=args.closed_loop,
                  progress=lambda done, total: bar.update(done, total + pages),
                  **({} if args.min_fit is None else {"min_fit": args.min_fit}))
        if args.output:
            write(args.output, out)
            bar.update(len(args.result) + 1, len(args.result) + 1)
    return out, as_json, as_text, passed


def cmd_report(args) -> None:
    """One self-contained HTML page of an identification."""
    from ..output.report import make_report

    path = make_report(args.source, args.output, data=args.data, truth=args.truth, validate=args.validate,
                       overwrite=args.force)
    print_written(args, f"wrote {path} (self-contained HTML: tables and figures)",
                  {"written": [path], "source": args.source, "bytes": path.stat().st_size})


EXPORTED = {"fmu": "FMI {v}.0 FMU, Model Exchange + Co-Simulation, provenance in its description, annotations and "
                   "documentation/index.html",
            "control": "python-control model: servofmu.output.export.load_control(path)", "mat": "MATLAB .mat",
            "json": "JSON", "toml": "plant file: servofmu build accepts it"}


def cmd_export(args) -> None:
    """An identified model as an FMU, python-control, MATLAB, JSON or plant file."""
    from ..output.export import export_result

    path, fmt = export_result(args.result, args.output, fmt=args.format, fmi_version=args.fmi_version,
                              name=args.name, command=args.command_line, overwrite=args.force)
    print_written(args, f"wrote {path} ({EXPORTED[fmt].format(v=args.fmi_version or 3)})",
                  {"written": [path], "format": fmt, "result": args.result,
                   **({"fmi_version": args.fmi_version or 3} if fmt == "fmu" else {})})


def register(sub) -> None:
    """Add the subcommands validate, report and export to the subparsers ``sub``."""
    from ..output.formats import FORMATS, SUFFIX_FORMATS

    p = sub.add_parser("validate", help="simulate identified models on other data: fit %% and residual tests")
    p.add_argument("result", metavar="RESULT.h5", nargs="+", role="input",
                   help="result file from `servofmu identify`; several: validated side by side, one column each")
    p.add_argument("data", metavar="DATA.h5", role="input",
                   help="data file (records or a measurement) it was not fitted to")
    p.add_argument("--skip", type=float, default=0.0, metavar="SECONDS",
                   help="leave the first SECONDS of every record out (as identify --skip)")
    p.add_argument("--closed-loop", metavar="CTRL.toml", role="input",
                   help="closed-loop records of this controller: replayed in the loop from their reference")
    p.add_argument("--min-fit", type=float, metavar="PCT",
                   help="the fit (%%) every record and experiment must reach (default 80, "
                        "servofmu.validation.replay.MIN_FIT; docs/validation.md); exit status 1 when the model fails")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_progress_option(p)
    p.add_argument("-o", "--output", metavar="FILE.html|FILE.png", help="write a page or a figure")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("report", help="one self-contained HTML page of an identification: tables and figures")
    p.add_argument("source", metavar="RESULT.h5|COMPARE.h5", role="input",
                   help="result file from `servofmu identify` or comparison file from `servofmu compare`")
    p.add_argument("--data", metavar="DATA.h5", role="input", help="the data file it was identified from (default: "
                   "the path its provenance records, or that name beside it)")
    p.add_argument("--truth", metavar="PLANT", help="the true plant (file or name in fmu_models/), when known: "
                                                    "drawn in the friction figure, relative errors in the table")
    p.add_argument("--validate", metavar="DATA.h5", role="input", help="add the validation on another data file "
                   "(fit %%, residual tests; see `servofmu validate`)")
    add_json_option(p)
    p.add_argument("-o", "--output", metavar="REPORT.html", required=True, help="HTML file to write")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("export", help="export an identified model: FMU, python-control, MATLAB, JSON, plant TOML")
    p.add_argument("result", metavar="RESULT.h5", role="input", help="result file from `servofmu identify`")
    p.add_argument("--format", choices=FORMATS, help=f"default: from the suffix of -o ({', '.join(SUFFIX_FORMATS)})")
    p.add_argument("--fmi-version", type=int, choices=(2, 3), help="FMI version of an FMU (default 3)")
    p.add_argument("--name", help="model name in the export (default: the plant's name + _identified)")
    add_json_option(p)
    p.add_argument("-o", "--output", metavar="FILE", required=True, help="file to write")
    p.set_defaults(func=cmd_export)
