"""Machine time against accuracy: the Cramér–Rao bound of the default stepped-sine plan and of the default broadband
plan, per parameter, and the broadband experiment time that would reach the stepped sine's bound.

    python scripts/bench_machine_time.py STEPPED.h5:PLANT [STEPPED.h5:PLANT ...]

STEPPED.h5: `servofmu measure PLANT.fmu --noise-snr 40` (the default plan).  For each:

- stepped sine: the bound of its converged experiments (servofmu.identification.cramer_rao.sine_fisher_information,
  noise on each experiment's window samples at 40 dB of that window's velocity, as scripts/bench_cramer_rao.py),
  and its machine time: every experiment's run to the end of its window, converged or not;
- broadband: the default plan (2.0 and 0.6 N RMS, 0.2–50 Hz, period 5 s, 1 + 2 periods, 4 realisations, odd-random,
  1000 Hz: 120 s), simulated noise-free; the bound of the output-error fit of its records
  (time_domain_fisher_information, white noise at 40 dB of the velocity over the whole run, as measure adds it);
- the stepped sine's bound again with the broadband run's absolute σ on every window (one sensor for both: 40 dB per
  window makes the noise of every experiment as small as its response, which a sensor does not);
- the same for a broadband design on 0.2–10 Hz (the power where these plants' poles are);
- the broadband time to reach the stepped sine's bound: 120 s × (bound_bb / bound_ss)² (the bound falls as
  1/√time with more periods or realisations of the same plan), and its ratio to the stepped sine's machine time.

The bound assumes the model's own noise (white, on the output) and a response smooth in the parameters; where the
response is chaotic (g2's limit cycle) the bound is not a statement about any estimator.
"""
from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np

from servofmu.broadband import BroadbandPlan
from servofmu.broadband.simulate import simulate_broadband
from servofmu.broadband.store import BroadbandData
from servofmu.identification.broadband_identify import broadband_records
from servofmu.identification.cramer_rao import (cramer_rao_bound, sine_fisher_information,
                                                time_domain_fisher_information)
from servofmu.identification.criterion import RecordCriterion, sine_data
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.measurement.datafile import read_data_file
from servofmu.model.plant import load_plant
from servofmu.simulation.batch import BatchSimulator

SNR_DB = 40.0
PLAN = BroadbandPlan("multisine", (2.0, 0.6), (0.2, 50.0), 1000.0, period=5.0, periods=2, transient_periods=1,
                     realisations=4)
DESIGNS = {"default, 0.2–50 Hz": PLAN, "0.2–10 Hz": replace(PLAN, band=(0.2, 10.0))}


def stepped(path: str, plant, absolute: float | None = None):
    """The stepped sine's bound with 40 dB of each window's velocity, or white noise ``absolute`` (m/s) on every
    window (the same sensor as the broadband run's)."""
    truth = plant.parameter_vector()[identified_mask(plant)]
    measured = read_data_file(path)
    seconds = sum(float(e.window.time[-1]) for e in measured.experiments)
    exps = [e for e in measured.experiments if e.converged]
    sigma = {e.index: math.sqrt(float(np.var(e.window.v))) / 10 ** (SNR_DB / 20) if absolute is None else absolute
             for e in exps}
    clean = sine_data(replace(measured, experiments=tuple(exps)))
    noise = np.array([sigma[e.index] * math.sqrt(2 / (e.samples_per_period * e.window_periods)) / abs(e.U1 * e.H)
                      for e in exps])
    fisher, jac = sine_fisher_information(plant, replace(clean, noise=noise), truth, threads=1)
    return cramer_rao_bound(fisher, jac), seconds, len(exps), len(measured.experiments)


def broadband(plant, plan):
    truth = plant.parameter_vector()[identified_mask(plant)]
    levels = simulate_broadband(plant, plan)
    data = BroadbandData(path="simulated", plan=plan, levels=tuple(levels))
    records = broadband_records(data)
    sigma = float(np.std(records.records[0].y)) / 10 ** (SNR_DB / 20)
    crit = RecordCriterion(plant, records, BatchSimulator(plant, threads=1))
    fisher, jac = time_domain_fisher_information(crit, truth, [sigma])
    seconds = len(plan.levels) * plan.realisations * (plan.periods + plan.transient_periods) * plan.period
    return cramer_rao_bound(fisher, jac), seconds, sigma


def main(cases) -> None:
    for case in cases:
        path, name = case.split(":")
        plant = load_plant(name)
        truth = plant.parameter_vector()[identified_mask(plant)]
        ss, ss_seconds, used, total = stepped(path, plant)
        for design, plan in DESIGNS.items():
            bb, bb_seconds, sigma = broadband(plant, plan)
            same, _, _, _ = stepped(path, plant, absolute=sigma)
            print(f"\n{name}, broadband {design}: stepped sine {ss_seconds:.0f} s of machine time ({used} of {total} "
                  f"experiments at steady state), broadband {bb_seconds:.0f} s; 40 dB (broadband: σ = {sigma:.3g} m/s "
                  "on every sample)\n")
            print("| parameter | truth | stepped sine, 40 dB per window | stepped sine, the broadband's σ | "
                  "broadband | broadband time to the stepped sine's bound, 40 dB per window / same σ (share of its "
                  "time) |\n|---|---|---|---|---|---|")
            for n, t, a, c, b in zip(identified_names(plant), truth, ss, same, bb):
                need = [bb_seconds * (b / x) ** 2 if np.isfinite(x) and x > 0 else math.inf for x in (a, c)]
                print(f"| {n} | {t:.6g} | {a / abs(t):.3g} | {c / abs(t):.3g} | {b / abs(t):.3g} | "
                      f"{need[0]:.3g} s ({need[0] / ss_seconds:.2f}) / {need[1]:.3g} s ({need[1] / ss_seconds:.2f}) |")


if __name__ == "__main__":
    main(sys.argv[1:])
