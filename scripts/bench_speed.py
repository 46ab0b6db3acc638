"""How fast `servofmu identify` is from process start to exit, where its time goes, how fast a training set is
made, and how many data files a fleet run identifies per second — the current servofmu against an earlier
revision (``--before``), measured in one run on the same files.

    python scripts/bench_speed.py [--demo DIR] [--before REV] [--previous REV] [--short-swarm N] [--out FILE.md]

``--demo DIR``: the output folder of `servofmu demo` (its g1/g2 data, networks and FMUs); made in a temporary
folder when not given.  The earlier revision is taken from git (``git archive``) and run from its sources with
the same interpreter and packages.  Both run with Python's bytecode cache on, as an installed package does.
``--previous REV``: a later revision whose `identify` is timed too (what the last changes gained).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TRUTH = {"g1": {"pole1": -10.0, "dc_gain": 1.0, "fc_pos": 0.5, "fc_neg": 0.4},
         "g2": {"pole1_re": -2.5, "pole1_im": 31.52, "pole2": -10.0, "dc_gain": 1.0, "fc_pos": 0.5, "fc_neg": 0.4}}

# Runs inside each version's own process: times every phase of one identification.
PHASES = r"""
import json, os, sys, time
if os.path.exists(sys.argv[4]):
    os.unlink(sys.argv[4])  # the output of the previous run (later revisions refuse to replace it)
t0 = time.perf_counter()
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.inputs import load_identification_inputs
from servofmu.identification.results import write_result
t1 = time.perf_counter()
data_file, structure, ann_file, out = sys.argv[1:5]
plant, data, ann, provenance = load_identification_inputs(data_file, structure, ann_file, "pso-ann")
t2 = time.perf_counter()
swarm = {}
if len(sys.argv) > 5:  # a shorter swarm (identify --iterations)
    from servofmu.identification.pso import PsoOptions
    swarm["pso"] = PsoOptions(iterations=int(sys.argv[5]))
est = PSOANNIdentifier(plant, ann=ann, **swarm).fit(data)
t3 = time.perf_counter()
write_result(out, est.result(provenance))
t4 = time.perf_counter()
stages = {s.name: s.seconds for s in est.stages_}
print(json.dumps({"imports": t1 - t0, "reading": t2 - t1,
                  "setup": (t3 - t2) - sum(stages.values()), **stages, "writing": t4 - t3,
                  "theta": dict(zip(est.names_, map(float, est.theta_)))}))
"""


class Version:
    """A servofmu to run: the working tree's (``root`` None) or an earlier revision's sources."""

    def __init__(self, label: str, root: Path | None):
        self.label, self.root = label, root

    def env(self) -> dict:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        if self.root is not None:
            env["PYTHONPATH"] = str(self.root)
        return env

    def run(self, *args, check=True, **kw) -> subprocess.CompletedProcess:
        proc = subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, env=self.env(),
                              cwd=self.root or ROOT, **kw)
        if check and proc.returncode != 0:
            sys.exit(f"{self.label}: {' '.join(map(str, args[:3]))} failed:\n{proc.stderr}")
        return proc

    def servofmu(self, *args, **kw) -> subprocess.CompletedProcess:
        return self.run("-m", "servofmu", *args, **kw)


def checkout(rev: str, folder: Path) -> Path:
    """The sources of ``rev`` in ``folder``, laid out as an installed package (examples as servofmu.fmu_models)."""
    folder.mkdir(parents=True)
    archive = folder / "src.tar"
    with open(archive, "wb") as fh:
        subprocess.run(["git", "-C", str(ROOT), "archive", rev, "servofmu", "fmu_models"], stdout=fh, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(folder, filter="data")
    shutil.move(str(folder / "fmu_models"), str(folder / "servofmu" / "fmu_models"))
    return folder


def worst_error(structure: str, theta: dict) -> float:
    return max(abs(theta[k] / v - 1) for k, v in TRUTH[structure].items())


def process_times(version: Version, demo: Path, structure: str, repeats: int, out: Path, *extra) -> list[float]:
    """Wall times of `servofmu identify` from process start to exit (the first run warms caches, not counted)."""
    args = ["identify", demo / f"{structure}.h5", "--structure", structure, "--ann", demo / f"{structure}-ann.h5",
            "--json", "-o", out, *extra]
    times = []
    for _ in range(repeats + 1):
        out.unlink(missing_ok=True)  # an existing output is refused (no --force before revision 0acfc33)
        t = time.perf_counter()
        version.servofmu(*args)
        times.append(time.perf_counter() - t)
    return times[1:]


def phase_times(version: Version, demo: Path, structure: str, repeats: int, out: Path, *iterations) -> dict:
    """Median time of each phase over ``repeats`` runs, and the last run's parameters (``iterations``: the
    swarm's, when not the paper's)."""
    runs = [json.loads(version.run("-c", PHASES, demo / f"{structure}.h5", structure, demo / f"{structure}-ann.h5",
                                   out, *iterations).stdout) for _ in range(repeats)]
    phases = {k: statistics.median(r[k] for r in runs) for k in runs[0] if k != "theta"}
    return {**phases, "theta": runs[-1]["theta"]}


def training_set_time(version: Version, demo: Path, structure: str, samples: int, out: Path) -> float:
    out.unlink(missing_ok=True)
    t = time.perf_counter()
    version.servofmu("dataset", structure, "--like", demo / f"{structure}.h5", "--samples", samples, "--seed", 0,
                     "-o", out)
    return time.perf_counter() - t


def fleet_files(version: Version, demo: Path, folder: Path, count: int) -> list[Path]:
    """``count`` g1 axes: measurements of the demo's g1 FMU at 40 dB output SNR, one noise seed each."""
    folder.mkdir(exist_ok=True)
    files = []
    for seed in range(count):
        path = folder / f"axis{seed:02d}.h5"
        if not path.exists():
            version.servofmu("measure", demo / "g1.fmu", "--amplitudes", "2.0,0.6", "--frequencies",
                             "0.5,1,2,5,10,20", "--noise-snr", 40, "--seed", seed, "--workers", 0, "-o", path)
        files.append(path)
    return files


def fleet_run(version: Version, demo: Path, files: list[Path], out: Path, *extra) -> tuple[float, list[dict]]:
    out.mkdir(exist_ok=True)
    t = time.perf_counter()
    proc = version.servofmu("identify", *files, "--structure", "g1", "--ann", demo / "g1-ann.h5", "--output-dir",
                            out, "--json", *extra)
    return time.perf_counter() - t, json.loads(proc.stdout)


def parameters(outcomes: list[dict]) -> dict:
    return {Path(o["data_file"]).name: o["parameters"] for o in outcomes}


def interrupted_fleet(version: Version, demo: Path, files: list[Path], out: Path, after: int) -> dict:
    """Interrupt a fleet run (SIGINT) once ``after`` results are written, resume it, and say what was redone."""
    out.mkdir()
    args = [sys.executable, "-m", "servofmu", "identify", *map(str, files), "--structure", "g1", "--ann",
            str(demo / "g1-ann.h5"), "--output-dir", str(out), "--workers", "0"]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=version.env())
    while len(list(out.glob("*-result.h5"))) < after and proc.poll() is None:
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate()
    before = {p.name: p.read_bytes() for p in out.glob("*-result.h5")}
    _, outcomes = fleet_run(version, demo, files, out, "--resume", "--workers", "0")
    kept = {Path(o["result_file"]).name for o in outcomes if o["status"] == "kept"}
    redone = {Path(o["result_file"]).name for o in outcomes if o["status"] == "identified"}
    return {"exit": proc.returncode, "message": err.strip().splitlines()[-1] if err.strip() else "",
            "finished": len(before), "kept": kept == set(before) and all((out / n).read_bytes() == b
                                                                        for n, b in before.items()),
            "redone": len(redone), "outcomes": outcomes}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, help="output folder of `servofmu demo` (default: run the demo)")
    ap.add_argument("--before", default="54db52b", help="earlier revision to compare with (git)")
    ap.add_argument("--previous", help="a later revision whose identify is timed too (git)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--short-swarm", type=int, default=10, metavar="N",
                    help="also time the current identify with --iterations N (the paper's swarm runs 50)")
    ap.add_argument("--samples", type=int, default=10_000, help="plants in the training sets")
    ap.add_argument("--files", type=int, default=40, help="data files of the fleet run")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench-speed.md")
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="servofmu-bench-speed-"))
    try:
        now, before = Version("now", None), Version(f"before ({args.before})", checkout(args.before, tmp / "before"))
        versions = [before, now]
        if args.previous:
            versions.insert(1, Version(f"previous ({args.previous})", checkout(args.previous, tmp / "previous")))
        demo = args.demo
        if demo is None:
            demo = tmp / "demo"
            now.servofmu("demo", "-o", demo)
        lines = ["# Speed of identify, training sets and fleets\n",
                 f"Generated by `scripts/bench_speed.py` on {date.today()} ({platform.machine()}, "
                 f"{os.cpu_count()} cores, Python {platform.python_version()}; load average "
                 f"{os.getloadavg()[0]:.2f} at the start). \"before\" is revision {args.before}, run from its "
                 "sources with the same interpreter and packages"
                 + (f" (\"previous\", revision {args.previous}, likewise)" if args.previous else "")
                 + "; all with the bytecode cache on and their "
                 "compiled libraries cached (one warm-up run first). Data: `servofmu demo`'s noise-free g1 and "
                 "g2 measurements and networks.\n"]

        short = f"now, `--iterations {args.short_swarm}`"
        lines += ["## `servofmu identify` from process start to exit\n",
                  f"Best and median of {args.repeats} runs of `servofmu identify DATA --structure S --ann ANN "
                  "--json -o RESULT.h5`; worst relative error of the identified parameters against the truth. "
                  f"The last row per structure: the swarm cut from the paper's 50 iterations to {args.short_swarm} "
                  "(what that costs in accuracy over random plants and noise: bench-swarm-budget.md).\n",
                  "| structure | version | best [s] | median [s] | worst relative error |", "|---|---|---|---|---|"]
        phases = {}
        for structure in ("g1", "g2"):
            for version in versions:
                times = process_times(version, demo, structure, args.repeats, tmp / f"{structure}-r.h5")
                phases[structure, version.label] = p = phase_times(version, demo, structure, args.repeats,
                                                                   tmp / f"{structure}-p.h5")
                lines.append(f"| {structure} | {version.label} | {min(times):.3f} | {statistics.median(times):.3f} "
                             f"| {worst_error(structure, p['theta']):.2e} |")
            times = process_times(now, demo, structure, args.repeats, tmp / f"{structure}-r.h5", "--iterations",
                                  args.short_swarm)
            phases[structure, short] = p = phase_times(now, demo, structure, args.repeats, tmp / f"{structure}-p.h5",
                                                       args.short_swarm)
            lines.append(f"| {structure} | {short} | {min(times):.3f} | {statistics.median(times):.3f} "
                         f"| {worst_error(structure, p['theta']):.2e} |")
        lines += ["", "### Where the time goes\n",
                  f"Median over {args.repeats} runs of a script doing what `identify` does, phase by phase (s): "
                  "imports of what identify uses; reading the data and network; setup (criterion, compiled library "
                  "loaded from the cache); the three stages; writing the result. The interpreter's own start is the "
                  "rest of the process time.\n"]
        keys = ["imports", "reading", "setup", "ann", "pso", "polish", "writing"]
        lines += ["| structure | version | " + " | ".join(keys) + " | sum |", "|---" * (len(keys) + 3) + "|"]
        for (structure, label), p in phases.items():
            lines.append(f"| {structure} | {label} | " + " | ".join(f"{p[k]:.3f}" for k in keys)
                         + f" | {sum(p[k] for k in keys):.3f} |")

        lines += ["", f"## Training sets of {args.samples} plants\n",
                  "`servofmu dataset S --like DATA --samples N --seed 0` on the machine's cores, one run each "
                  "(compiled library cached).\n",
                  "| structure | before [s] | now [s] | ratio |", "|---|---|---|---|"]
        for structure in ("g1", "g2"):
            t_before = training_set_time(before, demo, structure, args.samples, tmp / "ts.h5")
            t_now = training_set_time(now, demo, structure, args.samples, tmp / "ts.h5")
            lines.append(f"| {structure} | {t_before:.1f} | {t_now:.1f} | {t_before / t_now:.2f}× |")

        files = fleet_files(now, demo, tmp / "fleet", args.files)
        t_one, one = fleet_run(now, demo, files, tmp / "one", "--workers", "0")
        t_local, local = fleet_run(now, demo, files, tmp / "local", "--workers", "2")
        from distributed import LocalCluster  # noqa: E402 (only this section needs it)

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster:
            t_dask, dask = fleet_run(now, demo, files, tmp / "dask", "--scheduler", cluster.scheduler_address)
        same = parameters(one) == parameters(local) == parameters(dask)
        n = len(files)
        lines += ["", f"## A fleet: {n} data files in one call\n",
                  f"`servofmu identify A.h5 B.h5 ... --output-dir DIR`: {n} g1 axes measured from the demo's g1 FMU "
                  "at 40 dB output SNR (one noise seed each). Process wall time of the whole call. In one process "
                  "each fit already runs its simulations on all cores (threads in the batch simulator); a worker "
                  "runs one thread, so on this machine the workers gain only what the single process loses "
                  "between its threaded calls.\n",
                  "| where | wall time [s] | files per second | throughput vs one process |", "|---|---|---|---|"]
        for label, t in (("one process (`--workers 0`)", t_one), ("2 local worker processes", t_local),
                         ("Dask LocalCluster, 2 workers", t_dask)):
            lines.append(f"| {label} | {t:.1f} | {n / t:.2f} | {t_one / t:.2f}× |")
        lines.append(f"\nIdentified parameters identical in the three runs: {'yes' if same else 'NO'}.")

        resumed = interrupted_fleet(now, demo, files, tmp / "resumed", after=max(n // 4, 1))
        again = parameters(resumed["outcomes"]) == parameters(one)
        lines += ["", "### Interrupted and resumed\n",
                  f"The one-process run interrupted (SIGINT) after {resumed['finished']} results were written "
                  f"(exit {resumed['exit']}: `{resumed['message']}`), then started again with `--resume`: "
                  f"{resumed['redone']} files identified, the {resumed['finished']} finished results "
                  f"{'kept unchanged' if resumed['kept'] else 'NOT kept'}; all parameters identical to the "
                  f"uninterrupted run: {'yes' if again else 'NO'}."]
        args.out.write_text("\n".join(lines) + "\n")
        print(f"wrote {args.out}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
