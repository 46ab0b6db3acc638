"""Benchmark and accuracy study of `servofmu measure`; writes docs/bench-measure.md.

1. Throughput: the same plan measured in this process, on 2 local worker processes and on a Dask
   LocalCluster with 2 worker processes (loopback); runs/s and the ratio to this process, measured in one
   run, and a check that all three give bit-identical first harmonics.
2. Accuracy of the stored first harmonics: every (solver tolerance, samples per period) against a run at
   tolerance 1e-14 with 32768 samples per period, for g1 and g2 at the paper's magnitudes; and g1 against an
   independent scipy Radau integration of the plant equations (tests/reference.py).

Usage: python scripts/bench_measure.py [--out docs/bench-measure.md]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from servofmu.fmu import build_fmu  # noqa: E402
from servofmu.measurement.excitation import ExperimentSpec, Plan  # noqa: E402
from servofmu.measurement.measure import Job, MeasureOptions, measure, run_experiment
from servofmu.model.plant import load_plant  # noqa: E402
from servofmu.simulation.fmu_runner import FmuRunnerFactory
from servofmu.simulation.parallel import WorkerResource, Workers  # noqa: E402
from servofmu.runtime import RunOptions  # noqa: E402

AMPLITUDES = (2.0, 0.6)
FREQUENCIES = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0)
SAMPLES = (1024, 2048, 4096, 8192)


def throughput(fmus: dict[str, Path], tmp: Path) -> list[str]:
    from distributed import LocalCluster

    plans = {"g1": (4.0, 2.0, 0.6), "g2": (2.0, 0.6)}
    rows = ["Plans: g1 with amplitudes 4, 2, 0.6 N and g2 with 2, 0.6 N, each x frequencies "
            f"{', '.join(f'{f:g}' for f in FREQUENCIES)} Hz, default options (g1's experiments are short; g2's "
            "include limit cycles that run to max_time = 60 s). Wall times include the start of the local worker "
            "processes (each extracts and instantiates the FMU once) but not the start of the Dask cluster.", "",
            "| plan | where | experiments | wall time [s] | runs/s | speed-up vs this process |",
            "|---|---|---|---|---|---|"]
    identical = True
    t0 = time.perf_counter()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      worker_dashboard_address=None) as cluster:
        t_start = time.perf_counter() - t0
        for name, amplitudes in plans.items():
            n = len(amplitudes) * len(FREQUENCIES)
            timings, results = {}, {}
            for label, where in (("this process", dict(run=RunOptions(workers=0))),
                                 ("2 local processes", dict(run=RunOptions(workers=2))),
                                 ("Dask LocalCluster, 2 workers",
                                  dict(run=RunOptions(scheduler=cluster.scheduler_address)))):
                t1 = time.perf_counter()
                data = measure(fmus[name], tmp / f"{name}-{len(timings)}.h5", amplitudes=amplitudes,
                               frequencies=FREQUENCIES, **where)
                timings[label] = time.perf_counter() - t1
                results[label] = [(e.H, e.dc) for e in data.experiments]
            identical &= all(r == results["this process"] for r in results.values())
            for label, dt in timings.items():
                rows.append(f"| {name} | {label} | {n} | {dt:.2f} | {n / dt:.2f} | {timings['this process'] / dt:.2f} |")
    rows += ["", f"Dask cluster start-up: {t_start:.1f} s. First harmonics and DC bit-identical wherever they ran: "
             f"{'yes' if identical else 'NO'}."]
    return rows


def accuracy(fmus: dict[str, Path]) -> list[str]:
    configs = [(tol, n) for tol in (1e-10, 1e-11, 1e-12) for n in SAMPLES]
    reference_options = MeasureOptions(tolerance=1e-14, samples_per_period=32768, max_time=20.0)
    rows = ["Relative error |H - H_ref| / |H_ref| of the stored first harmonic, max over the experiments that "
            "reached a steady state (listed below); H_ref from tolerance 1e-14 and 32768 samples per period.", ""]
    header = "| plant | tolerance | " + " | ".join(f"{n} samples/period" for n in SAMPLES) + " |"
    rows += [header, "|---|---|" + "---|" * len(SAMPLES)]
    notes = []
    with Workers(workers=2) as pool:
        for name, fmu in fmus.items():
            factory = FmuRunnerFactory(fmu.read_bytes(), fmu.name, "u", "v")
            resource = WorkerResource(f"bench:{name}", factory)
            specs = Plan(AMPLITUDES, FREQUENCIES).experiments
            ref = {i: r for i, r in pool.imap(run_experiment, [Job(s, reference_options) for s in specs], resource)}
            ok = [i for i in ref if ref[i].converged]
            notes.append(f"{name}: steady state reached at " + ", ".join(
                f"(m = {specs[i].amplitude:g}, f = {specs[i].frequency:g} Hz)" for i in sorted(ok)))
            errors = {}
            jobs = [(c, s) for c in configs for s in specs if s.index in ok]
            out = pool.imap(run_experiment, [Job(s, MeasureOptions(tolerance=c[0], samples_per_period=c[1],
                                                                   max_time=20.0)) for c, s in jobs], resource)
            for k, res in out:
                c, s = jobs[k]
                err = abs(res.H - ref[s.index].H) / abs(ref[s.index].H)
                errors[c] = max(errors.get(c, 0.0), err)
            for tol in (1e-10, 1e-11, 1e-12):
                rows.append(f"| {name} | {tol:g} | " + " | ".join(f"{errors[(tol, n)]:.1e}" for n in SAMPLES)
                            + " |")
    rows += [""] + [f"- {n}" for n in notes]
    return rows


def against_radau(fmu: Path) -> list[str]:
    from reference import simulate_reference

    runner = FmuRunnerFactory(fmu.read_bytes(), fmu.name, "u", "v")()
    rows = ["| m [N] | f [Hz] | relative difference of H | max abs difference of v over the window [m/s] |",
            "|---|---|---|---|"]
    for m, f in ((2.0, 1.0), (0.6, 1.0), (2.0, 5.0), (0.6, 5.0), (0.6, 20.0)):
        res = run_experiment(runner, Job(ExperimentSpec(0, m, f), MeasureOptions()))
        t = res.window.time
        v = simulate_reference([-10.0], [], 10.0, {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}, m, f,
                               np.concatenate([[0.0], t]), rtol=1e-12, atol=1e-14)[1:]
        w = np.full(t.size, t[1] - t[0])
        w[0] = w[-1] = (t[1] - t[0]) / 2
        s1 = 1j * 2 / (t[-1] - t[0]) * np.sum(w * v * np.exp(-2j * np.pi * f * t))
        rows.append(f"| {m:g} | {f:g} | {abs(res.H - s1 / m) / abs(s1 / m):.1e} | {np.max(np.abs(res.window.v - v)):.1e} |")
    runner.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "bench-measure.md"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fmus = {name: build_fmu(load_plant(name), tmp / f"{name}.fmu", fmi_version=3) for name in ("g1", "g2")}
        t0 = time.perf_counter()
        parts = ["# Measurement benchmark and accuracy", "",
                 f"Generated by `python scripts/bench_measure.py` on {platform.machine()} with "
                 f"{len(os.sched_getaffinity(0))} cores, Python {platform.python_version()}.", "",
                 "## Throughput: this process vs local processes vs Dask", ""]
        parts += throughput(fmus, tmp)
        parts += ["", "## Accuracy of the first harmonics", ""]
        parts += accuracy(fmus)
        parts += ["", "### g1 against an independent Radau integration (scipy, rtol 1e-12, atol 1e-14)", "",
                  "Default settings (tolerance 1e-12, 8192 samples per period); H_ref from the same trapezoid sum "
                  "over the Radau solution at the window's sample times.", ""]
        parts += against_radau(fmus["g1"])
        load = os.getloadavg()
        parts += ["", f"(whole script: {time.perf_counter() - t0:.0f} s; load average at the end "
                  f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} over 1 / 5 / 15 min: other work on the machine "
                  "shrinks the parallel speed-ups)", ""]
    text = "\n".join(parts)
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
