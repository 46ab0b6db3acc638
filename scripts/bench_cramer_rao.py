"""Accuracy at the physical limit: servofmu's estimates against the Cramér–Rao bound of the output-error model.

    python scripts/bench_cramer_rao.py --demo DIR [--cases g1,stribeck_servo,g2-records,stribeck_axis-white,
                                                   stribeck_axis-drive] [--seeds 100] [--loop-seeds 100]
                                                   [--workers 1] [--out docs/bench-cramer-rao.md]

``--demo DIR``: a folder with the demo's g1 files (`servofmu demo`); stribeck_servo's FMU, measurement and network
are made there as scripts/bench_swarm_budget.py makes them when missing.  For every case the bound
(servofmu.identification.cramer_rao: Fisher information Jᵀ diag(s⁻²) J at the truth, J the criterion's Jacobian,
s the known noise level) and the RMS error of ``--seeds`` identifications, each on its own noise at 40 dB output
SNR, with the coverage of their 95 % intervals:

- ``g1``, ``stribeck_servo``: stepped sine under g1's plan (2.0, 0.6 N × 0.5 … 20 Hz), PSO-ANN as `identify` runs
  it; white noise on the velocity samples of every experiment's window (as `measure --noise-snr-db 40`), the
  harmonics re-estimated from them;
- ``g2-records``: one 20 s record at 200 Hz of a multisine force (zero-order hold), white noise on the velocity,
  `identify --method pso`;
- ``stribeck_axis-white``: the axis in its drive's loop (axis_controller, the demo's 16 s reference), exact
  encoder, white noise on the logged position and force command (the output-error model's own assumption),
  `identify --closed-loop`;
- ``stribeck_axis-drive``: the same loop with its 1 µm encoder and actuator noise 40 dB below the force command
  inside the loop (as scripts/bench_closed_loop.py), fitted as `identify --closed-loop` fits a drive whose
  controller file gives its encoder (the quantiser modelled: servofmu.identification.closed_loop); the bound
  takes the quantiser's q/√12 on the position and the actuator noise on the command as if they were white
  measurement noise, which they are not.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing
import platform
import sys
import time
import warnings
from dataclasses import replace
from datetime import date
from pathlib import Path

import numpy as np

from bench_swarm_budget import inputs  # scripts/: stribeck_servo's network made as that benchmark makes it

from servofmu.identification.ann import load_ann
from servofmu.identification.closed_loop import ClosedLoopCriterion, ClosedLoopData, ClosedLoopSeries
from servofmu.identification.cramer_rao import (cramer_rao_bound, sine_fisher_information,
                                                time_domain_fisher_information)
from servofmu.identification.criterion import RecordCriterion, RecordData, RecordSeries, sine_data
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import full_vectors, identified_mask, identified_names
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.frf import harmonics
from servofmu.model.controller import load_controller
from servofmu.model.plant import load_plant
from servofmu.commands.demo import reference_trajectories
from servofmu.simulation.batch import BatchSimulator
from servofmu.simulation.closed_loop import LoopSimulator

ROOT = Path(__file__).resolve().parent.parent
SNR_DB = 40.0
CASES = "g1,stribeck_servo,g2-records,stribeck_axis-white,stribeck_axis-drive"


def truth_of(plant):
    return plant.parameter_vector()[identified_mask(plant)]


def sine_case(name: str, demo: Path):
    """(plant, truth, Fisher, Jacobian, data(seed), fit(data, seed)) of stepped sine with noise on the windows."""
    plant, truth = load_plant(name), truth_of(load_plant(name))
    _, data_file, ann_file = inputs(name, demo, demo)
    measured, ann = read_data_file(data_file), load_ann(ann_file)
    exps = [e for e in measured.experiments if e.converged]
    sigma = {e.index: math.sqrt(float(np.var(e.window.v))) / 10 ** (SNR_DB / 20) for e in exps}

    def data(seed):
        noisy = []
        for e in exps:
            rng = np.random.default_rng([seed, e.index])
            v = e.window.v + sigma[e.index] * rng.standard_normal(e.window.v.shape)
            h = harmonics(e.window.time, v, e.frequency, start=e.window_start, periods=e.window_periods,
                          n_harmonics=1)
            noisy.append(replace(e, noise_sigma=sigma[e.index], H_noisy=h.first / e.U1, dc_noisy=h.dc))
        return sine_data(replace(measured, experiments=tuple(noisy)))

    clean = sine_data(measured)
    noise = np.array([sigma[e.index] * math.sqrt(2 / (e.samples_per_period * e.window_periods)) / abs(e.U1 * e.H)
                      for e in exps])
    fisher, jac = sine_fisher_information(plant, replace(clean, noise=noise), truth, threads=1)
    return plant, truth, fisher, jac, data, lambda d, seed: PSOANNIdentifier(plant, ann=ann, seed=seed,
                                                                             threads=1).fit(d)


def records_case(name: str = "g2"):
    """One multisine record, white noise on its velocity."""
    plant, truth = load_plant(name), truth_of(load_plant(name))
    t = np.arange(0.0, 20.0, 0.005)
    u = 2.0 * (np.sin(2 * np.pi * 0.4 * t) + 0.6 * np.sin(2 * np.pi * 1.3 * t + 1.0)
               + 0.5 * np.sin(2 * np.pi * 3.1 * t + 2.0) + 0.4 * np.sin(2 * np.pi * 5.2 * t + 0.5))
    v = BatchSimulator(plant).simulate_record(full_vectors(plant, truth[None]), t, u, hold="zoh", rtol=1e-10).v[0]
    sigma = float(np.std(v)) / 10 ** (SNR_DB / 20)
    fitted = np.ones(t.size, dtype=bool)

    def data(seed, y=None):
        y = v + sigma * np.random.default_rng(seed).standard_normal(v.shape) if y is None else y
        return RecordData(records=(RecordSeries("multisine", t, u, y, "v", "zoh", fitted),), source="simulated")

    crit = RecordCriterion(plant, data(0, v), BatchSimulator(plant, threads=1))
    fisher, jac = time_domain_fisher_information(crit, truth, [sigma])
    return plant, truth, fisher, jac, data, lambda d, seed: PSOANNIdentifier(plant, method="pso", seed=seed,
                                                                             threads=1).fit(d)


def loop_case(name: str, drive: bool):
    """The axis in its loop: white noise on the logged signals, or the drive's own encoder and actuator noise."""
    plant, truth = load_plant(name), truth_of(load_plant(name))
    base = load_controller("axis_controller")
    law = base.with_values(encoder_resolution=0.0, force_noise=0.0)
    t, ref = reference_trajectories(base.sample_time)["identify"]
    sim = LoopSimulator(plant, threads=1)
    full = full_vectors(plant, truth[None])
    clean = sim.simulate_loop(full, t, ref, law, rtol=1e-10)
    x0, u0 = clean.position[0], clean.command[0]
    fitted = np.ones(t.size, dtype=bool)
    force_noise = float(np.std(u0)) / 10 ** (SNR_DB / 20)
    q = base["encoder_resolution"]

    def series(x, u, resolution=0.0):
        return ClosedLoopData((ClosedLoopSeries("identify", t, ref, x, u, fitted),), law, "simulated",
                              encoder_resolution=resolution)

    def data(seed):
        if not drive:
            rng = np.random.default_rng(seed)
            return series(x0 + sigma[0] * rng.standard_normal(t.size), u0 + sigma[1] * rng.standard_normal(t.size))
        loop = sim.simulate_loop(full, t, ref, base.with_values(force_noise=force_noise, noise_seed=seed), rtol=1e-10)
        return series(q * np.floor(loop.position[0] / q + 0.5), loop.command[0], q)  # the quantiser modelled

    sigma = (np.array([q / math.sqrt(12), force_noise]) if drive else
             np.array([float(np.std(x0)), float(np.std(u0))]) / 10 ** (SNR_DB / 20))
    crit = ClosedLoopCriterion(plant, series(x0, u0), LoopSimulator(plant, threads=1))
    fisher, jac = time_domain_fisher_information(crit, truth, sigma)
    return plant, truth, fisher, jac, data, lambda d, seed: PSOANNIdentifier(plant, method="pso", seed=seed,
                                                                             threads=1).fit(d)


def binomial(k: int, n: int) -> str:
    p = k / n
    return f"{100 * p:.1f} ± {100 * math.sqrt(p * (1 - p) / n):.1f} %"


_CASE = None  # (truth, data, fit) of the case being run


def _one_seed(seed: int):
    """One identification on the noise of ``seed``: its error, which intervals cover, restarted, seconds, and
    the fit's roughness (records: the rise of −2·ln L one standard error away, about 1 where the intervals'
    quadratic premise holds; NaN for stepped sines)."""
    truth, data, fit = _CASE
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fit(data(seed), seed)
    covered = (est.intervals_[:, 0] <= truth) & (truth <= est.intervals_[:, 1])
    return est.theta_ - truth, covered, est.restarts_ > 0, est.seconds_, getattr(est, "roughness_", math.nan)


def run_case(case: str, demo: Path, seeds: int, lines: list, workers: int = 1) -> None:
    t0 = time.perf_counter()
    if case in ("g1", "stribeck_servo"):
        plant, truth, fisher, jac, data, fit = sine_case(case, demo)
    elif case == "g2-records":
        plant, truth, fisher, jac, data, fit = records_case("g2")
    else:
        plant, truth, fisher, jac, data, fit = loop_case(case.split("-")[0], drive=case.endswith("drive"))
    bound = cramer_rao_bound(fisher, jac)
    global _CASE
    _CASE = (truth, data, fit)  # inherited by the forked workers
    if workers > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            fits = pool.map(_one_seed, range(seeds), chunksize=1)
    else:
        fits = [_one_seed(seed) for seed in range(seeds)]
    errors, covered, restarted, seconds, roughness = zip(*fits)
    restarts = sum(restarted)
    errors, covered, roughness = np.array(errors), np.array(covered), np.array(roughness)
    rms_error = np.sqrt(np.mean(errors**2, axis=0))
    rough = (f" The fits' roughness (the rise of −2·ln L one standard error away along a profile direction, 1 for "
             f"the quadratic cost the intervals assume): median {np.median(roughness):.2f}, largest "
             f"{np.max(roughness):.2f}." if np.any(np.isfinite(roughness)) else "")
    lines += [f"## {case}", "",
              f"{seeds} noise seeds; median fit {np.median(seconds):.2f} s; {restarts} fits restarted. "
              f"RMS/CRB's own Monte-Carlo uncertainty: ±{100 / math.sqrt(2 * seeds):.0f} % (1σ).{rough}", "",
              "| parameter | truth | CRB (1σ) | RMS error | RMS / CRB | bias / CRB | 95 % intervals covering |",
              "|---|---|---|---|---|---|---|"]
    for k, name in enumerate(identified_names(plant)):
        ratio = rms_error[k] / bound[k] if np.isfinite(bound[k]) else math.nan
        bias = np.mean(errors[:, k]) / bound[k] if np.isfinite(bound[k]) else math.nan
        lines.append(f"| {name} | {truth[k]:.6g} | {bound[k]:.3g} | {rms_error[k]:.3g} | {ratio:.2f} | {bias:+.2f} | "
                     f"{covered[:, k].sum()} of {seeds} ({binomial(int(covered[:, k].sum()), seeds)}) |")
    lines += ["", f"All parameters: {covered.sum()} of {covered.size} intervals cover the truth "
              f"({binomial(int(covered.sum()), covered.size)}); worst RMS/CRB "
              f"{np.nanmax(rms_error / bound):.2f}.", ""]
    print("\n".join(lines[-(len(truth) + 4):]), file=sys.stderr, flush=True)
    print(f"{case}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo", type=Path, required=True, help="folder with the demo's g1 files (`servofmu demo`)")
    ap.add_argument("--cases", default=CASES)
    ap.add_argument("--seeds", type=int, default=100, help="noise seeds of the stepped-sine and record cases")
    ap.add_argument("--loop-seeds", type=int, default=100, help="noise seeds of the closed-loop cases")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench-cramer-rao.md")
    ap.add_argument("--workers", type=int, default=1, help="processes fitting the seeds (one thread each)")
    args = ap.parse_args()
    lines = ["# Accuracy against the Cramér–Rao bound", "",
             f"Generated by `scripts/bench_cramer_rao.py --cases {args.cases} --seeds {args.seeds} --loop-seeds "
             f"{args.loop_seeds}` on {date.today()} ({platform.machine()}, {platform.python_version()}, one thread "
             "per fit). CRB: √(I⁻¹)_kk with I = Jᵀ diag(s⁻²) J at the truth (servofmu.identification.cramer_rao), "
             f"s the noise level of each measurement at {SNR_DB:g} dB output SNR; RMS error over the seeds of the "
             "estimates as `identify` makes them; coverage of the 95 % intervals with its binomial standard "
             "error. The cases are described in the script's docstring; what the numbers say follows the "
             "tables.", ""]
    for case in args.cases.split(","):
        seeds = args.loop_seeds if case.startswith("stribeck_axis") else args.seeds
        run_case(case, args.demo, seeds, lines, args.workers)
        args.out.write_text("\n".join(lines))  # each case as it ends: a long run keeps what it has
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
