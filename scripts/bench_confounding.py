"""Parameters the data does not separate: do the combinations a result says its data determines cover the truth?

On the drive-log axis of scripts/bench_quantiser.py (an incline's constant load force, Stribeck friction; a 1 µm
encoder and actuator noise 40 dB below the force command in the drive's loop) — its 4 s log, and a 5.5 s log that
rests 2 s first —, for each noise seed: the records
simulated as that benchmark makes them, fitted in the loop with the quantiser left out (on this axis it hardly
matters), the groups of parameters the result names as not separated (servofmu.identification.confounding), and for
each combination it calls determined, whether the truth's value of that combination lies within the printed ±.
Beside it, the coverage of the single parameters' own 95 % intervals over the same fits.

Usage: nice -n 10 python scripts/bench_confounding.py [--cases drive_axis,drive_axis_rest] [--seeds 20]
       [--out docs/bench-confounding.md]
"""
from __future__ import annotations

import argparse
import collections
import warnings
from pathlib import Path

import numpy as np
from bench_quantiser import CASES, log_maker

from servofmu.identification.confounding import confounded_groups
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import identified_names
from servofmu.runtime import available_cores


def run(name: str, seeds: int) -> list[str]:
    """The page's lines for one case."""
    plant, truth, force_noise, data = log_maker(name)
    names = identified_names(plant)
    covered, single, members, rows = [], [], collections.Counter(), []
    for seed in range(seeds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = PSOANNIdentifier(plant, method="pso", seed=seed, threads=1).fit(data(force_noise, seed, 0.0))
        single.append((est.intervals_[:, 0] <= truth) & (truth <= est.intervals_[:, 1]))
        groups = confounded_groups(names, est.theta_, est.covariance_, est.intervals_)
        for group in groups:
            members[", ".join(group.names)] += 1
            for combination in group.determined:
                coefficients = dict(combination.coefficients)
                true = sum(c * truth[names.index(n)] for n, c in coefficients.items())
                hit = abs(true - combination.value) <= combination.half_width
                covered.append(hit)
                rows.append(f"| {seed} | {combination.text()} | {true:.6g} | {'yes' if hit else '**no**'} |")
        if not groups:
            rows.append(f"| {seed} | (no group named) | | |")
        print(name, seed, len(groups), flush=True)
    n, hits = len(covered), int(np.sum(covered))
    se = np.sqrt(0.95 * 0.05 / max(n, 1))
    return [f"## {name}", "",
            f"{seeds} seeds. Determined combinations covering the truth: **{hits} of {n} ({100 * hits / max(n, 1):.1f} "
            f"%)** (a calibrated 95 % interval: 95 ± {196 * se:.1f} % at this count); the single parameters' "
            f"intervals over the same fits: {100 * np.mean(single):.1f} % ({int(np.sum(single))} of "
            f"{np.size(single)}).", "",
            "Groups named (members: seeds): " + "; ".join(f"{k}: {v}" for k, v in members.most_common()) + ".", "",
            "| seed | determined combination (as printed) | truth's value | covered |", "|---|---|---|---|", *rows,
            ""]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="drive_axis,drive_axis_rest",
                    help=f"comma-separated, of {', '.join(CASES)} (scripts/bench_quantiser.py)")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default="docs/bench-confounding.md")
    args = ap.parse_args()
    lines = ["# Parameters the data does not separate: the determined combinations against the truth", "",
             f"Made by `scripts/bench_confounding.py` on {available_cores()} cores. "
             + " ".join(__doc__.split("\n\n")[1].split()), ""]
    for name in args.cases.split(","):
        if name not in CASES:
            raise SystemExit(f"--cases: {name!r} is none of {', '.join(CASES)}")
        lines += run(name, args.seeds)
    Path(args.out).write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
