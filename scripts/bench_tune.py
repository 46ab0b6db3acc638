"""Drive gains tuned on the identified model, checked on the true axis in co-simulation.

For linear_axis and stribeck_axis: the plant identified in the loop of axis_controller.toml from noisy records
(actuator noise 40 dB below the force command, 1 µm encoder; the demo's 16 s identification reference, seed 0);
then, with friction feed-forward off and on,

- `tune` (the swarm, sensitivity peak ≤ 1.7) from axis_controller.toml and from a badly tuned start (every gain
  a tenth of the example's), the reference rule at the same peak, the swarm on a result at the true parameters
  (the identified intervals' widths), and a dense grid search over the feedback gains and the mass feed-forward
  on the true plant under the same bound (the batch simulator's loop; its best point co-simulated);
- each controller co-simulated on libcosim with the true plant on the reversing stroke (0.05 m·(1 − cos πt), 4 s,
  the demo's) and a step: RMS and peak tracking error, settling, velocity error at the reversals, margins;
- the tuned loop's sensitivity peak at every corner of the identified 95 % box, and the tracking error there;
- the trade-off: the RMS error on the axis of the swarm's and the rule's gains against the bound on the peak;
- the time `tune` takes (without and with the check on the axis).

Usage: nice -n 10 python scripts/bench_tune.py [--out docs/bench-tune.md] [--quick]
"""
from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import servofmu as sf
from servofmu.control.cosim import cosimulate, write_cosim_records
from servofmu.control.fmus import build_controller_fmu
from servofmu.control.system import write_system
from servofmu.identification.closed_loop import closed_loop_data
from servofmu.identification.prior import full_vectors, identified_mask
from servofmu.identification.results import result_from_estimator
from servofmu.model.controller import load_controller
from servofmu.commands.demo import reference_trajectories
from servofmu.runtime import available_cores
from servofmu.simulation.closed_loop import LoopSimulator
from servofmu.tuning.check import check_on_axis
from servofmu.tuning.loop import analyse_loop, axis_mass, sensitivity_peak
from servofmu.tuning.run import step_for, tune_axis
from servofmu.tuning.search import GainSpace, TuneOptions, to_bound, tracking_errors
from servofmu.tuning.task import Task

PLANTS = ("linear_axis", "stribeck_axis")
SNR_DB = 40.0
BOUND = 1.7


def identify(folder: Path, name: str, fmu: Path, controller, refs):
    """The plant identified in the loop from noisy co-simulated records (as bench_closed_loop's section 2)."""
    exact = controller.with_values(encoder_resolution=0.0)
    drive = build_controller_fmu(exact, folder / f"{name}-ident-drive.fmu", fmi_version=2)
    ssp = write_system(fmu, drive, refs["identify"], folder / f"{name}-clean.ssp", controller=exact)
    force_noise = float(np.std(cosimulate(ssp)["force_command"])) / 10 ** (SNR_DB / 20)
    noisy = controller.with_values(force_noise=force_noise, noise_seed=0)
    ssp = write_system(fmu, drive, refs["identify"], folder / f"{name}-noisy.ssp", controller=noisy)
    records = write_cosim_records(cosimulate(ssp), ssp, folder / f"{name}-records.h5")
    est = sf.PSOANNIdentifier(sf.load_plant(name), method="pso", seed=0).fit(closed_loop_data(records, controller))
    return result_from_estimator(est, "pso", {"controller_file": str(controller.source)})


def at_truth(result, truth):
    """The result moved to the true parameters, its intervals' widths kept."""
    true = truth.parameter_vector()[identified_mask(truth)]
    return replace(result, plant=truth, theta=true, intervals=result.intervals - result.theta[:, None] + true[:, None])


def grid_search(truth, base, task: Task, quick: bool):
    """The best feedback gains and mass feed-forward on the true plant under the bound (filter off, the whole
    reference velocity fed forward): a dense grid in the swarm's coordinates, and each of its shapes (integral
    corner, bandwidth ratio, mass share) also at the fastest velocity loop the bound allows."""
    space = GainSpace(axis_mass(truth), base.sample_time, int(base["delay"]))
    sim = LoopSimulator(truth, threads=available_cores())
    # the velocity loop's speed every 0.05 decade (the bound cuts across it), the two corners every 0.13 decade
    # (the loop is symmetric in them), the mass feed-forward at three shares
    axes = ((np.linspace(-0.9, 0.1, 6), np.linspace(-1.6, 0.0, 6), np.linspace(-1.6, 0.0, 6), (1.0,)) if quick else
            (np.linspace(-0.9, 0.1, 21), np.linspace(-1.6, 0.0, 13), np.linspace(-1.6, 0.0, 13), (1.0, 1.25, 1.5)))
    def peak(x, corners=True):
        return sensitivity_peak(truth, space.controller(base, x))

    best, points = (np.inf, None), 0
    shapes = list(itertools.product(*axes[1:]))
    # every point of the grid, and every shape at the fastest velocity loop the bound allows (the bound cuts
    # across the grid's steps of the velocity loop)
    grid = [np.array([a, b, c, 0.0, 1.0, m]) for a, (b, c, m) in itertools.product(axes[0], shapes)]
    grid += [x for x in (to_bound(peak, np.array([axes[0][-1], b, c, 0.0, 1.0, m]), BOUND, -2.0)
                         for b, c, m in shapes) if x is not None]
    for x in grid:
        if peak(x) > BOUND:
            continue
        points += 1
        candidate = space.controller(base, x)
        rms = tracking_errors(sim, truth.parameter_vector()[None], task, candidate)[0]
        if rms < best[0]:
            best = (rms, candidate)
    return best[1], points, len(grid)


def corners(result, controller, task: Task):
    """(largest sensitivity peak, largest RMS error on the model) over every corner of the identified box."""
    plant = result.plant
    sets = full_vectors(plant, np.array(list(itertools.product(*result.intervals))))
    peaks = [sensitivity_peak(plant.with_parameters(p), controller, points=3000) for p in sets]
    sim = LoopSimulator(plant, threads=available_cores())
    return max(peaks), float(np.max(tracking_errors(sim, sets, task, controller))), len(sets)


def row(label, controller, truth, figures):
    s = analyse_loop(truth, controller).summary()
    return (f"| {label} | {s['sensitivity_peak']:.3f} | {s['gain_margin_db']:.1f} | {s['phase_margin_deg']:.1f} | "
            f"{figures.rms_error:.3e} | {figures.peak_error:.3e} | {1e3 * figures.settling_time:.0f} | "
            f"{figures.reversal_velocity_error:.2e} | {100 * figures.saturated:.2f} |")


def compare(name, result, truth, given, compensate, task, ssp, quick, lines, speed):
    """One table: given, rule, tuned, tuned from a bad start, tuned on the truth, the grid's best."""
    options = TuneOptions(max_sensitivity=BOUND, threads=available_cores())
    started = time.perf_counter()
    tuning = tune_axis(result, given, task, options, compensate=compensate, source=name)
    speed.setdefault(name, time.perf_counter() - started)
    bad = given.with_values(kp_position=given["kp_position"] / 10, kp_velocity=given["kp_velocity"] / 10,
                            ki_velocity=given["ki_velocity"] / 10, velocity_feedforward=0.1,
                            mass_feedforward=given["mass_feedforward"] / 10)
    from_bad = tune_axis(result, bad, task, options, compensate=compensate, source=name).controller
    on_truth = tune_axis(at_truth(result, truth), given, task, options, compensate=compensate).controller
    t0 = time.perf_counter()
    grid, points, total = grid_search(truth, tuning.runs["given"].controller, task, quick)
    grid_s = time.perf_counter() - t0
    controllers = {"axis_controller.toml": tuning.runs["given"].controller, "reference rule": tuning.runs["rule"]
                   .controller, "tuned (swarm)": tuning.controller, "tuned from a tenth of every gain": from_bad,
                   "tuned on the true parameters": on_truth, "grid search on the true plant": grid}
    step = step_for(task, list(controllers.values()))
    runs = {r.label: r.figures for r in check_on_axis(ssp, controllers, task, step)}
    lines += [f"### {name}, friction feed-forward {'on' if compensate else 'off'}", "",
              "| controller | Ms (true plant) | gain margin [dB] | phase margin [deg] | RMS error [m] | "
              "peak error [m] | settling [ms] | velocity error at reversals [m/s] | at the limit [%] |",
              "|---|---|---|---|---|---|---|---|---|",
              *(row(label, c, truth, runs[label]) for label, c in controllers.items()), ""]
    rms = {label: f.rms_error for label, f in runs.items()}
    tuned = rms["tuned (swarm)"]
    peak, worst, n = corners(result, tuning.controller, task)
    lines += [f"- RMS error, axis_controller.toml / tuned: **{rms['axis_controller.toml'] / tuned:.2f}x**; reference "
              f"rule / tuned: **{rms['reference rule'] / tuned:.2f}x**; tuned / grid's best: "
              f"**{tuned / rms['grid search on the true plant']:.3f}** (grid: {points} of {total} points within "
              f"the bound, {grid_s:.0f} s)",
              f"- from a tenth of every gain: {rms['tuned from a tenth of every gain'] / tuned:.3f} × the tuned "
              f"error; tuned on the true parameters / tuned on the identified model: "
              f"{rms['tuned on the true parameters'] / tuned:.3f}",
              f"- the tuned loop at all {n} corners of the identified 95 % box: sensitivity peak ≤ {peak:.3f}, RMS "
              f"error on the model ≤ {worst:.3e} m (nominal {tuning.runs['tuned'].figures.rms_error:.3e} m)",
              f"- swarm: {tuning.search.evaluations} candidates, {tuning.search.simulated} simulated; rule at "
              f"a = {tuning.rule_a:.3f}", ""]
    print("\n".join(lines[-14:]), flush=True)
    return tuning


def trade_off(name, result, truth, base, task, ssp, bounds, lines):
    lines += [f"### {name}: RMS error on the axis against the bound on the sensitivity peak (feed-forward of "
              "friction off)", "", "| bound Ms | swarm [m] | rule [m] | rule / swarm | axis_controller.toml / swarm |",
              "|---|---|---|---|---|"]
    for bound in bounds:
        tuning = tune_axis(result, base, task, TuneOptions(max_sensitivity=bound, threads=available_cores()))
        runs = {r.label: r.figures.rms_error for r in check_on_axis(ssp, {k: v.controller for k, v in
                                                                          tuning.runs.items()}, task, tuning.step)}
        lines.append(f"| {bound:g} | {runs['tuned']:.3e} | {runs['rule']:.3e} | {runs['rule'] / runs['tuned']:.2f} | "
                     f"{runs['given'] / runs['tuned']:.2f} |")
        print(lines[-1], flush=True)
    lines.append("")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/bench-tune.md")
    ap.add_argument("--quick", action="store_true", help="a coarse grid and two bounds: a smoke run")
    args = ap.parse_args()
    base = load_controller("axis_controller")
    refs = reference_trajectories(base.sample_time)
    task = Task(*refs["reversals"], "reversing stroke 0.05·(1 − cos πt) m, 4 s")
    lines = ["# Tuning the drive on the identified model, checked on the true axis", "",
             f"Made by `scripts/bench_tune.py` on {available_cores()} cores. {__doc__.split(chr(10), 2)[2]}"]
    speed = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in PLANTS:
            truth = sf.load_plant(name)
            fmu = sf.build_fmu(truth, folder / f"{name}.fmu", fmi_version=2)
            result = identify(folder, name, fmu, base, refs)
            drive = build_controller_fmu(base, folder / f"{name}-drive.fmu", fmi_version=2)
            ssp = write_system(fmu, drive, refs["reversals"], folder / f"{name}-axis.ssp", controller=base)
            error = np.max(np.abs(result.theta / truth.parameter_vector()[identified_mask(truth)] - 1))
            lines += [f"## {name}", "", f"Identified in the loop: worst relative parameter error {error:.2e}.", ""]
            for compensate in (False, True):
                compare(name, result, truth, base, compensate, task, ssp, args.quick, lines, speed)
            trade_off(name, result, truth, base, task, ssp, (1.5, 2.0) if args.quick else (1.4, 1.5, 1.7, 2.0, 2.3),
                      lines)
            if name == "linear_axis":
                t0 = time.perf_counter()
                tune_axis(result, base, task, TuneOptions(), axis=ssp)
                speed["linear_axis with --axis"] = time.perf_counter() - t0
    lines += ["## Speed", "", "`tune` (the library's tune_axis; swarm of 16 particles × 30 iterations, the "
              "uncertainty set of the nominal model and 6 corners) on the example axis, the first tuning of each "
              f"plant (load average at the end of the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores):", "",
              *(f"- {k}: {v:.1f} s" for k, v in speed.items()), ""]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
