"""A small mutation check: does each test that claims to guard a behaviour fail when that behaviour is broken?

Each mutation below is one textual change to one source file.  For each, the package (servofmu/, the example
files of fmu_models/) and the tests are copied into a temporary folder (from a commit, HEAD by default, with
`git archive`; or the files as they are with --worktree), the change is made in the copy only, and the tests that
claim the behaviour are run there (pytest in the copy, with PYTHONPATH pointing at it, so that the commands the
tests start import the copy too).  A mutation is caught when those tests fail.  The unchanged copy is run first:
its tests must pass, or the check says so.  Nothing in the working tree is written to.

Usage: python scripts/mutation_check.py [--rev REV | --worktree] [--only NAME ...] [--out docs/mutation-check.md]
"""
from __future__ import annotations

import argparse
import io
import os
import shlex
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Mutation:
    name: str
    what: str
    edits: tuple[tuple[str, str, str], ...]  # alternatives (file, old text, new text): the first one that applies
    tests: tuple[str, ...]  # pytest arguments, relative to the copy


MUTATIONS = (
    Mutation("pso-no-clip", "PSO: an initial guess outside the box is not clipped into it",
             (("servofmu/identification/search.py", "    return np.clip(x0, lower, upper)\n", "    return x0\n"),),
             ("tests/test_pso.py",)),
    Mutation("nls-default-start", "CasADi NLS: theta0=None starts 20 % above the structure's values",
             (("servofmu/baselines/casadi_nls.py",
               "structure.parameter_vector()[identified_mask(structure)] if theta0 is None",
               "1.2 * structure.parameter_vector()[identified_mask(structure)] if theta0 is None"),),
             ("tests/test_casadi_nls.py", "-k", "default_start")),
    Mutation("controller-ki", "controller files: the velocity loop's ki read 20 % high",
             (("servofmu/model/controller.py", "            values[parameter] = float(v)\n",
               "            values[parameter] = float(v) * (1.2 if parameter == 'ki_velocity' else 1.0)\n"),),
             ("tests/test_control.py", "-k", "example_controller or libcosim_and_fmpy")),
    Mutation("intervals-10x", "intervals: 10 times wider",
             (("servofmu/identification/criterion.py", "    half = t_quantile(level, dof) *",
               "    half = 10 * t_quantile(level, dof) *"),),
             ("tests/test_intervals.py",)),
    Mutation("overwrite", "the output rule lets an existing output be replaced without overwrite=True/--force",
             (("servofmu/fileio.py", '    if mode == "new" and path.exists():', "    if False:"),),
             ("tests/test_overwrite.py",)),
    Mutation("overwrite-cli", "the command line asks the output rule to replace whether or not --force is given",
             (("servofmu/cli/common.py", '    return "replace" if getattr(args, "force", False) else "new"',
               '    return "replace"'),),
             ("tests/test_overwrite.py",)),
    Mutation("chen-fbar", "Chen 2002: F̄ 10 % high (on g1 the pole's error grows from 0.5 % to 4 %)",
             (("servofmu/baselines/chen2002.py", "    f_bar = float(np.dot(x, y) / np.dot(x, x))",
               "    f_bar = 1.1 * float(np.dot(x, y) / np.dot(x, x))"),),
             ("tests/test_chen2002.py", "-k", "g1_fmu")),
)


PARTS = ("servofmu", "fmu_models", "tests", "pyproject.toml")


def copy_tree(dest: Path, rev: str | None) -> None:
    """The package, its example files (inside it, as installed) and the tests, from commit ``rev`` or (None) the
    working tree."""
    if rev is None:
        ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".pytest_cache")
        for part in PARTS[:3]:
            shutil.copytree(ROOT / part, dest / part, ignore=ignore)
        shutil.copy(ROOT / "pyproject.toml", dest / "pyproject.toml")
    else:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev, *PARTS],
                                 capture_output=True, check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(dest, filter="data")
    (dest / "fmu_models").rename(dest / "servofmu" / "fmu_models")


def apply(mutation: Mutation, dest: Path) -> str | None:
    """Make the change in the copy; the file changed, or None when no alternative's text is there (once)."""
    for file, old, new in mutation.edits:
        path = dest / file
        if path.is_file() and path.read_text().count(old) == 1:
            path.write_text(path.read_text().replace(old, new))
            return file
    return None


def run_tests(dest: Path, tests: tuple[str, ...]) -> tuple[bool, str, float]:
    env = {**os.environ, "PYTHONPATH": str(dest), "PYTHONDONTWRITEBYTECODE": "1"}
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *tests],
                          cwd=dest, env=env, capture_output=True, text=True)
    last = (proc.stdout.strip().splitlines() or ["(no output)"])[-1]
    return proc.returncode == 0, last, time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--rev", default="HEAD", help="the commit to copy (default HEAD)")
    source.add_argument("--worktree", action="store_true", help="copy the files as they are instead")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="only these mutations")
    parser.add_argument("--out", type=Path, help="also write the table to this Markdown file")
    args = parser.parse_args()
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only]
    rev = None if args.worktree else subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.rev],
                                                    capture_output=True, text=True, check=True).stdout.strip()
    rows = []
    for m in chosen:
        with tempfile.TemporaryDirectory(prefix="mutation-check-") as tmp:
            dest = Path(tmp)
            copy_tree(dest, rev)
            passed, summary, seconds = run_tests(dest, m.tests)
            if not passed:
                rows.append((m, shlex.join(m.tests), "-", f"not run: the tests fail unmutated ({summary})"))
                print(f"{m.name}: tests fail without the mutation: {summary}", flush=True)
                continue
            file = apply(m, dest)
            if file is None:
                rows.append((m, shlex.join(m.tests), "-", "not applied: the mutated text is not in the source"))
                print(f"{m.name}: not applied", flush=True)
                continue
            passed, summary, seconds = run_tests(dest, m.tests)
            caught = "no" if passed else "yes"
            rows.append((m, shlex.join(m.tests), file, f"{caught} ({summary}, {seconds:.0f} s)"))
            print(f"{m.name}: caught {caught}: {summary}", flush=True)
    lines = ["| mutation | change | file | tests | caught |", "|---|---|---|---|---|"]
    lines += [f"| {m.name} | {m.what} | {file} | `{tests}` | {caught} |" for m, tests, file, caught in rows]
    table = "\n".join(lines)
    print(table)
    if args.out:
        where = "the working tree" if rev is None else f"commit {rev}"
        head = (f"# Mutation check\n\nOutput of `python scripts/mutation_check.py --out {args.out}` on {where}: "
                "each mutation is one change to a copy of the package; the tests named are run on the copy (and "
                "first on the unchanged copy, where they must pass).  *caught* means the tests failed on the "
                "mutated copy.\n\n")
        args.out.write_text(head + table + "\n")
    return 0 if all(caught.startswith("yes") for *_, caught in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
