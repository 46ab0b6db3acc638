"""How well the newer friction laws are identified: dahl_servo, gms_servo, stribeck_shaped and viscous_axis.

    python scripts/bench_laws.py [--plants dahl_servo,gms_servo,stribeck_shaped,viscous_axis] [--seeds 20]
                                 [--starts 50] [--work DIR] [--out docs/bench-laws.md]

For every shipped example plant, identified as `identify` does without a network (``method="pso"``: the prior
box around the structure file's values, swarm, polish, restarts above the noise floor), one thread:

1. Noise-free: the plant's FMU measured under `measure`'s default plan (2.0 and 0.6 N, the 1-2-5 grid around its
   bandwidth), and one 20 s record at 200 Hz of a four-tone multisine force (zero-order hold, zero mean, so the
   axis moves both ways) simulated at rtol 1e-10; each identified from the structure file's values (the truth):
   the worst relative parameter error.
2. 40 dB output SNR over ``--seeds`` seeds on the stepped sines (white noise on every experiment's window, the
   harmonics re-estimated, as scripts/bench_cramer_rao.py does): how many 95 % intervals contain the truth, per
   parameter and overall, with the binomial standard error.
3. The wider prior (spread 0.8, as docs/bench-restarts.md): ``--starts`` identifications of the noise-free
   stepped sines, each starting from a structure whose identified values are drawn from the prior of spread 0.8
   around the truth (seed k of the draw and of the search): how many end within 1e-3 of the truth.
4. viscous_axis: the error of fv_pos − fv_neg from the record and from the stepped sines, and the line the result
   prints about what G holds (servofmu.model.laws.viscous.viscous_note).
"""
from __future__ import annotations

import argparse
import math
import platform
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from datetime import date
from pathlib import Path

import numpy as np

from servofmu.fmu import build_fmu
from servofmu.identification.criterion import RecordData, RecordSeries, sine_data
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import full_vectors, identified_mask, identified_names, sample_identified
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.frf import harmonics
from servofmu.measurement.measure import measure
from servofmu.model.friction import viscous_damping
from servofmu.model.laws.viscous import viscous_note
from servofmu.model.plant import load_plant
from servofmu.runtime import RunOptions
from servofmu.simulation.batch import BatchSimulator

ROOT = Path(__file__).resolve().parent.parent
PLANTS = "dahl_servo,gms_servo,stribeck_shaped,viscous_axis"
SNR_DB = 40.0
WIDER = 0.8     # docs/bench-restarts.md's wider prior
WITHIN = 1e-3   # a start counts as found within this worst relative error
TONES = ((1.0, 0.4, 0.0), (0.6, 1.3, 1.0), (0.5, 3.1, 2.0), (0.4, 5.2, 0.5))  # (relative amplitude, Hz, rad)


def truth_of(plant) -> np.ndarray:
    """The identified parameters' true values (the plant file's)."""
    return plant.parameter_vector()[identified_mask(plant)]


def worst_relative(theta, truth) -> float:
    """The largest |theta/truth − 1| over the parameters."""
    return float(np.max(np.abs(np.asarray(theta) / np.asarray(truth) - 1)))


def binomial(k: int, n: int) -> str:
    """k of n as a percentage with its binomial standard error, e.g. "95.0 ± 2.2 %"."""
    p = k / n
    return f"{100 * p:.1f} ± {100 * math.sqrt(p * (1 - p) / n):.1f} %"


def covers(intervals, truth) -> np.ndarray:
    """Which of the (p, 2) intervals contain the truth."""
    intervals = np.asarray(intervals)
    return (intervals[:, 0] <= truth) & (truth <= intervals[:, 1])


def multisine(amplitude: float = 2.0, duration: float = 20.0, dt: float = 0.005):
    """(t, u) of the record's four-tone force, zero mean."""
    t = np.arange(0.0, duration, dt)
    u = amplitude * sum(a * np.sin(2 * np.pi * f * t + phase) for a, f, phase in TONES)
    return t, u


def fit(structure, data, seed: int = 0):
    """`identify`'s default without a network, on one thread, warnings of a spent budget silenced (counted)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return PSOANNIdentifier(structure, method="pso", seed=seed, threads=1).fit(data)


def record_data(plant, truth) -> RecordData:
    """The noise-free multisine record of ``plant``."""
    t, u = multisine()
    v = BatchSimulator(plant, threads=1).simulate_record(full_vectors(plant, truth[None]), t, u, hold="zoh",
                                                          rtol=1e-10).v[0]
    return RecordData(records=(RecordSeries("multisine", t, u, v, "v", "zoh", np.ones(t.size, bool)),),
                      source="simulated")


def noisy_sines(measured, seed: int):
    """The stepped sines with white noise at SNR_DB on every converged window, the harmonics re-estimated."""
    out = []
    for e in (e for e in measured.experiments if e.converged):
        sigma = math.sqrt(float(np.var(e.window.v))) / 10 ** (SNR_DB / 20)
        v = e.window.v + sigma * np.random.default_rng([seed, e.index]).standard_normal(e.window.v.shape)
        h = harmonics(e.window.time, v, e.frequency, start=e.window_start, periods=e.window_periods, n_harmonics=1)
        out.append(replace(e, noise_sigma=sigma, H_noisy=h.first / e.U1, dc_noisy=h.dc))
    return sine_data(replace(measured, experiments=tuple(out)))


def miss_line(k: int, names, start, est, truth) -> str:
    """One start that ended off the truth: how far its start was, which parameter ended worst, its restarts."""
    errors = np.abs(est.theta_ / truth - 1)
    return (f"  - start {k}: start up to {worst_relative(start, truth):.0%} off the truth; ended {errors.max():.1%} off "
            f"in {names[int(np.argmax(errors))]} after {est.restarts_} restarts; fitness {est.fitness_:.2e}")


def counts(text: str, plants: list[str]) -> dict[str, int]:
    """One count for every plant, or one per plant (comma-separated, in ``--plants`` order)."""
    values = [int(v) for v in text.split(",")]
    return dict(zip(plants, values if len(values) > 1 else values * len(plants)))


def with_values(plant, **values):
    """``plant`` with the parameters named in ``values`` replaced."""
    params = plant.parameters() | values
    return plant.with_parameters([params[n] for n in plant.parameter_names()])


def absorbed(plant, fv: float):
    """(poles, G(0)) of G/(1 + fv·G): the G that takes up a viscous friction ``fv`` common to both directions."""
    num, den = plant.transfer_function()
    closed = np.polyadd(den, fv * num)
    return np.sort(np.roots(closed).real), float(num[-1] / closed[-1])


def first_order(work: Path):
    """viscous_axis with its fast pole dropped: the first-order axis of docs/identification.md."""
    text = (ROOT / "fmu_models" / "viscous_axis.toml").read_text()
    path = work / "viscous_axis_first_order.toml"
    path.write_text(text.replace("[[-4.0, 0.0], [-60.0, 0.0]]", "[[-4.0, 0.0]]")
                    .replace('name = "viscous_axis"', 'name = "viscous_axis_first_order"'))
    return load_plant(path)


def viscous_rows(truth_plant, data, label: str) -> list[str]:
    """Item 4 on one plant and data set: from the structure's own fv_pos (the truth) and from a structure that
    assumes fv_pos = 0 (fv_neg started at 0.25): the error of fv_pos − fv_neg, what G then holds against
    G/(1 + fv_pos·G), and the line the result prints."""
    fv = truth_plant.friction.values()
    true_diff, rows = fv["fv_pos"] - fv["fv_neg"], []
    for start, structure in (("structure's fv_pos", truth_plant),
                             ("fv_pos = 0 assumed", with_values(truth_plant, fv_pos=0.0, fv_neg=0.25))):
        est = fit(structure, data)
        fitted = est.result().plant
        got = fitted.friction.values()
        diff = got["fv_pos"] - got["fv_neg"]
        poles, dc = absorbed(truth_plant, fv["fv_pos"] - structure.friction.values()["fv_pos"])
        held = np.sort(np.real(fitted.all_poles()))
        rows.append(f"| {truth_plant.name} (order {truth_plant.order}) | {label} | {start} | {diff:.9g} | "
                    f"{abs(diff / true_diff - 1):.1e} | {', '.join(f'{p:.6g}' for p in held)} (G/(1 + fv·G): "
                    f"{', '.join(f'{p:.6g}' for p in poles)}) | {fitted.dc_gain:.6g} ({dc:.6g}) | "
                    f"{viscous_note(got, viscous_damping(fitted))} |")
        print(rows[-1], file=sys.stderr, flush=True)
    return rows


def viscous_section(work: Path, measured_sines) -> list[str]:
    """Item 4: fv_pos − fv_neg and what G holds, on the shipped second-order axis and its first-order variant."""
    lines = ["## viscous_axis: fv_pos − fv_neg and what G holds", "",
             "| plant | data | start | fv_pos − fv_neg (truth −0.2) | relative error | fitted poles (expected) | "
             "fitted G(0) (expected) | the result's line |", "|---|---|---|---|---|---|---|---|"]
    for plant in (load_plant("viscous_axis"), first_order(work)):
        truth = truth_of(plant)
        lines += viscous_rows(plant, record_data(plant, truth), "record (multisine, both ways)")
        if plant.name == "viscous_axis":
            lines += viscous_rows(plant, measured_sines, "stepped sines")
    return lines + [""]


def run_plant(name: str, work: Path, seeds: int, starts: int, lines: list, summary: list) -> None:
    t0 = time.perf_counter()
    plant = load_plant(name)
    truth, names = truth_of(plant), identified_names(plant)
    fmu, data_file = work / f"{name}.fmu", work / f"{name}.h5"
    if not data_file.exists():
        build_fmu(plant, fmu, overwrite=True)
        measure(fmu, data_file, run=RunOptions(workers=0))
    measured = read_data_file(data_file)
    sines = sine_data(measured)
    t_measure = time.perf_counter() - t0
    est_sines, est_record = fit(plant, sines), fit(plant, record_data(plant, truth))
    err_sines, err_record = worst_relative(est_sines.theta_, truth), worst_relative(est_record.theta_, truth)
    print(f"{name}: measured {t_measure:.0f} s; noise-free sines {err_sines:.2e} ({est_sines.seconds_:.1f} s), "
          f"record {err_record:.2e} ({est_record.seconds_:.1f} s)", file=sys.stderr, flush=True)

    covered, seconds = [], []
    for seed in range(seeds):
        est = fit(plant, noisy_sines(measured, seed), seed)
        covered.append(covers(est.intervals_, truth))
        seconds.append(est.seconds_)
    covered = np.array(covered, dtype=bool).reshape(seeds, len(truth))
    print(f"{name}: {seeds} noisy seeds, {covered.sum()} of {covered.size} cover", file=sys.stderr, flush=True)

    drawn = sample_identified(plant, starts, WIDER, np.random.default_rng(20261127))
    found, worst, restarted, misses = 0, 0.0, 0, []
    for k in range(starts):
        est = fit(plant.with_parameters(full_vectors(plant, drawn[k][None])[0]), sines, k)
        w = worst_relative(est.theta_, truth)
        found, worst, restarted = found + (w < WITHIN), max(worst, w), restarted + (est.restarts_ > 0)
        if w >= WITHIN:
            misses.append(miss_line(k, names, drawn[k], est, truth))
    print(f"{name}: {found} of {starts} starts within {WITHIN:g}", file=sys.stderr, flush=True)

    plan = measured.plan
    lines += [f"## {name}", "",
              f"Plan: {', '.join(f'{a:g}' for a in plan.amplitudes)} N × {', '.join(f'{f:g}' for f in plan.frequencies)} Hz "
              f"({len(sines.frequencies) if hasattr(sines, 'frequencies') else '?'} experiments used). "
              f"Identified: {', '.join(names)}.", "",
              f"- Noise-free, from the structure file: stepped sines worst relative error {err_sines:.2e} "
              f"({est_sines.seconds_:.1f} s), record {err_record:.2e} ({est_record.seconds_:.1f} s).",
              f"- 40 dB, {seeds} seeds (median fit {np.median(seconds) if seeds else math.nan:.1f} s): "
              f"{covered.sum()} of {covered.size} intervals contain the truth "
              f"({binomial(int(covered.sum()), covered.size) if covered.size else 'n/a'}).",
              f"- Wider prior, {starts} starts: {found} of {starts} within {WITHIN:g} (worst {worst:.2e}; "
              f"{restarted} restarted)."] + misses + ["",
              "| parameter | truth | intervals containing the truth |", "|---|---|---|"]
    for k, n in enumerate(names):
        lines.append(f"| {n} | {truth[k]:.6g} | {covered[:, k].sum()} of {seeds} "
                     f"({binomial(int(covered[:, k].sum()), seeds) if seeds else 'n/a'}) |")
    lines.append("")
    if "fv_pos" in plant.friction.values():
        lines += viscous_section(work, sines)
    summary.append(f"| {name} | {len(names)} | {err_sines:.1e} | {err_record:.1e} | "
                   f"{covered.sum()} of {covered.size} ({binomial(int(covered.sum()), covered.size) if covered.size else 'n/a'}) | "
                   f"{found} of {starts} | {time.perf_counter() - t0:.0f} |")
    print(f"{name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", default=PLANTS)
    ap.add_argument("--seeds", default="20", help="noise seeds at 40 dB (one, or one per plant)")
    ap.add_argument("--starts", default="50", help="random starts from the wider prior (one, or one per plant)")
    ap.add_argument("--work", type=Path, help="folder for the FMUs and measurements (kept; default a temporary one)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench-laws.md")
    args = ap.parse_args()
    lines, summary = [], []
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        plants = args.plants.split(",")
        seeds, starts = counts(args.seeds, plants), counts(args.starts, plants)
        for name in plants:
            run_plant(name, work, seeds[name], starts[name], lines, summary)
            args.out.write_text("\n".join(head(args) + summary + [""] + lines))  # a long run keeps what it has
    print(f"wrote {args.out}")


def head(args) -> list[str]:
    """The page's title, provenance and summary table head."""
    return ["# Identification of the newer friction laws", "",
            f"Generated by `scripts/bench_laws.py --plants {args.plants} --seeds {args.seeds} --starts {args.starts}` "
            f"on {date.today()} ({platform.machine()}, {platform.python_version()}, one thread). What is measured: "
            "the script's docstring.", "",
            "| plant | identified | noise-free sines: worst rel. error | noise-free record: worst rel. error | "
            "40 dB: intervals containing the truth | wider prior: within 1e-3 | seconds |",
            "|---|---|---|---|---|---|---|"]


if __name__ == "__main__":
    main()
