"""Benchmark of `servofmu select` (docs/bench-select.md): on records of known plants at 40 dB, how often the true
structure is ranked first, how often a structure with more parameters than the truth is chosen, and how long a
selection over the default candidate set takes.

Plants: every friction law (Coulomb, Stribeck, LuGre), with and without viscous friction, G of order 1, 2 and 3
and one with a zero.  The truth of a plant with viscous friction is its law and order with fv = 0: the viscous
force is absorbed exactly by a G of the same order (docs/selection.md), so no data can tell it apart.

Per plant and seed: a 20 s record at 100 Hz (two magnitudes, two tones each, random phases) to fit and another
to validate on, white noise on the velocity at 40 dB; `select` over the default candidates (15: 3 laws x
orders 1-3, with and without a zero; where the plant format has load terms, the second stage adds each to the
structure ranked first, and a plant with a constant load offset is benchmarked too: its truth is Coulomb at order
1, whose levels fc+ − offset and fc− + offset are the same forces — docs/selection.md — one with a spring and
two with a position ripple, of order 1 and 2).  The newer laws' plants: direction-dependent viscous friction and
the Stribeck curve's shape exponent δ (friction terms of the second stage), Dahl and Maxwell-slip friction (laws
named with the default ones, LAWS_NAMED).  One plant in closed loop: a cogging axis in the example drive's
loop, 8 s records of strokes with position and command noise, selected with --closed-loop.

    python scripts/bench_select.py --seeds 20              # the full benchmark
    python scripts/bench_select.py --seeds 3 --plants coulomb1,coulomb3  # a smaller one
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import servofmu as sf
from servofmu.measurement.records import import_records
from servofmu.identification.prior import identified_names
from servofmu.model.laws.registry import default_laws
from servofmu.model.plant import plant_from_dict
from servofmu.runtime import RunOptions, cache_dir
from servofmu.selection.candidates import default_candidates, supported_load_terms
from servofmu.simulation.batch import BatchSimulator

DT, DURATION, SNR_DB = 0.01, 20.0, 40.0


def _plant(name, poles, zeros, dc, friction):
    return plant_from_dict({"name": name, "linear": {"poles": poles, "zeros": zeros, "dc_gain": dc},
                            "friction": friction})


# name -> (plant, true candidate name, input scale)
PLANTS = {
    "coulomb1": (sf.load_plant("g1"), "coulomb/1", 1.0),
    "coulomb1_fv": (_plant("coulomb1_fv", [[-10.0, 0.0]], [], 1.0,
                           {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4, "fv": 1.0}), "coulomb/1", 1.0),
    "coulomb2z": (_plant("coulomb2z", [[-4.0, 20.0], [-4.0, -20.0]], [[-6.0, 0.0]], 1.2,
                         {"model": "coulomb", "fc_pos": 0.3, "fc_neg": 0.25}), "coulomb/2z", 1.0),
    "coulomb3": (sf.load_plant("g2"), "coulomb/3", 2.0),
    "stribeck2": (_plant("stribeck2", [[-5.0, 0.0], [-40.0, 0.0]], [], 2.0,
                         {"model": "stribeck", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.45, "fs_neg": 0.35,
                          "vs": 0.05}), "stribeck/2", 1.0),
    "stribeck2_fv": (sf.load_plant("stribeck_servo"), "stribeck/2", 1.0),
    "lugre1_fv": (sf.load_plant("lugre_servo"), "lugre/1", 1.0),
}
if "offset" in supported_load_terms():  # the plant format's [load] section
    PLANTS["coulomb1_offset"] = (plant_from_dict({
        "name": "coulomb1_offset", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
        "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}, "load": {"offset": 0.3}}),
        "coulomb/1", 1.0)  # the same forces as levels 0.2 and 0.7 without an offset (docs/selection.md)
if "stiffness" in supported_load_terms():  # a spring of 4 N/m on g1: 1 N at the records' 0.25 m of travel
    PLANTS["coulomb1_spring"] = (plant_from_dict({
        "name": "coulomb1_spring", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
        "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}, "load": {"stiffness": 4.0, "x0": 0.0}}),
        "coulomb+stiffness/1", 1.0)
if "ripple" in supported_load_terms():  # a ripple of 0.2 N and period 5 cm on g1: 14 periods over the travel
    PLANTS["coulomb1_ripple"] = (plant_from_dict({
        "name": "coulomb1_ripple", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
        "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4},
        "load": {"ripple_amplitude": 0.2, "ripple_period": 0.05, "ripple_phase": 0.7}}), "coulomb+ripple/1", 1.0)
    # a ripple of 0.15 N and period 4 cm on a second-order axis (stribeck2's G with Coulomb friction)
    PLANTS["coulomb2_ripple"] = (plant_from_dict({
        "name": "coulomb2_ripple", "linear": {"poles": [[-5.0, 0.0], [-40.0, 0.0]], "dc_gain": 2.0},
        "friction": {"model": "coulomb", "fc_pos": 0.3, "fc_neg": 0.25},
        "load": {"ripple_amplitude": 0.15, "ripple_period": 0.04, "ripple_phase": -1.1}}), "coulomb+ripple/2", 1.0)
# The newer laws' example plants (docs/friction.md): direction-dependent viscous friction and the Stribeck curve's
# shape exponent are friction terms of the default selection's second stage; Dahl and Maxwell-slip friction are
# laws a user names (LAWS_NAMED: the default candidates and theirs).
PLANTS.update({
    "viscous_axis": (sf.load_plant("viscous_axis"), "coulomb+fv_asym/2", 1.0),
    "stribeck_shaped": (sf.load_plant("stribeck_shaped"), "stribeck+delta/1", 1.0),
    # δ = 0.7 on an axis whose slow half moves within its Stribeck velocity (stribeck_shaped's, 0.04 m/s, is a
    # few percent of its speeds: the curve's shape shows only at the reversals)
    "stribeck_delta": (_plant("stribeck_delta", [[-6.0, 0.0]], [], 1.5,
                              {"model": "stribeck", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.6, "fs_neg": 0.5,
                               "vs": 0.15, "delta": 0.7}), "stribeck+delta/1", 1.0),
    "dahl_servo": (sf.load_plant("dahl_servo"), "dahl/1", 1.0),
    "gms_servo": (sf.load_plant("gms_servo"), "gms/1", 1.0),
})
LAWS_NAMED = {"dahl_servo": "dahl", "gms_servo": "gms"}


# Closed-loop plants: name -> (plant, true candidate name, controller); their records are the example drive's
# loop (fmu_models/axis_controller.toml, its encoder left out) following strokes, fitted with --closed-loop.
LOOP_PLANTS = {}
if "ripple" in supported_load_terms():  # tests/test_select.py's cogging axis: 12 N of 32 mm beside 40/32 N
    LOOP_PLANTS["axis_ripple_loop"] = (plant_from_dict({
        "name": "axis_ripple_loop", "linear": {"poles": [[-2.0, 0.0]], "gain": 0.01},
        "friction": {"model": "coulomb", "fc_pos": 40.0, "fc_neg": 32.0},
        "load": {"ripple_amplitude": 12.0, "ripple_period": 0.032, "ripple_phase": 0.3}}), "coulomb+ripple/1",
        "axis_controller")
LOOP_DURATION = 8.0


def excitation(t: np.ndarray, scale: float, rng: np.random.Generator) -> np.ndarray:
    """Two magnitudes, as the paper's tests: 2 N at 1 Hz with 0.6 N at 3.1 Hz, then 0.7 N at 0.6 Hz with 0.3 N at
    4.3 Hz (random phases), times ``scale``."""
    ph = rng.uniform(0, 2 * np.pi, 4)
    half = t < t[-1] / 2
    return scale * np.where(half, 2 * np.sin(2 * np.pi * t + ph[0]) + 0.6 * np.sin(2 * np.pi * 3.1 * t + ph[1]),
                            0.7 * np.sin(2 * np.pi * 0.6 * t + ph[2]) + 0.3 * np.sin(2 * np.pi * 4.3 * t + ph[3]))


def record(plant, path: Path, seed: int, scale: float) -> Path:
    """A 20 s velocity record of ``plant`` with white noise at SNR_DB, imported as a machine's record."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, DURATION, DT)
    u = excitation(t, scale, rng)
    v = BatchSimulator(plant).simulate_record(plant.parameter_vector()[None], t, u, rtol=1e-10).v[0]
    v = v + np.std(v) * 10 ** (-SNR_DB / 20) * rng.standard_normal(v.size)
    csv = path.with_suffix(".csv")
    np.savetxt(csv, np.column_stack([t, u, v]), delimiter=",", header="t,u,v", comments="")
    import_records([csv], path, "t", "u", "v")
    return path


def controller_file(folder: Path, name: str) -> Path:
    """The controller file ``name`` without its encoder (the records' position noise stands for it)."""
    from servofmu.model.controller import load_controller

    text = Path(load_controller(name).source).read_text().split("[encoder]")[0]
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


def loop_record(plant, controller: Path, path: Path, seed: int) -> Path:
    """A LOOP_DURATION closed-loop record of ``plant`` in the loop of ``controller``: strokes of 0.3 m at 0.5 Hz
    with a 1 cm tone at 3.1 Hz (random phase), 1 µm of position noise and 1 % of command noise, imported as a
    drive's log."""
    from servofmu.measurement.records import LoopChannels
    from servofmu.model.controller import load_controller
    from servofmu.simulation.closed_loop import LoopSimulator

    rng = np.random.default_rng(seed)
    law = load_controller(controller)
    t = np.arange(0.0, LOOP_DURATION, law.sample_time)
    f1, f2, phase = rng.uniform(0.4, 0.6), rng.uniform(2.5, 3.5), rng.uniform(0, 2 * np.pi)
    reference = 0.15 * (1 - np.cos(2 * np.pi * f1 * t)) + 0.01 * np.sin(2 * np.pi * f2 * t + phase)
    loop = LoopSimulator(plant).simulate_loop(plant.parameter_vector()[None], t, reference, law, rtol=1e-10)
    position = loop.position[0] + 1e-6 * rng.standard_normal(t.size)
    command = loop.command[0] + 0.01 * np.std(loop.command[0]) * rng.standard_normal(t.size)
    csv = path.with_suffix(".csv")
    np.savetxt(csv, np.column_stack([t, reference, position, command]), delimiter=",", header="t,ref,pos,cmd",
               comments="", fmt="%.17g")
    import_records([csv], path, "t", "cmd", "pos", kind="position", loop=LoopChannels(reference="ref"))
    return path


def _cpu() -> float:
    """CPU seconds of this process and its finished children (the worker processes)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _libraries() -> int:
    """How many compiled simulator libraries the cache holds."""
    folder = cache_dir()
    return sum(1 for p in folder.iterdir() if p.suffix == ".so") if folder.is_dir() else 0


def one(name: str, seed: int, folder: Path, workers: int, iterations: int | None, screen: bool = True) -> dict:
    if name in LOOP_PLANTS:
        plant, truth, controller = LOOP_PLANTS[name]
        controller = controller_file(folder, controller)
        fit = loop_record(plant, controller, folder / f"{name}-{seed}-fit.h5", 1000 * seed + 1)
        val = loop_record(plant, controller, folder / f"{name}-{seed}-val.h5", 1000 * seed + 2)
        options = sf.SelectOptions(seed=seed, iterations=iterations, closed_loop=str(controller))
    else:
        plant, truth, scale = PLANTS[name]
        fit = record(plant, folder / f"{name}-{seed}-fit.h5", 1000 * seed + 1, scale)
        val = record(plant, folder / f"{name}-{seed}-val.h5", 1000 * seed + 2, scale)
        named = [*default_laws(), LAWS_NAMED[name]] if name in LAWS_NAMED else None
        options = sf.SelectOptions(seed=seed, iterations=iterations, candidates=named)
    if "screen" in sf.SelectOptions.__dataclass_fields__:
        options = replace(options, screen=screen)
    libraries = _libraries()
    load, t0, cpu0 = os.getloadavg()[0], time.perf_counter(), _cpu()
    sel = sf.select_files([fit], val, folder / f"{name}-{seed}-select.h5", options,
                          RunOptions(workers=workers, overwrite=True))
    seconds, cpu = time.perf_counter() - t0, _cpu() - cpu0
    compiled = _libraries() - libraries
    by_name = {s.name: s for s in sel.scores}
    chosen = sel.chosen
    # a truth that no stage fitted: the parameters its plant identifies (the truth is the plant's structure then)
    truth_parameters = by_name[truth].parameters if truth in by_name else len(identified_names(plant))
    return {"plant": name, "seed": seed, "truth": truth, "chosen": chosen.name if chosen else None,
            "truth_rank": by_name[truth].rank if truth in by_name else None,
            "more_parameters": bool(chosen and chosen.parameters > truth_parameters),
            "failed": sum(s.status == "failed" for s in sel.scores), "seconds": seconds, "cpu_seconds": cpu,
            "compiled": compiled,  # simulator libraries the selection compiled (not in the cache yet)
            "load": [load, os.getloadavg()[0]], "fits": len(sel.scores),
            "screened": sum(getattr(s, "screened", False) for s in sel.scores),
            # the chosen fit's roughness (about 1 where regular), on all of the records and where the selection was
            # made again on their start (the share of them it was made on: 1 = all)
            "roughness": getattr(sel, "roughness", None), "roughness_whole": getattr(sel, "roughness_whole", None),
            "horizon": getattr(sel, "horizon", 1.0),
            "slowest": max((s.seconds, s.name) for s in sel.scores),
            "levels": [chosen.result.plant.friction.fc_pos, chosen.result.plant.friction.fc_neg]
            if chosen and chosen.result else None,
            # every candidate's scores, so that a ranking rule can be examined again without refitting
            "candidates": [{"name": s.name, "parameters": s.parameters, "bic": s.bic, "white": s.white,
                            "validation_neg2loglik": s.validation_neg2loglik, "flags": list(s.flags),
                            "validation_allowance": getattr(s, "validation_allowance", None),
                            "screened": bool(getattr(s, "screened", False)), "seconds": s.seconds}
                           for s in sel.scores]}


SENSITIVITY_STEP = 1e-4  # the relative change of a parameter in the sensitivity check (--sensitivity)


def sensitivity(name: str, seed: int, folder: Path) -> dict:
    """How far the true plant's response on its fit record moves when one identified parameter moves by
    SENSITIVITY_STEP (relative, a fraction of its standard error): the largest change of the velocity (in noise
    standard deviations) and of the position (in ripple periods where the plant has one, else in mm), over the
    parameters; and where the polish of ``select`` ends from the true values and from the true values each moved
    by SENSITIVITY_STEP (random signs): the difference of their BIC.  A regular axis moves by a fraction of the
    noise and the two polishes end alike; a chaotic one (a mass in a ripple's wells, driven: a forced pendulum)
    moves by whole periods, and the truth's minimum is a needle no polish from a start that far off reaches."""
    from servofmu.identification.prior import identified_mask
    from servofmu.selection.candidates import parse_candidates
    from servofmu.selection.data import load_selection_data
    from servofmu.selection.select import CandidateJob, fit_candidate

    plant, truth, scale = PLANTS[name]
    rng = np.random.default_rng(1000 * seed + 1)  # the fit record's input, as record() draws it
    t = np.arange(0, DURATION, DT)
    u = excitation(t, scale, rng)
    vector, columns = plant.parameter_vector(), np.flatnonzero(identified_mask(plant))
    columns = columns[vector[columns] != 0]
    rows = np.repeat(vector[None], 1 + columns.size, axis=0)
    rows[1 + np.arange(columns.size), columns] *= 1 + SENSITIVITY_STEP
    res = BatchSimulator(plant).simulate_record(rows, t, u, rtol=1e-10)
    noise = np.std(res.v[0]) * 10 ** (-SNR_DB / 20)
    dv = float(np.max(np.abs(res.v[1:] - res.v[0])) / noise)
    dx = float(np.max(np.abs(res.position[1:] - res.position[0])))
    fit = record(plant, folder / f"{name}-{seed}-fit.h5", 1000 * seed + 1, scale)
    data, _ = load_selection_data([fit], 0.0, None)
    moved = vector.copy()
    moved[columns] *= 1 + SENSITIVITY_STEP * np.random.default_rng(seed).choice([-1.0, 1.0], columns.size)
    candidate = parse_candidates([truth])[0]
    bics = [fit_candidate(None, CandidateJob(candidate, start, data, data, sf.SelectOptions(seed=seed), None, {},
                                             mode="refit")).bic
            for start in (plant, plant.with_parameters(moved))]
    period = plant.load.ripple_period
    return {"plant": name, "seed": seed, "velocity_noise": dv, "position_m": dx, "period_m": period,
            "bic_truth": bics[0], "bic_moved": bics[1]}


def sensitivity_report(rows: list[dict]) -> str:
    lines = [f"`scripts/bench_select.py --sensitivity`: each identified parameter of the true plant moved by "
             f"{SENSITIVITY_STEP:g} (relative) on the fit record; the largest change of the velocity and the position "
             "over the parameters, and the BIC of the polish (`select`'s, at the identifier's tolerances) from the "
             f"true values and from the true values all moved by {SENSITIVITY_STEP:g} (random signs).", "",
             "| plant | seed | velocity change (noise σ) | position change | polish from the truth: BIC | "
             f"from the truth moved by {SENSITIVITY_STEP:g}: BIC above |", "|---|---|---|---|---|---|"]
    for r in rows:
        position = (f"{r['position_m'] / r['period_m']:.3g} periods" if r["period_m"] else
                    f"{1e3 * r['position_m']:.3g} mm")
        lines.append(f"| {r['plant']} | {r['seed']} | {r['velocity_noise']:.3g} | {position} | {r['bic_truth']:.1f} | "
                     f"{r['bic_moved'] - r['bic_truth']:.1f} |")
    return "\n".join(lines)


def _median(rows: list[dict], key: str) -> str:
    values = [r[key] for r in rows if key in r]
    return f"{np.median(values):.1f}" if values else "—"


def _loads(rows: list[dict]) -> str:
    """The range of the 1-minute load averages at the selections' starts and ends."""
    values = [x for r in rows for x in r.get("load", [])]
    return f"{min(values):.1f}–{max(values):.1f}" if values else "—"


def report(rows: list[dict], args) -> str:
    lines = ["# Structure selection: the true structure ranked first?", "",
             f"Made by `scripts/bench_select.py --seeds {args.seeds}` on 2 cores, {args.workers} worker processes "
             "(the load average at each selection's start and end in the last column). Per plant and seed: one 20 s "
             "record at 100 Hz "
             f"to fit and one to validate on, {SNR_DB:g} dB white noise on the velocity, `select` over the default "
             f"{len(default_candidates())} candidates (3 laws × orders 1–3, with and without a zero; "
             f"swarm iterations: {args.iterations or 50}). A plant with viscous friction has as its truth its law "
             "and order (fv is absorbed by G exactly: docs/selection.md).", "",
             "| plant | truth | seeds | truth ranked first | more parameters than the truth chosen | "
             "chosen instead | failed fits | seconds per selection (median) | CPU seconds (median) | load |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:  # rows of earlier runs may name another member of the truth's class of equal structures
        r["truth"] = {**PLANTS, **LOOP_PLANTS}.get(r["plant"], (None, r["truth"]))[1]
    for name in dict.fromkeys(r["plant"] for r in rows):
        rs = [r for r in rows if r["plant"] == name]
        first = sum(r["chosen"] == r["truth"] for r in rs)
        over = sum(r["more_parameters"] for r in rs)
        others = sorted({r["chosen"] or "none" for r in rs if r["chosen"] != r["truth"]})
        lines.append(f"| {name} | {rs[0]['truth']} | {len(rs)} | {first} ({100 * first / len(rs):.0f} %) | "
                     f"{over} ({100 * over / len(rs):.0f} %) | {', '.join(others) or '—'} | "
                     f"{sum(r['failed'] for r in rs)} | {np.median([r['seconds'] for r in rs]):.1f} | "
                     f"{_median(rs, 'cpu_seconds')} | {_loads(rs)} |")
    first = sum(r["chosen"] == r["truth"] for r in rows)
    over = sum(r["more_parameters"] for r in rows)
    lines += ["", f"All: truth first in {first} of {len(rows)} selections ({100 * first / len(rows):.1f} %), more "
              f"parameters than the truth in {over} ({100 * over / len(rows):.1f} %).", ""]
    compiled = [r["compiled"] for r in rows if "compiled" in r]
    if compiled:
        lines += [f"Simulator libraries compiled (not yet in the cache): {sum(compiled)} in all, median "
                  f"{np.median(compiled):.0f} per selection; {sum(c == 0 for c in compiled)} selections compiled "
                  "none.", ""]
    levels = [r["levels"] for r in rows if r["plant"] == "coulomb1_offset" and r.get("levels")
              and r["chosen"] == "coulomb/1"]
    if levels:
        low, high = np.min(levels, axis=0), np.max(levels, axis=0)
        lines += [f"coulomb1_offset (fc± 0.5/0.4 N, offset 0.3 N) chosen as coulomb/1: its levels fc+ {low[0]:.3f}–"
                  f"{high[0]:.3f} N, fc− {low[1]:.3f}–{high[1]:.3f} N over {len(levels)} selections — the offset's "
                  "forces, 0.5 − 0.3 = 0.2 and 0.4 + 0.3 = 0.7 N.", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--plants", default=",".join([*PLANTS, *LOOP_PLANTS]))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--iterations", type=int)
    parser.add_argument("--no-screen", action="store_true", help="every candidate fitted at the full tolerance")
    parser.add_argument("-o", "--output", default="docs/bench-select.md")
    parser.add_argument("--json", help="also write every selection's row (JSON lines)")
    parser.add_argument("--from-json", help="make the report from the rows of an earlier run (JSON lines)")
    parser.add_argument("--sensitivity", action="store_true",
                        help="no selections: how far each plant's response moves with its parameters (sensitivity)")
    args = parser.parse_args()
    if args.from_json:
        rows = [json.loads(line) for line in Path(args.from_json).read_text().splitlines() if line.strip()]
        args.seeds = max(r["seed"] for r in rows) + 1
        Path(args.output).write_text(report(rows, args))
        print(report(rows, args))
        return
    unknown = [p for p in args.plants.split(",") if p not in PLANTS and p not in LOOP_PLANTS]
    if unknown:
        parser.error(f"unknown plant {unknown[0]!r}; the plants: {', '.join([*PLANTS, *LOOP_PLANTS])}")
    rows = []
    if args.sensitivity:
        if any(p in LOOP_PLANTS for p in args.plants.split(",")):
            parser.error("--sensitivity takes open-loop plants: " + ", ".join(PLANTS))
        with tempfile.TemporaryDirectory() as tmp:
            for name in args.plants.split(","):
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    rows.append(sensitivity(name, seed, Path(tmp)))
                    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
        Path(args.output).write_text(sensitivity_report(rows) + "\n")
        print(sensitivity_report(rows))
        return
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for name in args.plants.split(","):
                rows.append(one(name, seed, Path(tmp), args.workers, args.iterations, not args.no_screen))
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
                if args.json:
                    with open(args.json, "a") as f:
                        f.write(json.dumps(rows[-1]) + "\n")
    Path(args.output).write_text(report(rows, args))
    print(report(rows, args))


if __name__ == "__main__":
    main()
