"""A broadband measurement of a plant file simulated without an FMU (the batch simulator the identification uses):
for studies over many seeds and for tests, where building and running an FMU per seed would cost seconds each.

The same experiment as servofmu.broadband.measure: the plan's whole signal from rest in one run, the input held
for one sample, output sample k the velocity at k/rate, white Gaussian noise at ``noise_snr_db`` (σ² = var(v over
the whole run)/10^(SNR/10), from a numpy Generator seeded with (seed, 0xB0AD)).
"""
from __future__ import annotations

import math

import numpy as np

from ..model.plant import Plant
from ..simulation.batch import BatchSimulator
from .bla import estimate_bla, split_periods
from .signals import BroadbandPlan
from .store import BroadbandLevel, write_broadband

__all__ = ["simulate_broadband", "write_simulated"]


def simulate_broadband(plant: Plant, plan: BroadbandPlan, noise_snr_db: float | None = None, seed: int = 0,
                       rtol: float = 1e-10) -> list[BroadbandLevel]:
    """Per level of ``plan``: the records of ``plant`` and their BLA (of the noisy output when there is noise)."""
    u = plan.signals()
    t = np.arange(u.size) / plan.rate
    v = BatchSimulator(plant).simulate_record(plant.parameter_vector()[None], t, u.ravel(), hold="zoh",
                                              rtol=rtol).v[0].reshape(u.shape)
    noisy = None
    if noise_snr_db is not None:
        rng = np.random.default_rng([seed, 0xB0AD])
        noisy = v + math.sqrt(float(np.var(v)) / 10 ** (noise_snr_db / 10)) * rng.standard_normal(v.shape)
    out = []
    for i, level in enumerate(plan.levels):
        y = v[i] if noisy is None else noisy[i]
        cut = [split_periods(x, plan.samples, plan.periods, plan.transient_periods) for x in (u[i], y)]
        out.append(BroadbandLevel(level, u[i], v[i], None if noisy is None else noisy[i],
                                  estimate_bla(*cut, plan.lines, plan.rate, plan.free_lines)))
    return out


def write_simulated(path, plant: Plant, plan: BroadbandPlan, noise_snr_db: float | None = None, seed: int = 0):
    """:func:`simulate_broadband` written as a data file of kind broadband (its parameters the plant's)."""
    levels = simulate_broadband(plant, plan, noise_snr_db, seed)
    provenance = {"plant": plant.name, "simulated": "servofmu.broadband.simulate", "noise_snr_db":
                  float("nan") if noise_snr_db is None else float(noise_snr_db), "seed": seed}
    return write_broadband(path, plan, levels, provenance, plant.parameters())
