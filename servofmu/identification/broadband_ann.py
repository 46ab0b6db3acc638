"""The network's features of broadband data (docs/broadband.md, "The ANN on broadband data"): the paper's first
stage — a network mapping measured responses to the parameters — on a broadband measurement.

A stepped-sine plan gives the network H and the mean velocity at each (amplitude, frequency); a broadband plan
gives, per RMS level, the BLA at hundreds of lines, too many inputs for a network trained on a few thousand plants
and each too noisy alone.  So the lines of every level are averaged in BINS bands, log-spaced over the excited
lines: the features of one band are those of one stepped-sine experiment (ann_features: log|H|, cos∠H, sin∠H,
dc/(|H|·level)) at the level's RMS as its amplitude and the band's geometric-mean frequency, with H the band's mean
BLA and dc the level's mean velocity over its analysed periods (asymmetric friction moves it).  The result is a
SineData of those pseudo-experiments: the training set, the network's layout (plan rows: levels, band frequencies)
and the identifier's first stage read it as they read stepped-sine data.  The training set simulates every drawn
plant under the measurement's whole plan from rest, noise-free, and takes the same BLA and bands
(simulate_chunk), so the measured and the simulated features are one function of the records.
"""
from __future__ import annotations

import numpy as np

from ..broadband.bla import estimate_bla, split_periods
from .criterion import SineData

__all__ = ["BINS", "band_edges", "banded", "broadband_sine_data", "simulate_chunk"]

# bands per level: a few per decade of the default 0.2–50 Hz band (g1's pole at 1.6 Hz, stribeck_servo's at
# 0.8 and 6.4 Hz each fall in their own), 12 pseudo-experiments over two levels
BINS = 6


def band_edges(frequencies: np.ndarray) -> np.ndarray:
    """BINS + 1 log-spaced edges (Hz) spanning the excited lines' ``frequencies``."""
    f = np.asarray(frequencies, float)
    return np.geomspace(f.min(), f.max() * (1 + 1e-9), min(BINS, f.size) + 1)


def banded(frequencies: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(band frequencies, mean G per band) of a BLA's lines; a band without a line is left out."""
    f = np.asarray(frequencies, float)
    which = np.clip(np.searchsorted(band_edges(f), f, side="right") - 1, 0, None)
    bands = [b for b in np.unique(which)]
    centres = np.array([np.exp(np.mean(np.log(f[which == b]))) for b in bands])
    return centres, np.array([np.mean(G[which == b]) for b in bands])


def _pseudo(levels, frequencies, blas, dcs, source: str, noisy: bool) -> SineData:
    amps, freqs, H, dc = [], [], [], []
    for level, G, mean_v in zip(levels, blas, dcs):
        centres, means = banded(frequencies, G)
        amps += [level] * centres.size
        freqs += list(centres)
        H += list(means)
        dc += [mean_v] * centres.size
    return SineData(amplitudes=np.array(amps, float), frequencies=np.array(freqs, float), H=np.array(H, complex),
                    dc=np.array(dc, float), noisy=noisy, source=source, skipped=0)


def broadband_sine_data(data) -> SineData:
    """The network's pseudo-experiments of a broadband data file (servofmu.broadband.store.BroadbandData): per level
    and band, the mean of the stored BLA and the level's mean (noisy, where the file has it) velocity over its
    analysed periods."""
    plan = data.plan
    dcs = []
    for lv in data.levels:
        y = lv.v if lv.v_noisy is None else lv.v_noisy
        dcs.append(float(np.mean(split_periods(y, plan.samples, plan.periods, plan.transient_periods))))
    return _pseudo(plan.levels, data.levels[0].bla.frequencies, [lv.bla.G for lv in data.levels], dcs,
                   str(data.path), any(lv.v_noisy is not None for lv in data.levels))


def simulate_chunk(simulator, item):
    """Worker task of a training set on a broadband plan: (H, dc, converged) of the pseudo-experiments of each
    parameter set (full vectors) of a chunk, each plant simulated from rest under the whole plan, noise-free; a run
    that fails (NaN) not converged."""
    params, plan, rtol = item
    u = plan.signals()
    t = np.arange(u.size) / plan.rate
    v = simulator.simulate_record(params, t, u.ravel(), hold="zoh", rtol=rtol).v.reshape(len(params), *u.shape)
    H, dc, ok = [], [], []
    for run in v:
        finite = bool(np.all(np.isfinite(run)))
        run = np.nan_to_num(run)
        blas, dcs = [], []
        for i in range(len(plan.levels)):
            cut = [split_periods(x, plan.samples, plan.periods, plan.transient_periods) for x in (u[i], run[i])]
            blas.append(estimate_bla(*cut, plan.lines, plan.rate, plan.free_lines))
            dcs.append(float(np.mean(cut[1])))
        sd = _pseudo(plan.levels, blas[0].frequencies, [b.G for b in blas], dcs, "", False)
        H.append(sd.H)
        dc.append(sd.dc)
        ok.append(np.full(sd.H.size, finite))
    return np.array(H), np.array(dc), np.array(ok)
