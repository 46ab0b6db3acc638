"""What a default install costs, before and after a change of the dependencies; writes docs/install.md.

For each revision (git commits of this repository; default: the last one before dask and python-control became
extras, and HEAD) the wheel is built from the commit's tree and installed with no extras in a fresh virtual
environment, torch's CPU build first (``pip install torch==2.13.0``, as scripts/setup.sh does).  Measured there, in an
empty folder outside the checkout:

- the size of the environment's site-packages, torch's share and the number of distributions installed;
- ``servofmu --help``: wall time, median of --repeat runs (the first, which fills the bytecode caches, not counted);
- ``python -c "import servofmu"`` and ``python -c "import servofmu.cli"``: the same;
- which of torch, dask, python-control, libcosimpy ``servofmu identify --help`` loads.

Usage: python scripts/bench_install.py [--before REV] [--after REV] [--repeat N] [--out docs/install.md]
(needs git, network access to the package index; about 2 minutes per revision).
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BEFORE = "86a3a59"  # the last commit with dask[distributed] and control among the dependencies
TORCH = "torch==2.13.0"
HEAVY = ("torch", "dask", "distributed", "control", "libcosimpy")


def run(*args, cwd=None, env=None, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(a) for a in args], cwd=cwd, env=env, check=True, capture_output=True, text=True, **kw)


def timed(argv, cwd, env, repeat: int) -> float:
    """Median wall time of ``argv`` in seconds (after one unmeasured run)."""
    run(*argv, cwd=cwd, env=env)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run(*argv, cwd=cwd, env=env)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def folder_size(path: Path) -> int:
    return sum(p.lstat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def measure_revision(rev: str, work: Path, repeat: int) -> dict:
    commit = run("git", "rev-parse", "--short", rev, cwd=ROOT).stdout.strip()
    src = work / f"src-{commit}"
    src.mkdir()
    archive = subprocess.run(["git", "archive", commit], cwd=ROOT, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    env_dir = work / f"venv-{commit}"
    venv.create(env_dir, with_pip=True)
    py = env_dir / "bin" / "python"
    run(py, "-m", "pip", "install", "--quiet", "--upgrade", "pip")
    run(py, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", work / f"dist-{commit}", src)
    (wheel,) = (work / f"dist-{commit}").glob("servofmu-*.whl")
    start = time.perf_counter()
    run(py, "-m", "pip", "install", "--quiet", TORCH)
    run(py, "-m", "pip", "install", "--quiet", wheel)
    install_seconds = time.perf_counter() - start
    site = Path(run(py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])").stdout.strip())
    dists = run(py, "-m", "pip", "list", "--format=freeze").stdout.split()
    here = work / f"run-{commit}"
    here.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    servofmu = env_dir / "bin" / "servofmu"
    imports = run(py, "-X", "importtime", "-m", "servofmu", "identify", "--help", cwd=here, env=env).stderr
    loaded = [m for m in HEAVY if any(line.rstrip().endswith(f"| {m}") for line in imports.splitlines())]
    installed = [m for m in HEAVY
                 if run(py, "-c", f"import importlib.util as u; print(u.find_spec('{m}') is not None)").stdout.strip()
                 == "True"]
    largest = sorted(((folder_size(d) if d.is_dir() else d.stat().st_size), d.name) for d in site.iterdir()
                     if not d.name.endswith((".dist-info", ".pth")) and d.name != "__pycache__")[::-1][:8]
    return {"rev": commit, "largest": largest, "load": os.getloadavg()[0],
            "subject": run("git", "log", "-1", "--format=%s", commit, cwd=ROOT).stdout.strip(),
            "site_bytes": folder_size(site), "torch_bytes": folder_size(site / "torch"),
            "distributions": len(dists), "install_seconds": install_seconds,
            "help": timed([servofmu, "--help"], here, env, repeat),
            "import": timed([py, "-c", "import servofmu"], here, env, repeat),
            "import_cli": timed([py, "-c", "import servofmu.cli"], here, env, repeat),
            "python": timed([py, "-c", "pass"], here, env, repeat),
            "installed": installed, "loaded": loaded}


BROUGHT_BY = {"cmake": "FMPy's", "sympy": "torch's", "networkx": "torch's", "scipy.libs": "scipy's",
              "numpy.libs": "numpy's"}  # folders that are another distribution's dependency


def short(text: str, width: int = 90) -> str:
    return text if len(text) <= width else text[:width].rsplit(" ", 1)[0] + " …"


def mb(n: int) -> str:
    return f"{n / 1e6:,.0f} MB"


def ms(s: float) -> str:
    return f"{s * 1e3:.0f} ms"


def report(before: dict, after: dict, repeat: int) -> str:
    rows = [("site-packages of a default install", mb(before["site_bytes"]), mb(after["site_bytes"])),
            ("of which torch (CPU build)", mb(before["torch_bytes"]), mb(after["torch_bytes"])),
            ("without torch", mb(before["site_bytes"] - before["torch_bytes"]),
             mb(after["site_bytes"] - after["torch_bytes"])),
            ("distributions installed", str(before["distributions"]), str(after["distributions"])),
            ("of torch, dask, distributed, control, libcosimpy installed", ", ".join(before["installed"]) or "none",
             ", ".join(after["installed"]) or "none"),
            ("`pip install` (torch, then the wheel; local package cache)", f"{before['install_seconds']:.0f} s",
             f"{after['install_seconds']:.0f} s"),
            ("`servofmu --help`", ms(before["help"]), ms(after["help"])),
            ('`python -c "import servofmu"`', ms(before["import"]), ms(after["import"])),
            ('`python -c "import servofmu.cli"`', ms(before["import_cli"]), ms(after["import_cli"])),
            ('`python -c "pass"` (the interpreter alone)', ms(before["python"]), ms(after["python"])),
            ("loaded by `servofmu identify --help`", ", ".join(before["loaded"]) or "none of them",
             ", ".join(after["loaded"]) or "none of them")]
    table = ["| | before | after |", "|---|---|---|"] + [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return "\n".join([
        "# Installing servofmu",
        "",
        "## pip install",
        "",
        "servofmu needs Python ≥ 3.11 and a C compiler (`cc`, `gcc` or `clang`: FMUs and the identifier's simulator",
        "are compiled on first use).  torch comes first, as its CPU build: pip's default torch for Linux brings",
        "several GB of CUDA libraries that servofmu never uses.",
        "",
        "```console",
        "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu",
        "pip install servofmu                 # from a checkout: pip install .",
        "servofmu demo",
        "```",
        "",
        "The default install runs every command.  Two extras add what only some users need:",
        "",
        "| extra | brings | for |",
        "|---|---|---|",
        "| `servofmu[dask]` | dask, distributed | `--scheduler tcp://HOST:PORT`: measurement, training sets and "
        "fleets on a Dask cluster |",
        "| `servofmu[control]` | python-control | `servofmu.output.export.load_control`: exported models as "
        "python-control systems |",
        "| `servofmu[all]` | both | |",
        "",
        "A feature whose extra is missing says so in one line, e.g. `a Dask scheduler needs dask: pip install "
        "'servofmu[dask]'`.",
        "libcosimpy, the default co-simulation engine, is a dependency where it has wheels (Linux x86_64 with "
        "glibc ≥ 2.28, Windows; Python < 3.15); elsewhere `servofmu cosim` and the demo's closed loop run on FMPy",
        "and say so in one warning line.",
        "",
        "scripts/setup.sh (behind the README's two commands) installs the checkout in `.venv` with the extra `[test]`,",
        "which includes both extras and the test tools.  CI also installs the wheel as a user does, in a fresh virtual",
        "environment with no extras, and runs `servofmu demo` and the README's tour there "
        "(`scripts/check_install.sh`).",
        "",
        "## What it costs",
        "",
        f"Generated by `python scripts/bench_install.py` on {platform.machine()}, Python "
        f"{platform.python_version()}: each revision's wheel installed with no extras in a fresh virtual environment "
        f"(`pip install {TORCH}` first), times the median of {repeat} runs in an empty folder.",
        "",
        f"- before: {before['rev']} ({short(before['subject'])})",
        f"- after: {after['rev']} ({short(after['subject'])})",
        "",
        *table,
        "",
        f"The largest parts of the default install (after): "
        + ", ".join(f"{name} {mb(size)}" + (f" ({BROUGHT_BY[name]})" if name in BROUGHT_BY else "")
                    for size, name in after["largest"])
        + ".  Load average (1 min) when timed: "
        f"{before['load']:.1f} before, {after['load']:.1f} after, on {os.cpu_count()} cores shared with other work: "
        "the times are indicative.",
        "",
        "`import servofmu` loads no dependency (the public names load on first use) and the command line parses its",
        "options before it imports what a command needs; torch is imported only by the code that trains or loads",
        "networks (servofmu.identification.ann: `train`, `identify --ann`, the demo).  tests/test_install.py checks",
        "that `servofmu --help` and `identify`, `validate`, `report`, `export` and `cosim --help` load none of torch,",
        "dask, python-control, libcosimpy.",
        "",
    ])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default=BEFORE)
    parser.add_argument("--after", default="HEAD")
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--out", default=str(ROOT / "docs" / "install.md"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="servofmu-bench-install-") as tmp:
        results = []
        for rev in (args.before, args.after):
            print(f"{rev}: building, installing, timing ...", file=sys.stderr, flush=True)
            results.append(measure_revision(rev, Path(tmp), args.repeat))
            print(results[-1], file=sys.stderr, flush=True)
    Path(args.out).write_text(report(*results, args.repeat))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
