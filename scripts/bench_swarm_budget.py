"""What the swarm's budget buys: PSO-ANN with the paper's 50 iterations against shorter swarms, down to none (the
polish straight from the network's estimate and the nine random first particles), and with the search's
simulations at a looser tolerance, on the same data.

    python scripts/bench_swarm_budget.py [--demo DIR] [--random 50] [--noise-seeds 10] [--out FILE.md]

``--demo DIR``: the output folder of `servofmu demo` (its g1/g2 FMUs and networks); made in a temporary folder when
not given.  ``--plants``: g1 and g2 use the demo's files; another example plant (stribeck_servo, ...) is built,
measured under g1's plan and given a network of its own in the run.  Data: noise-free features of plants drawn
from the training prior (seed 20261121, as scripts/bench_identify.py) and from a wider one, all settling in every
experiment, and measurements of each plant's FMU at 40 dB output SNR.  Per budget: how many random plants are
identified within 1e-3, the worst relative error, the 95 % intervals' coverage on the noisy data and the median
time of a fit, all in one run.
"""
from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np

from bench_identify import settled_plants  # scripts/: the same random plants as the identifier's benchmark

from servofmu.fmu import build_fmu
from servofmu.identification.ann import load_ann
from servofmu.identification.criterion import SEARCH_RTOL, sine_data
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import identified_mask
from servofmu.identification.pso import PsoOptions
from servofmu.identification.train import train_from_file
from servofmu.identification.training_set import make_training_set
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.measure import MeasureOptions, measure
from servofmu.model.plant import load_plant
from servofmu.runtime import RunOptions

ROOT = Path(__file__).resolve().parent.parent
# (swarm iterations, search tolerance); the first is identify's default: the paper's 50 (Table I) at SEARCH_RTOL
VARIANTS = ((50, SEARCH_RTOL), (30, SEARCH_RTOL), (20, SEARCH_RTOL), (10, SEARCH_RTOL), (0, SEARCH_RTOL),
            (50, 1e-4), (10, 1e-4))


def inputs(name: str, demo: Path, work: Path) -> tuple[Path, Path, Path]:
    """The FMU, noise-free measurement and network of ``name``: the demo's, or for another example plant built here
    as the demo builds g1's (its plan, a 10 000-plant training set, a network)."""
    if (demo / f"{name}-ann.h5").exists():
        return demo / f"{name}.fmu", demo / f"{name}.h5", demo / f"{name}-ann.h5"
    plant = load_plant(name)
    fmu, data, ds, ann = (work / f"{name}{suffix}" for suffix in (".fmu", ".h5", "-ds.h5", "-ann.h5"))
    build_fmu(plant, fmu)
    plan = read_data_file(demo / "g1.h5").plan
    measure(fmu, data, amplitudes=list(plan.amplitudes), frequencies=list(plan.frequencies), run=RunOptions(workers=0))
    make_training_set(plant, sine_data(read_data_file(data)), 10_000, ds, seed=0)
    train_from_file(ds, ann, seed=0)
    return fmu, data, ann


def run(name: str, demo: Path, work: Path, n_random: int, noise_seeds: int, lines: list) -> None:
    plant = load_plant(name)
    truth = plant.parameter_vector()[identified_mask(plant)]
    fmu, data_file, ann_file = inputs(name, demo, work)
    ann = load_ann(ann_file)
    measured = read_data_file(data_file)
    data = sine_data(measured)
    amps, freqs = list(measured.plan.amplitudes), list(measured.plan.frequencies)
    noisy = []
    for seed in range(1, noise_seeds + 1):
        path = work / f"{name}-noise{seed}.h5"
        measure(fmu, path, amplitudes=amps, frequencies=freqs, run=RunOptions(workers=0),
                options=MeasureOptions(noise_snr_db=40.0, seed=seed))
        noisy.append(sine_data(read_data_file(path)))
    sets = {label: settled_plants(plant, data, n_random, spread)[0]
            for label, spread in (("prior", 0.5), ("wider", 0.8))}
    PSOANNIdentifier(plant, ann=ann).fit(data)  # warm-up: the batch library loaded once

    lines += [f"## {name}", "",
              f"Noise-free data of {n_random} random plants from the training prior (spread 0.5) and {n_random} from a "
              f"wider one (spread 0.8: many outside the network's training range); {noise_seeds} measurements of the "
              f"{name} FMU at 40 dB ({', '.join(map(str, amps))} N × {', '.join(map(str, freqs))} Hz).", "",
              "| swarm iterations | search tolerance | model evaluations (median) | prior: within 1e-3 | "
              "prior: worst error | wider: within 1e-3 | wider: worst error | 40 dB: worst error | "
              "40 dB: 95 % coverage | median fit [s] | time vs default |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    base = None
    for iterations, rtol in VARIANTS:
        def fit(d, iterations=iterations, rtol=rtol):
            return PSOANNIdentifier(plant, ann=ann, pso=PsoOptions(iterations=iterations), search_rtol=rtol).fit(d)

        times, evaluations, worst = [], [], {k: [] for k in sets}
        for label, plants in sets.items():
            for d, th in plants:
                e = fit(d)
                times.append(e.seconds_)
                evaluations.append(e.evaluations_)
                worst[label].append(float(np.max(np.abs(e.theta_ / th - 1))))
        noisy_worst, covered = [], 0
        for d in noisy:
            e = fit(d)
            noisy_worst.append(float(np.max(np.abs(e.theta_ / truth - 1))))
            lo, hi = e.intervals_.T
            covered += int(np.sum((lo <= truth) & (truth <= hi)))
        median = statistics.median(times)
        base = base or median
        random = " | ".join(f"{sum(w < 1e-3 for w in ws)} of {len(ws)} | {max(ws):.2e}" for ws in worst.values())
        default = (iterations, rtol) == VARIANTS[0]
        lines.append(f"| {iterations}{' (default)' if default else ''} | {rtol:g} "
                     f"| {statistics.median(evaluations):.0f} | {random} | {max(noisy_worst):.2e} | "
                     f"{100 * covered / (truth.size * len(noisy)):.1f} % | {median:.3f} | {median / base:.2f} |")
    lines.append("")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, help="output folder of `servofmu demo` (default: run the demo)")
    ap.add_argument("--random", type=int, default=50, help="random plants per structure")
    ap.add_argument("--noise-seeds", type=int, default=10)
    ap.add_argument("--plants", default="g1,g2,stribeck_servo")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench-swarm-budget.md")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        demo = args.demo
        if demo is None:
            demo = work / "demo"
            subprocess.run([sys.executable, "-m", "servofmu", "demo", "-o", str(demo)], check=True,
                           capture_output=True)
        lines = ["# What the swarm's budget and tolerance buy", "",
                 f"Generated by `scripts/bench_swarm_budget.py` on {date.today()} ({platform.machine()}, "
                 f"{platform.python_version()}). PSO-ANN as `identify` runs it (the demo's networks, seed 0), with "
                 "the swarm's iterations cut from the paper's 50 (inertia falling from 1 to 0 over whatever number is "
                 "given); 0 iterations: the ten first particles (the network's estimate and nine random points in "
                 "its box) and the polish. Search tolerance: the integrator's relative tolerance of the swarm's "
                 "simulations (the polish's stay at 1e-10). Times are of the fit alone, in this one process, in the "
                 "same run.", ""]
        for name in args.plants.split(","):
            t = time.perf_counter()
            run(name, demo, work, args.random, args.noise_seeds, lines)
            print(f"{name}: {time.perf_counter() - t:.0f} s", file=sys.stderr)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
