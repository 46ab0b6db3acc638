"""Selection on stepped-sine data: `select` over the default candidates on the default measurement of shipped plants.

Per plant (g1, lugre_servo, stribeck_servo): its FMU measured with `measure`'s default plan (2 magnitudes × its
default frequencies) noise-free and at 40 dB (velocity noise, seed 1), validated on a third measurement at 40 dB
(seed 2); `select` of each, timed (wall and the CPU seconds of its processes).  With ``--before DIR`` (a checkout of
another revision) the same selections run with that revision's servofmu too, one after the other on the same files:
the ratio of the times is measured in one run.

Usage: python scripts/bench_select_sines.py [--plants g1,lugre_servo,stribeck_servo] [--before DIR]
       [--out docs/bench-select-sines.md]
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def servofmu(checkout: Path, *argv) -> subprocess.CompletedProcess:
    """A command of the servofmu in ``checkout`` (its sources first on the path)."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    # run outside any checkout: `python -m` puts the working folder first on the path
    return subprocess.run([sys.executable, "-m", "servofmu", *map(str, argv)], capture_output=True, text=True,
                          env=env, check=False, cwd=tempfile.gettempdir())


def timed_select(checkout: Path, data: Path, validation: Path, out: Path) -> tuple[str, float, float]:
    """(chosen structure, wall seconds, CPU seconds of the selection's processes)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = servofmu(checkout, "select", data, "--validate", validation, "-o", out, "--force")
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"select failed: {proc.stderr.strip()}")
    chosen = next(line.split(":", 1)[1].strip() for line in proc.stdout.splitlines() if line.startswith("chosen:"))
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return chosen, wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", default="g1,lugre_servo,stribeck_servo")
    ap.add_argument("--before", type=Path, help="a checkout of the revision to compare with")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench-select-sines.md")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-select-sines-") as tmp:
        tmp = Path(tmp)
        for plant in args.plants.split(","):
            fmu = tmp / f"{plant}.fmu"
            for argv in (("build", plant, "-o", fmu),
                         ("measure", fmu, "-o", tmp / f"{plant}-clean.h5"),
                         ("measure", fmu, "--noise-snr", 40, "--seed", 1, "-o", tmp / f"{plant}-40dB.h5"),
                         ("measure", fmu, "--noise-snr", 40, "--seed", 2, "-o", tmp / f"{plant}-val.h5")):
                proc = servofmu(ROOT, *argv)
                if proc.returncode != 0:
                    raise SystemExit(proc.stderr)
            for kind in ("clean", "40dB"):
                data = tmp / f"{plant}-{kind}.h5"
                load = os.getloadavg()[0]
                new = timed_select(ROOT, data, tmp / f"{plant}-val.h5", tmp / "new.h5")
                old = timed_select(args.before, data, tmp / f"{plant}-val.h5", tmp / "old.h5") \
                    if args.before else None
                rows.append((plant, kind, load, new, old))
                print(plant, kind, new, old, flush=True)
    write_doc(args, rows)


def write_doc(args, rows) -> None:
    lines = ["# Selection on stepped-sine data", "",
             f"Made by `python scripts/bench_select_sines.py{' --before REV' if args.before else ''}` on "
             f"{os.cpu_count()} cores: `select` over the default candidates on the default measurement of each plant "
             "(`measure`'s plan), noise-free and at 40 dB (velocity noise, seed 1), validated on a measurement at "
             "40 dB (seed 2). Wall and CPU seconds (the selection's processes); the load average at each start "
             "(other work on the machine stretches the wall time, far less the CPU time).", ""]
    head = "| plant | data | load | chosen | wall (s) | CPU (s) |"
    rule = "|---|---|---|---|---|---|"
    if args.before:
        head += " chosen before | wall before (s) | CPU before (s) | CPU after/before |"
        rule += "---|---|---|---|"
    lines += [head, rule]
    for plant, kind, load, new, old in rows:
        line = f"| {plant} | {kind} | {load:.1f} | {new[0]} | {new[1]:.1f} | {new[2]:.1f} |"
        if old:
            line += f" {old[0]} | {old[1]:.1f} | {old[2]:.1f} | × {new[2] / old[2]:.2f} |"
        lines.append(line)
    args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
