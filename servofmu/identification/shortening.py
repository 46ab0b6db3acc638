"""Long records shortened for the work that need not see every sample: a swarm's particles and a selection's
ranking (docs/selection.md, long records).  Open-loop records go to the rate their input needs — input and output
through one linear-phase anti-aliasing filter, the input then linear between the kept samples — and what is still
longer than the budget to the first share of every record; a closed loop keeps its drive's rate (its delay and
velocity filter are samples) and is only cut in time.  The polish and the final fits use every sample."""
from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from .criterion import RecordData, RecordSeries, SineData

__all__ = ["first_share", "search_share", "shortened", "reduced_rate", "reduction_factor", "input_bandwidth",
           "fitted_total", "long_open_loop", "SEARCH_SAMPLES", "RATE_FACTOR", "INPUT_POWER", "KAISER_BETA"]


def first_share(data, share: float):
    """``data`` (records, open- or closed-loop) with every record cut after the first ``share`` of its fitted time
    span (every per-sample array of the record cut alike)."""
    def cut(r):
        t = r.time[r.fitted]
        n = int(np.searchsorted(r.time, t[0] + share * (t[-1] - t[0]), side="right"))
        arrays = {f.name: getattr(r, f.name) for f in fields(r)}
        return replace(r, **{k: a[:n] for k, a in arrays.items()
                             if isinstance(a, np.ndarray) and a.shape == r.time.shape})
    return replace(data, records=tuple(cut(r) for r in data.records))


# The samples of the fitted records a swarm's particles are scored on at most (search_share): a swarm finds the
# valley, which the polish on every sample then descends; 4000 is the length of the benchmark's records, whose
# selections the 20-seed benchmark measures (docs/bench-select.md)
SEARCH_SAMPLES = 4000


def search_share(data):
    """The records a swarm scores its particles on: where the records hold more than SEARCH_SAMPLES fitted samples
    in all (a drive's log at 1 kHz and beyond: the swarm's 510 simulations of every sample were most of a fit's
    time), open-loop records at the rate their input needs (reduced_rate), then the first share of every record's
    fitted span that holds SEARCH_SAMPLES; else ``data`` itself; stepped-sine data as it is."""
    return shortened(data, SEARCH_SAMPLES)


def fitted_total(data) -> int:
    """The fitted samples of every record of ``data`` together."""
    return sum(int(np.count_nonzero(r.fitted)) for r in data.records)


def shortened(data, samples: int):
    """``data`` with at most ``samples`` fitted samples in all: open-loop records first at a reduced rate
    (reduced_rate), then the first share of every record; ``data`` itself where it holds no more (stepped-sine
    data: always)."""
    if isinstance(data, SineData) or fitted_total(data) <= samples:
        return data
    data = reduced_rate(data)
    total = fitted_total(data)
    return data if total <= samples else first_share(data, samples / total)


# A reduced record keeps this many samples per period of the highest frequency its input needs (input_bandwidth):
# its simulation interpolates the input linearly between them, which errs by (2π/RATE_FACTOR)²/8 of a sine at that
# frequency (3e-3 at 40, on the band's last, weakest component: g1's 10 kHz record reduced to 100 Hz fitted the
# model within 1e-3 of the signal's RMS at 20 samples per period)
RATE_FACTOR = 40.0
# The share of the input's AC power below the input's bandwidth
INPUT_POWER = 0.999
# The anti-aliasing filter: scipy's polyphase resampler with a Kaiser window of this β (a flat pass band: the
# Chebyshev filter of scipy's decimate, run forward and backward, moved g1's response by 2 % in its band)
KAISER_BETA = 10.0


def input_bandwidth(u: np.ndarray, dt: float) -> float:
    """The frequency (Hz) below which INPUT_POWER of the input's power (its mean removed) lies."""
    power = np.abs(np.fft.rfft(u - np.mean(u))) ** 2
    cumulative = np.cumsum(power[1:])
    if not cumulative.size or cumulative[-1] <= 0:
        return 0.5 / dt
    k = int(np.searchsorted(cumulative, INPUT_POWER * cumulative[-1])) + 1
    return k / (u.size * dt)


def reduction_factor(record: RecordSeries) -> int:
    """How many of an open-loop record's samples make one of its reduced rate: the rate at least RATE_FACTOR times
    the input's bandwidth (1: no reduction)."""
    dt = float(np.median(np.diff(record.time)))
    return max(1, int((1.0 / dt) // (RATE_FACTOR * input_bandwidth(record.u, dt))))


def reduced_rate(data):
    """Open-loop records at the rate their input needs (reduction_factor): input and output low-passed below the
    reduced rate's Nyquist frequency by the same linear-phase filter (KAISER_BETA) and kept at every q-th sample,
    the input then linear between samples ("foh": a held input low-passed is no longer held).  The fit loses what
    the plant does above that band, where the input puts under 1e-3 of its power, and the noise there;
    closed-loop records as they are (the drive's loop runs at its own rate: its delay and filter are samples)."""
    if not isinstance(data, RecordData):
        return data
    out = []
    for r in data.records:
        q = reduction_factor(r)
        if q < 2 or r.time.size < 64 * q:
            out.append(r)
            continue
        keep = slice(0, None, q)
        n = r.time[keep].size
        out.append(replace(r, time=r.time[keep], u=_decimated(r.u, q)[:n], y=_decimated(r.y, q)[:n], hold="foh",
                           fitted=r.fitted[keep]))
    return replace(data, records=tuple(out))


def long_open_loop(data) -> RecordData | None:
    """Open-loop records of more than SEARCH_SAMPLES fitted samples at the rate their input needs (reduced_rate),
    or None: other data, short records, or an input whose band leaves no rate to reduce."""
    if not isinstance(data, RecordData) or fitted_total(data) <= SEARCH_SAMPLES:
        return None
    reduced = reduced_rate(data)
    return None if fitted_total(reduced) == fitted_total(data) else reduced


def _decimated(x: np.ndarray, q: int) -> np.ndarray:
    """``x`` low-passed and kept at every q-th sample from the first: the Kaiser-windowed sinc of
    scipy.signal.resample_poly(x, 1, q, window=("kaiser", KAISER_BETA), padtype="line") — 20·q + 1 taps, cut off at
    the reduced rate's Nyquist frequency, unit gain at 0 Hz, its delay compensated, the ends extended along the line
    through the first and last values — computed only at the kept samples (one product of a strided view of the
    record with the taps: the same numbers to rounding, tests/test_long_records.py, without importing
    scipy.signal, a second of identify's start on a quiet machine)."""
    x = np.asarray(x, dtype=float)
    half = 10 * q
    m = np.arange(-half, half + 1)
    taps = np.sinc(m / q) * np.kaiser(m.size, KAISER_BETA)
    taps /= taps.sum()
    line = np.linspace(x[0], x[-1], x.size)
    padded = np.concatenate([np.zeros(half), x - line, np.zeros(half)])
    kept = np.lib.stride_tricks.sliding_window_view(padded, m.size)[::q]
    return kept @ taps[::-1] + line[::q]
