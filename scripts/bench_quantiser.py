"""The encoder's quantiser in closed-loop identification: bias and coverage of the 95 % intervals with the
quantiser's error left out of the fit and modelled (servofmu.identification.closed_loop).

Two axes in their drives' loops, each with a 1 µm encoder and actuator noise 40 dB below the force command:

- stribeck_axis (fmu_models/) with axis_controller, on the demo's 16 s identification reference;
- the axis of tests/test_drive_logs.py — 25 kg, viscous damping, Stribeck friction, a constant load force (an
  incline) — with its drive (position P, velocity P on a two-sample moving average, a 350 N output limit) and
  ±175 N test pulses injected after the limit, on a 4 s reference with reversals and a fast move; and on two
  longer logs of it (12 s; 2 s at rest first, 5.5 s), fitted with the quantiser left out only;
- that axis with friction the same in both directions, fitted as symmetric (the offset is then separated from the
  friction), on a 16 s log that first dwells at speeds from 2 to 200 mm/s each way.

The records come from the loop simulator with the controller's own quantiser and actuator noise (the law the
controller FMU runs: docs/bench-closed-loop.md, section 1, has it equal to libcosim's co-simulation to 1e-12); the
encoder reading is logged.  Every seed is fitted twice: with the quantiser left out of the fit (the criterion as
before: encoder resolution 0 in the data) and modelled (ENCODER_REALISATIONS white uniform error sequences in
antithetic pairs, fed back through the loop, common to every candidate).  Without a quantiser in the data nothing
changes: a fit of records without one simulates a single loop without error.  What the page holds after its
generated part (from a line "## History" on) is kept when it is written again.

Usage: nice -n 10 python scripts/bench_quantiser.py [--seeds 20] [--out docs/bench-quantiser.md]
       (or each case alone, e.g. in parallel: --case stribeck_axis, --case drive_axis, ...; then --join)
"""
from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

from servofmu.identification.closed_loop import (ENCODER_REALISATIONS, ClosedLoopData, ClosedLoopSeries,
                                                 LoopSimulator)
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import full_vectors, identified_mask, identified_names
from servofmu.model.controller import controller_from_dict, load_controller
from servofmu.model.plant import load_plant, plant_from_dict
from servofmu.commands.demo import reference_trajectories
from servofmu.runtime import available_cores

SNR_DB = 40.0
Q = 1e-6  # the encoder's quantum (m)
CASES = ("stribeck_axis", "drive_axis", "drive_axis_long", "drive_axis_rest", "drive_axis_symmetric")
# Longer logs of the drive axis (its reference as it is, 12 s; or 2 s at rest first, 5.5 s), fitted with the
# quantiser left out only (on this axis it hardly matters): (duration, rest) of drive_reference.
DRIVE_LOGS = {"drive_axis": (4.0, 0.5), "drive_axis_long": (12.0, 0.5), "drive_axis_rest": (5.5, 2.0),
             "drive_axis_symmetric": (16.0, 0.5)}
# The symmetric axis's log dwells at these speeds (m/s) first: a friction run, as a drive's commissioning makes one.
DWELL = (0.002, 0.004, 0.007, 0.012, 0.02, 0.05, 0.1, 0.2)

# The drive-log axis of tests/test_drive_logs.py, in newtons (35 N/V: velocity P 60 V per m/s, ±10 V, 5 V pulses).
DRIVE = {"name": "volt_drive", "sample_time": 1e-3, "delay": 1, "position": {"kp": 40.0},
         "velocity": {"kp": 60.0 * 35.0, "filter": "moving-average", "window": 2}, "output": {"limit": 350.0},
         "encoder": {"resolution": Q}}
DRIVE_AXIS = {"name": "drive_axis", "linear": {"poles": [[-60.0 / 25.0, 0.0]], "zeros": [], "gain": 1.0 / 25.0},
              "friction": {"model": "stribeck", "fc_pos": 30.0, "fc_neg": 24.0, "fs_pos": 45.0, "fs_neg": 38.0,
                           "vs": 0.01, "v_smooth": 1e-3},
              "load": {"offset": -30.0}}
# The same axis with friction the same in both directions (the levels' means), fitted as symmetric: the offset is
# then told from the friction by the motion in each direction (docs/identification.md).
DRIVE_AXIS_SYMMETRIC = {**DRIVE_AXIS, "name": "drive_axis_symmetric",
                        "friction": {"model": "stribeck", "symmetric": True, "fc_pos": 27.0, "fs_pos": 41.5,
                                     "vs": 0.01, "v_smooth": 1e-3}}


def drive_reference(duration: float = 4.0, ts: float = 1e-3, rest: float = 0.5, dwell: tuple = ()):
    """The drive axis's reference (m) and test pulses (N): at rest for ``rest`` s (the force holding the axis
    against its load, with no friction at rest, tells the load from the friction), then ``dwell``: 0.5 s at each
    (speed, m/s) forth and back (the friction curve at those speeds), then reversals at 0.8 and 2.4 Hz, and a
    30 mm move in 16 ms at the middle (the output saturates); ±175 N pulses of 8-15 ms every 120-220 ms
    (seeded, the same every run)."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, duration, ts)
    speed = np.zeros_like(t)
    for i, v in enumerate(np.repeat(dwell, 2)):
        speed[(t >= rest + 0.5 * i) & (t < rest + 0.5 * (i + 1))] = v * (-1) ** i
    s = np.maximum(t - rest - len(dwell), 0.0)
    move = 0.015 * (1 + np.tanh((t - duration / 2) / 0.016))  # 0.03 / (1 + exp(−(t − T/2)/0.008)), no overflow
    x = 0.015 * (1 - np.cos(2 * np.pi * 0.8 * s)) + 0.004 * (1 - np.cos(2 * np.pi * 2.4 * s)) + move - move[0]
    x += np.cumsum(speed) * ts
    pulses, start = np.zeros_like(t), int(0.1 / ts)
    while start < t.size:
        width = int(rng.integers(8, 16))
        pulses[start:start + width] = 175.0 * rng.choice([-1.0, 1.0])
        start += int(rng.integers(120, 220))
    return t, x, pulses


def case(name: str):
    """(plant, controller, time, reference, disturbance or None) of a case."""
    if name == "stribeck_axis":
        controller = load_controller("axis_controller")
        t, x = reference_trajectories(controller.sample_time)["identify"]
        return load_plant("stribeck_axis"), controller, t, x, None
    duration, rest = DRIVE_LOGS[name]
    if name == "drive_axis_symmetric":
        return (plant_from_dict(DRIVE_AXIS_SYMMETRIC), controller_from_dict(DRIVE),
                *drive_reference(duration, rest=rest, dwell=DWELL))
    return plant_from_dict(DRIVE_AXIS), controller_from_dict(DRIVE), *drive_reference(duration, rest=rest)


def kinds(name: str) -> tuple[str, ...]:
    """The fits a case makes: with the quantiser left out and modelled, or left out only (the longer logs)."""
    return ("left out",) if name in ("drive_axis_long", "drive_axis_rest") else ("left out", "modelled")


def log_maker(name: str):
    """(plant, truth, force noise 40 dB below the command, data(noise, seed, resolution)): the case's drive logs
    (the loop simulated with the controller's quantiser and actuator noise, the encoder's reading logged) as
    closed-loop data whose fit models the quantiser of ``resolution`` (0: left out)."""
    plant, controller, t, ref, dist = case(name)
    truth = plant.parameter_vector()[identified_mask(plant)]
    sim = LoopSimulator(plant, threads=1)
    full = full_vectors(plant, truth[None])
    law = controller.with_values(encoder_resolution=0.0, force_noise=0.0)
    clean = sim.simulate_loop(full, t, ref, law, rtol=1e-10, disturbance=dist)
    force_noise = float(np.std(clean.command[0])) / 10 ** (SNR_DB / 20)
    fitted = np.ones(t.size, dtype=bool)

    def data(noise: float, seed: int, resolution: float) -> ClosedLoopData:
        loop = sim.simulate_loop(full, t, ref, controller.with_values(force_noise=noise, noise_seed=seed),
                                 rtol=1e-10, disturbance=dist)
        encoder = Q * np.floor(loop.position[0] / Q + 0.5)  # the reading the law used, as the drive logs it
        series = ClosedLoopSeries("log", t, ref, encoder, loop.command[0], fitted, dist)
        return ClosedLoopData((series,), law, "simulated", encoder_resolution=resolution)

    return plant, truth, force_noise, data


def run_case(name: str, seeds: int) -> dict:
    """Per fit kind ("left out", "modelled"): relative errors (seeds, parameters), coverage, seconds per fit; and
    the errors of one noise-free run with the quantiser alone."""
    plant, truth, force_noise, data = log_maker(name)

    def fit(d: ClosedLoopData, seed: int):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            est = PSOANNIdentifier(plant, method="pso", seed=seed, threads=1).fit(d)
            return est, time.perf_counter() - t0

    out = {"names": identified_names(plant), "truth": truth, "force_noise": force_noise}
    for kind, resolution in [(k, {"left out": 0.0, "modelled": Q}[k]) for k in kinds(name)]:
        errors, covered, seconds = [], [], []
        for seed in range(seeds):
            est, s = fit(data(force_noise, seed, resolution), seed)
            errors.append(est.theta_ / truth - 1)
            covered.append((est.intervals_[:, 0] <= truth) & (truth <= est.intervals_[:, 1]))
            seconds.append(s)
            print(name, kind, seed, " ".join(f"{100 * e:+.3f}{'' if c else '!'}"
                                            for e, c in zip(errors[-1], covered[-1])), f"{s:.1f} s", flush=True)
        out[kind] = np.array(errors), np.array(covered), float(np.median(seconds))
        out[kind + ", quantiser alone"] = fit(data(0.0, 0, resolution), 0)[0].theta_ / truth - 1
    return out


def table(name: str, res: dict, seeds: int) -> list[str]:
    """The page's lines for one case."""
    names = res["names"]
    log = f"; a log of {DRIVE_LOGS[name][0]:g} s, {DRIVE_LOGS[name][1]:g} s of it at rest first" \
        if name in DRIVE_LOGS else ""
    if name == "drive_axis_symmetric":
        log += (f", then 0.5 s at each of {', '.join(f'{1e3 * v:g}' for v in DWELL)} mm/s forth and back; "
                "friction fitted as symmetric")
    lines = [f"### {name}", "", f"Actuator noise {res['force_noise']:.3g} N RMS{log}; truth: "
             + ", ".join(f"{n} {v:g}" for n, v in zip(names, res["truth"])) + ".", "",
             "| the quantiser in the fit | worst rel. error | median worst | intervals covering the truth | "
             "lowest per parameter | s per fit |", "|---|---|---|---|---|---|"]
    for kind in kinds(name):
        errors, covered, seconds = res[kind]
        worst = np.max(np.abs(errors), axis=1)
        lines.append(f"| {kind} | {100 * worst.max():.3f} % | {100 * np.median(worst):.3f} % | "
                     f"{100 * covered.mean():.1f} % ({covered.sum()} of {covered.size}) | "
                     f"{100 * covered.mean(axis=0).min():.0f} % | {seconds:.1f} |")
    lines += ["", f"Mean relative error of each parameter in % (in brackets: how often its 95 % interval covers the "
              f"truth, of {seeds} seeds); last rows: one run with the quantiser alone (no actuator noise).", "",
              "| the quantiser in the fit | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for kind in kinds(name):
        errors, covered, _ = res[kind]
        lines.append(f"| {kind} | " + " | ".join(f"{100 * e:+.3f} ({100 * c:.0f} %)" for e, c in
                                                 zip(errors.mean(axis=0), covered.mean(axis=0))) + " |")
    for kind in kinds(name):
        lines.append(f"| {kind}, quantiser alone | "
                     + " | ".join(f"{100 * e:+.3f}" for e in res[kind + ", quantiser alone"]) + " |")
    return lines + [""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--case", choices=CASES, help="run one case; its table is written beside the page (OUT.CASE)")
    ap.add_argument("--join", action="store_true", help="write the page from the tables of the cases run alone")
    ap.add_argument("--out", default="docs/bench-quantiser.md")
    args = ap.parse_args()
    if args.join:
        body = [Path(f"{args.out}.{name}").read_text() for name in CASES]
    else:
        body = []
        for name in [args.case] if args.case else CASES:
            body.append("\n".join(table(name, run_case(name, args.seeds), args.seeds)))
            print(body[-1], flush=True)
        if args.case:
            Path(f"{args.out}.{args.case}").write_text(body[0])
            return
    lines = ["# The encoder's quantiser in closed-loop identification", "",
             f"Made by `scripts/bench_quantiser.py` on {available_cores()} cores, {args.seeds} noise seeds per "
             f"axis; a 1 µm encoder and actuator noise {SNR_DB:g} dB below the force command in the loop.  "
             "*Left out*: the fit simulates the loop without the quantiser (what identify did before).  "
             f"*Modelled*: the quantiser's error, white and uniform on ±q/2, fed back through the loop in "
             f"{ENCODER_REALISATIONS} sequences (antithetic pairs) common to every candidate, the candidate's loops averaged "
             "(servofmu.identification.closed_loop).  The intervals: Newey–West on leave-one-segment-out "
             "residuals, a record's position and command together "
             "(servofmu.identification.long_run.newey_west_covariance).", "", *body]
    out = Path(args.out)
    kept = out.read_text().partition("\n## History\n") if out.exists() else ("", "", "")
    out.write_text("\n".join(lines) + (kept[1] + kept[2] if kept[1] else ""))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
