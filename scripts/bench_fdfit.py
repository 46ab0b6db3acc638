"""The frequency-domain fit of G(s) over seeds, in numbers pasted into docs/broadband.md ("Fitting G(s)").

For g2 and stribeck_servo with their friction set to zero (linear plants), 40 dB output noise, the default plan
(one level 2 N RMS, band 0.2–50 Hz, period 5 s, 1 + 2 periods, 4 realisations, odd-random grid, 1000 Hz), 20
seeds, simulated without an FMU (servofmu.broadband.simulate):

1. the BLA: the share of the lines at which its ±2σ band and its 95 % band (σ its total standard deviation) hold the true
   zero-order-hold response, and its noise variance over the true one (4σ_v²/(N·P·M·|U|²), white noise σ_v);
2. the fit (servofmu.identification.frequency_fit): per parameter, the share of seeds whose 95 % interval holds
   the truth, the RMS error over the mean standard deviation the fit claims, the cost over its degrees of freedom,
   and the fit's time; started from the structure scaled by 1.3 (G's parameters) so that the start is not the truth.
3. with friction (g1, g2, stribeck_servo as shipped, both levels 2.0 and 0.6 N RMS): the cost per level and the
   frequency-domain G against the true G — the bias the friction puts on a linear fit of the BLA.
4. closed loop, a synthetic drive log (G = 1/(s + 10) behind a zero-order hold at 1 kHz, a velocity loop
   u = 30·(r − y), white reference, coloured output noise fed back by the loop; 40 000 samples, 20 seeds): the
   share of the frequencies with γ²_ru ≥ 0.9 where the estimate from the reference holds the true G within its
   ±2σ, and where the direct estimate does, with its median deviation below 5 Hz.

Usage: python scripts/bench_fdfit.py [SEEDS]
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from servofmu.broadband import BroadbandPlan
from servofmu.broadband.bla import closed_loop_estimate, h1_estimate
from servofmu.broadband.simulate import simulate_broadband
from servofmu.identification.frequency_fit import fit_bla, g_names, linear_response
from servofmu.model.plant import load_plant

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_closed_loop_frf import GAIN, POLE, RATE, loop_log  # noqa: E402  (the test's velocity loop)

PLAN = dict(band=(0.2, 50.0), rate=1000.0, period=5.0, periods=2, transient_periods=1, realisations=4)


def frictionless(name: str):
    plant = load_plant(name)
    levels = {k: 0.0 for k in ("fc_pos", "fc_neg", "fs_pos", "fs_neg") if getattr(plant.friction, k) is not None}
    return replace(plant, friction=replace(plant.friction, **levels))


def perturbed(plant, factor=1.3):
    vector, names = plant.parameter_vector(), plant.parameter_names()
    for n in g_names(plant):
        vector[names.index(n)] *= factor
    return plant.with_parameters(vector)


def coverage(name: str, seeds: int) -> None:
    truth = frictionless(name)
    plan = BroadbandPlan("multisine", (2.0,), **PLAN)
    band_cover, band95_cover, noise_ratio, inside, errors, sds, costs, seconds = [], [], [], [], [], [], [], []
    values = truth.parameters()
    for seed in range(seeds):
        plan = replace(plan, seed=seed)
        (lv,) = simulate_broadband(truth, plan, noise_snr_db=40.0, seed=seed)
        b = lv.bla
        g = linear_response(truth, truth.parameter_vector(), b.frequencies, plan.rate)
        band_cover.append(np.mean(np.abs(b.G - g) <= 2 * b.std_total))
        band95_cover.append(np.mean(np.abs(b.G - g) <= b.band_factor() * b.std_total))
        sigma_v = np.sqrt(np.var(lv.v) / 1e4)
        true_var = 4 * sigma_v ** 2 / (plan.samples * plan.periods * plan.realisations * b.U ** 2)
        noise_ratio.append(np.mean(b.var_noise) / np.mean(true_var))
        t0 = time.perf_counter()
        fit = fit_bla(perturbed(truth), [b], plan.rate)
        seconds.append(time.perf_counter() - t0)
        t = np.array([values[n] for n in fit.names])
        inside.append((fit.intervals[:, 0] <= t) & (t <= fit.intervals[:, 1]))
        errors.append(fit.theta - t)
        sds.append(np.sqrt(np.diag(fit.covariance)))
        costs.append(fit.cost_ratio)
    inside, errors, sds = np.array(inside), np.array(errors), np.array(sds)
    print(f"\n{name}, friction 0, 40 dB, {seeds} seeds, {b.frequencies.size} lines: BLA ±2σ band holds the true G at "
          f"{100 * np.mean(band_cover):.1f} % of the lines (seeds {100 * np.min(band_cover):.0f}–"
          f"{100 * np.max(band_cover):.0f} %), its 95 % band (±{b.band_factor():.3g}σ, BLA.band_factor) at "
          f"{100 * np.mean(band95_cover):.1f} % (seeds {100 * np.min(band95_cover):.0f}–{100 * np.max(band95_cover):.0f}"
          f" %); noise variance estimated / true {np.mean(noise_ratio):.3f} "
          f"(seeds {np.min(noise_ratio):.3f}–{np.max(noise_ratio):.3f}); fit cost/dof {np.mean(costs):.3f}; "
          f"fit {np.median(seconds) * 1e3:.0f} ms (median)\n")
    print("| parameter | truth | 95 % interval holds the truth | RMS error / mean claimed σ |\n|---|---|---|---|")
    for i, n in enumerate(fit.names):
        rms = np.sqrt(np.mean(errors[:, i] ** 2))
        print(f"| {n} | {values[n]:.6g} | {inside[:, i].sum()}/{seeds} | {rms / np.mean(sds[:, i]):.2f} |")


def bias() -> None:
    print("\n| plant | level (N RMS) | cost/dof | G from the BLA of this level | true G |\n|---|---|---|---|---|")
    for name in ("g1", "g2", "stribeck_servo"):
        truth = load_plant(name)
        plan = BroadbandPlan("multisine", (2.0, 0.6), **PLAN)
        for lv in simulate_broadband(truth, plan, noise_snr_db=40.0, seed=0):
            fit = fit_bla(truth, [lv.bla], plan.rate)
            values = truth.parameters()
            got = ", ".join(f"{n} {v:.4g}" for n, v in zip(fit.names, fit.theta))
            want = ", ".join(f"{n} {values[n]:.4g}" for n in fit.names)
            print(f"| {name} | {lv.level:g} | {fit.cost_ratio:.3g} | {got} | {want} |")


def closed_loop(seeds: int, n: int = 40000) -> None:
    rate, pole, gain = RATE, POLE, GAIN
    ref_in, direct_in, direct_dev = [], [], []
    for seed in range(seeds):
        r, u, y = loop_log(n, seed)  # the test's loop (tests/test_closed_loop_frf.py), one log per seed
        cl = closed_loop_estimate(r, u, y, rate, n // 32, (1.0, 200.0))
        d = h1_estimate(u, y, rate, n // 32, (1.0, 200.0))
        g = gain / (np.exp(2j * np.pi * cl.frequencies / rate) - pole)
        good = cl.coherence_ru >= 0.9
        ref_in.append(np.mean((np.abs(cl.G - g) <= 2 * np.sqrt(cl.var))[good]))
        direct_in.append(np.mean((np.abs(d.G - g) <= 2 * np.sqrt(d.var))[good]))
        low = cl.frequencies < 5
        direct_dev.append(np.median(np.abs(d.G[low] / g[low] - 1)))
    print(f"\nclosed loop, {seeds} seeds: at the frequencies with γ²_ru ≥ 0.9, the true G within ±2σ of the estimate "
          f"from the reference at {100 * np.mean(ref_in):.1f} % (seeds {100 * np.min(ref_in):.0f}–"
          f"{100 * np.max(ref_in):.0f} %), of the direct estimate at {100 * np.mean(direct_in):.1f} %; the direct "
          f"estimate's median deviation below 5 Hz {100 * np.mean(direct_dev):.0f} %")


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    for plant in ("g2", "stribeck_servo"):
        coverage(plant, n)
    bias()
    closed_loop(n)
