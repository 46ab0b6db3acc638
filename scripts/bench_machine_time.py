"""Machine time against accuracy: the default stepped-sine plan against broadband designs of several lengths, by the
Cramér–Rao bound and by the RMS error of identifications over noise seeds.

    python scripts/bench_machine_time.py STEPPED.h5:PLANT [STEPPED.h5:PLANT ...] [--seeds 20] [--workers 2]
                                         [--out docs/bench-machine-time.md]

STEPPED.h5: `servofmu measure PLANT.fmu` (the default plan, noise-free: each seed adds its own noise).  For each:

- stepped sine: its machine time counts every experiment's run to the end of its window, converged or not; its
  converged experiments are fitted (`identify --method pso`: the swarm and the polish, no network) after white noise
  is put on their window samples and the harmonics re-estimated, two ways:
  - "40 dB per window": σ at 40 dB of each window's velocity on each of its samples, as `measure --noise-snr 40`
    adds it (8192 samples a period: a 5 Hz window is sampled at 41 kHz);
  - "one sensor": the noise density of the broadband run's sensor (σ_bb at 1 kHz, σ_bb the default broadband
    plan's 40 dB): a window's harmonics then carry the noise of rate × window seconds samples of σ_bb, whatever its
    sampling;
- broadband: each design simulated from rest (servofmu.broadband.simulate, 40 dB of the run's velocity on every
  1 kHz sample) and identified as `identify` does it (servofmu.identification.broadband_identify: the
  frequency-domain G, the swarm on the records, the polish);
- per design: the bound √(I⁻¹)_kk at the truth (servofmu.identification.cramer_rao), the RMS relative error of
  the seeds' estimates per parameter, the worst parameter's, and the median fit's wall time.

The bound assumes the model's own noise (white, on the output) and a response smooth in the parameters; where the
response is chaotic (g2's limit cycle at its lower level) the bound is not a statement about any estimator.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import multiprocessing
import platform
import sys
import tempfile
import time
from dataclasses import replace
from datetime import date
from pathlib import Path

import numpy as np

from servofmu.broadband import BroadbandPlan
from servofmu.broadband.simulate import simulate_broadband, write_simulated
from servofmu.broadband.store import BroadbandData
from servofmu.identification.broadband_identify import broadband_records, identify_broadband
from servofmu.identification.cramer_rao import (cramer_rao_bound, sine_fisher_information,
                                                time_domain_fisher_information)
from servofmu.identification.criterion import RecordCriterion, sine_data
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.identification.run import IdentifyOptions
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.frf import harmonics
from servofmu.model.plant import load_plant
from servofmu.runtime import RunOptions
from servofmu.simulation.batch import BatchSimulator

SNR_DB = 40.0
DEFAULT = BroadbandPlan("multisine", (2.0, 0.6), (0.2, 50.0), 1000.0, period=5.0, periods=2, transient_periods=1,
                        realisations=4)
# designs by total machine time: the default, fewer realisations, a shorter period (lines 0.42 Hz apart), and the
# design of the search below with the lowest bound on stribeck_servo: one period from rest per level
DESIGNS = {"120 s (default)": DEFAULT, "60 s": replace(DEFAULT, realisations=2),
           "30 s": replace(DEFAULT, realisations=1),
           "14.4 s": replace(DEFAULT, realisations=1, period=2.4, band=(1 / 2.4, 50.0)),
           "9.6 s, one period": replace(DEFAULT, realisations=1, period=4.8, band=(1 / 4.8, 50.0), periods=1,
                                        transient_periods=0)}
# the search over designs of at most a quarter of the stepped sine's time: highest line, period, grid, levels and
# (transient, analysed) periods, one realisation
SEARCH = dict(f_max=(3.0, 5.0, 10.0, 50.0), period=(2.4, 3.6, 4.8), grid=("full", "odd-random"),
              levels=((2.0, 0.6), (2.0,), (0.6,)), periods=((0, 1), (1, 1)))


def truth_of(plant) -> np.ndarray:
    return plant.parameter_vector()[identified_mask(plant)]


def plan_seconds(plan: BroadbandPlan) -> float:
    return len(plan.levels) * plan.realisations * (plan.periods + plan.transient_periods) * plan.period


def broadband_sigma(plant, plan: BroadbandPlan) -> float:
    """The white noise (m/s) at SNR_DB of ``plan``'s whole noise-free run, as simulate_broadband adds it."""
    v = np.concatenate([lv.v.ravel() for lv in simulate_broadband(plant, plan)])
    return math.sqrt(float(np.var(v))) / 10 ** (SNR_DB / 20)


def window_sigmas(measured, sensor: float | None) -> dict:
    """Per converged experiment, σ on its window samples: 40 dB of its velocity, or the sensor's density
    (``sensor`` m/s on 1 kHz samples) at the window's own rate."""
    out = {}
    for e in measured.experiments:
        if e.converged:
            rate = e.samples_per_period * e.frequency
            out[e.index] = (math.sqrt(float(np.var(e.window.v))) / 10 ** (SNR_DB / 20) if sensor is None
                            else sensor * math.sqrt(rate / DEFAULT.rate))
    return out


def stepped_data(measured, sigma: dict, seed: int | None):
    """The converged experiments as fitted data: noise-free with the noise levels recorded (seed None), or with
    white noise σ on the window samples of seed ``seed`` and the harmonics re-estimated."""
    exps = []
    for e in (e for e in measured.experiments if e.converged):
        if seed is None:
            exps.append(replace(e, noise_sigma=sigma[e.index]))
            continue
        v = e.window.v + sigma[e.index] * np.random.default_rng([seed, e.index]).standard_normal(e.window.v.shape)
        h = harmonics(e.window.time, v, e.frequency, start=e.window_start, periods=e.window_periods, n_harmonics=1)
        exps.append(replace(e, noise_sigma=sigma[e.index], H_noisy=h.first / e.U1, dc_noisy=h.dc))
    return sine_data(replace(measured, experiments=tuple(exps)))


def stepped_bound(plant, measured, sigma: dict) -> np.ndarray:
    clean = stepped_data(measured, sigma, None)
    noise = np.array([sigma[e.index] * math.sqrt(2 / (e.samples_per_period * e.window_periods)) / abs(e.U1 * e.H)
                      for e in measured.experiments if e.converged])
    fisher, jac = sine_fisher_information(plant, replace(clean, noise=noise), truth_of(plant), threads=1)
    return cramer_rao_bound(fisher, jac)


def broadband_bound(plant, plan: BroadbandPlan) -> np.ndarray:
    levels = simulate_broadband(plant, plan)
    records = broadband_records(BroadbandData(path="simulated", plan=plan, levels=tuple(levels)))
    crit = RecordCriterion(plant, records, BatchSimulator(plant, threads=1))
    fisher, jac = time_domain_fisher_information(crit, truth_of(plant), [broadband_sigma(plant, plan)])
    return cramer_rao_bound(fisher, jac)


def fit_one(job: tuple) -> tuple:
    """One identification: (key, seed, estimate, wall seconds)."""
    key, name, what, seed = job
    plant = load_plant(name)
    t0 = time.perf_counter()
    if what[0] == "stepped":
        _, path, sigma = what
        est = PSOANNIdentifier(plant, method="pso", seed=0, threads=1).fit(stepped_data(read_data_file(path),
                                                                                       sigma, seed))
        theta = est.theta_
    else:
        with tempfile.TemporaryDirectory() as tmp:
            data = Path(tmp) / "bb.h5"
            write_simulated(data, plant, what[1], SNR_DB, seed)
            result = identify_broadband(data, name, Path(tmp) / "r.h5", IdentifyOptions(method="pso"),
                                        RunOptions(workers=0), "pso", threads=1)
        theta = result.theta
    return key, seed, np.asarray(theta, dtype=float), time.perf_counter() - t0


def cases(args) -> list[dict]:
    """Per STEPPED.h5:PLANT: the designs (stepped sine two ways, the broadband ones) with their times and bounds."""
    out = []
    for case in args.cases:
        path, name = case.rsplit(":", 1)
        plant, measured = load_plant(name), read_data_file(path)
        sensor = broadband_sigma(plant, DEFAULT)
        ss_seconds = sum(float(e.window.time[-1]) for e in measured.experiments)
        steady = sum(e.converged for e in measured.experiments)
        designs = []
        for label, sensor_sigma in (("40 dB per window", None), ("one sensor", sensor)):
            sigma = window_sigmas(measured, sensor_sigma)
            designs.append(dict(label=f"stepped sine, {label}", seconds=ss_seconds, what=("stepped", path, sigma),
                                bound=stepped_bound(plant, measured, sigma)))
        for label, plan in DESIGNS.items():
            designs.append(dict(label=f"broadband {label}", seconds=plan_seconds(plan), what=("broadband", plan),
                                bound=broadband_bound(plant, plan)))
        out.append(dict(name=name, plant=plant, ss_seconds=ss_seconds, steady=steady,
                        total=len(measured.experiments), sensor=sensor, designs=designs,
                        search=design_search(plant, ss_seconds, designs[0]["bound"], designs[1]["bound"])))
    return out


def design_search(plant, ss_seconds: float, ss_window: np.ndarray, ss_sensor: np.ndarray) -> list[tuple]:
    """Every design of SEARCH at most a quarter of the stepped sine's time, by the time it would need (× periods)
    to reach the stepped sine's bound on its worst parameter, as a share of the stepped sine's time (one sensor,
    40 dB per window): [(share one sensor, share per window, worst parameter, plan)], best first."""
    names, rows = identified_names(plant), []
    for f_max, period, grid, levels, (t, p) in itertools.product(*SEARCH.values()):
        plan = replace(DEFAULT, band=(1 / period, f_max), period=period, grid=grid, levels=levels,
                       transient_periods=t, periods=p, realisations=1)
        if plan_seconds(plan) > ss_seconds / 4:
            continue
        bound = broadband_bound(plant, plan)
        need = [plan_seconds(plan) * (bound / ss) ** 2 / ss_seconds for ss in (ss_sensor, ss_window)]
        rows.append((float(np.max(need[0])), float(np.max(need[1])), names[int(np.argmax(need[0]))], plan))
    return sorted(rows, key=lambda r: r[0])


def table(case: dict, fits: dict) -> list[str]:
    names, truth = identified_names(case["plant"]), truth_of(case["plant"])
    lines = [f"## {case['name']}", "", f"Stepped sine: {case['ss_seconds']:.0f} s of machine time, {case['steady']} of "
             f"{case['total']} experiments at steady state (fitted: those). Broadband σ = {case['sensor']:.3g} m/s on "
             "every 1 kHz sample of the default plan.", "",
             "| design | machine time | share of the stepped sine's | worst RMS error (relative) | its parameter | "
             "worst bound (relative) | the same for 1 s of the design (× √time) | worst RMS / its bound | median fit |",
             "|---|---|---|---|---|---|---|---|---|"]
    per_param = []
    for i, d in enumerate(case["designs"]):
        got = fits.get((case["name"], i), [])
        est = np.array([g[2] for g in got]) if got else np.full((0, truth.size), np.nan)
        rms = np.sqrt(np.mean((est - truth) ** 2, axis=0)) / np.abs(truth) if got else np.full(truth.size, np.nan)
        rel_bound = d["bound"] / np.abs(truth)
        k = int(np.nanargmax(rms)) if got else int(np.argmax(rel_bound))
        wall = np.median([g[3] for g in got]) if got else math.nan
        lines.append(f"| {d['label']} | {d['seconds']:.1f} s | {d['seconds'] / case['ss_seconds']:.2f} | "
                     f"{rms[k]:.3g} ({len(got)} seeds) | {names[k]} | {np.max(rel_bound):.3g} | "
                     f"{np.max(rel_bound) * math.sqrt(d['seconds']):.3g} | "
                     f"{rms[k] / rel_bound[k]:.2f} | {wall:.1f} s |")
        per_param.append((d["label"], rms, rel_bound))
    lines += ["", "Per parameter, RMS relative error over the seeds / relative bound:", "",
              "| design | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for label, rms, rel_bound in per_param:
        lines.append(f"| {label} | " + " | ".join(f"{r:.3g} / {b:.3g}" for r, b in zip(rms, rel_bound)) + " |")
    lines += ["", f"The search ({len(case['search'])} designs of at most a quarter of the stepped sine's time, one "
              "realisation: highest line × period × grid × levels × (transient, analysed) periods, "
              f"{dict((k, v) for k, v in SEARCH.items())}), the five closest to the goal: the time each would need "
              "(more periods of it) to reach the stepped sine's bound on its worst parameter, as a share of the "
              "stepped sine's time (the goal: ≤ 0.25)", "",
              "| band (Hz) | period | grid | levels (N RMS) | transient + analysed periods | machine time | needs, one "
              "sensor | its worst parameter | needs, 40 dB per window |", "|---|---|---|---|---|---|---|---|---|"]
    for one, window, worst, plan in case["search"][:5]:
        lines.append(f"| {plan.band[0]:.3g}–{plan.band[1]:g} | {plan.period:g} s | {plan.grid} | "
                     f"{', '.join(f'{x:g}' for x in plan.levels)} | {plan.transient_periods} + {plan.periods} | "
                     f"{plan_seconds(plan):.1f} s | {one:.2f} | {worst} | {window:.2f} |")
    return lines + [""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="+", help="STEPPED.h5:PLANT")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--json", type=Path, help="every fit's estimate, one JSON object per line")
    args = parser.parse_args()
    started = time.perf_counter()
    all_cases = cases(args)
    jobs = [((c["name"], i), c["name"], d["what"], seed) for c in all_cases for i, d in enumerate(c["designs"])
            for seed in range(args.seeds)]
    fits: dict = {}
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        for n, (key, seed, theta, wall) in enumerate(pool.imap_unordered(fit_one, jobs), 1):
            fits.setdefault(key, []).append((key, seed, theta, wall))
            if args.json:
                with args.json.open("a") as f:
                    f.write(json.dumps({"plant": key[0], "design": key[1], "seed": seed, "theta": theta.tolist(),
                                        "seconds": wall}) + "\n")
            print(f"{n}/{len(jobs)} {key} seed {seed}: {wall:.1f} s", file=sys.stderr, flush=True)
    text = ["# Machine time against accuracy: stepped sine and broadband", "",
            f"Generated by `scripts/bench_machine_time.py` on {date.today()} ({platform.machine()}, "
            f"{platform.python_version()}, {args.workers} workers of one thread, {args.seeds} seeds, "
            f"{(time.perf_counter() - started) / 60:.0f} min); the method is the script's docstring. Inputs: "
            "`servofmu build PLANT -o PLANT.fmu`, `servofmu measure PLANT.fmu -o PLANT-ss.h5` (the default plan, "
            "noise-free); cases " + ", ".join(f"`{Path(c).name}`" for c in args.cases) + ".", ""]
    for c in all_cases:
        text += table(c, fits)
    output = "\n".join(text)
    print(output)
    if args.out:
        args.out.write_text(output)


if __name__ == "__main__":
    main()
