"""`servofmu demo`: the whole path on the paper's plants g1 and g2, then the example axis in its loop."""
from __future__ import annotations

from pathlib import Path

from .common import DeprecatedAlias, ProgressBar, add_json_option, add_output_option, add_progress_option, print_written

__all__ = ["register", "cmd_demo"]


def cmd_demo(args) -> None:
    """Run the demo into its folder, printing what it does (with --json: the files written, at the end)."""
    from ..commands.demo import run_demo

    with ProgressBar(args, "step", label="demo") as bar:
        results = run_demo(Path(args.output), report=(lambda line: None) if args.json else bar.say,
                           overwrite=args.force, stage=bar.stage)
    if args.json:
        files = sorted(str(f) for f in Path(args.output).rglob("*") if f.is_file())
        print_written(args, "", {"written": files, "folder": args.output,
                                 "identified": {name: dict(zip(r.names, map(float, r.theta)))
                                                for name, r in results.items()}})


def register(sub) -> None:
    """Add the subcommand demo to the subparsers ``sub``."""
    p = sub.add_parser("demo", help="the whole path on the paper's plants g1 and g2")
    add_output_option(p, "folder for the demo's files (default demo-output)", metavar="FOLDER", default="demo-output",
                      role="folder")
    p.add_argument("--out", dest="output", action=DeprecatedAlias, alias_of="-o/--output", metavar="FOLDER",
                   help="deprecated spelling of -o/--output")
    p.add_argument("--force", action="store_true", help="replace the demo's files in an existing -o folder")
    add_json_option(p)
    add_progress_option(p)
    p.set_defaults(func=cmd_demo, output_folders=("output",))
