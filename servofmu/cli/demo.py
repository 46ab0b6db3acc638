"""`servofmu demo`: the whole path on the paper's plants g1 and g2, then the example axis in its loop."""
from __future__ import annotations

from pathlib import Path

__all__ = ["register", "cmd_demo"]


def cmd_demo(args) -> None:
    """Run the demo into its folder, printing what it does."""
    from ..output.demo import run_demo

    run_demo(Path(args.out), report=print, overwrite=args.force)


def register(sub) -> None:
    """Add the subcommand demo to the subparsers ``sub``."""
    p = sub.add_parser("demo", help="the whole path on the paper's plants g1 and g2")
    p.add_argument("--out", default="demo-output", help="folder for the demo's files (default demo-output)")
    p.add_argument("--force", action="store_true", help="replace the demo's files in an existing --out folder")
    p.set_defaults(func=cmd_demo, output_folders=("out",))
