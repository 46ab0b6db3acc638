"""Long, fast records: an open-loop record at 10 kHz reduced to the rate its input needs (anti-aliased, the input
linear between the kept samples) replays the true plant as the full record does — against scipy's own
simulation, independent of servofmu's — and what a swarm or a ranking is given of long records is at most its
budget of samples; a closed loop is cut in time, never in rate."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import servofmu as sf
from servofmu.simulation.batch import BatchSimulator
from servofmu.identification.criterion import RecordData, RecordSeries
from servofmu.identification.shortening import (RATE_FACTOR, input_bandwidth, reduced_rate, reduction_factor,
                                                shortened)
from servofmu.identification.closed_loop import ClosedLoopData, ClosedLoopSeries
from servofmu.model.controller import load_controller

DT = 1e-4  # 10 kHz
FC_POS, FC_NEG, POLE, GAIN = 0.5, 0.4, -10.0, 10.0  # g1: G = 10/(s + 10), Coulomb 0.5/0.4 N, smoothed by tanh(v/1e-3)


def _input(t):
    return np.where(t < 5, 2 * np.sin(2 * np.pi * t) + 0.6 * np.sin(2 * np.pi * 3.1 * t),
                    0.7 * np.sin(2 * np.pi * 0.6 * t) + 0.3 * np.sin(2 * np.pi * 4.3 * t))


def _g1_velocity(t, u_of_t):
    """g1's velocity for a continuous input, by scipy's LSODA (rtol 1e-10): dv/dt = p·v + K·(u − F(v))."""
    def rhs(time, v):
        f = np.tanh(v[0] / 1e-3)
        friction = FC_POS * max(f, 0.0) + FC_NEG * min(f, 0.0)
        return [POLE * v[0] + GAIN * (u_of_t(time) - friction)]
    return solve_ivp(rhs, (t[0], t[-1]), [0.0], method="LSODA", t_eval=t, rtol=1e-10, atol=1e-13,
                     max_step=1e-3).y[0]


@pytest.fixture(scope="module")
def fast_record():
    t = np.arange(0.0, 10.0, DT)
    u = _input(t)
    v = _g1_velocity(t, lambda s: _input(np.asarray(s)))  # the input as a smooth signal, sampled at 10 kHz
    return RecordData((RecordSeries("r", t, u, v, "v", "zoh", np.ones(t.size, bool)),), "fast")


def test_the_rate_follows_the_inputs_band(fast_record):
    r = fast_record.records[0]
    band = input_bandwidth(r.u, DT)
    assert 4.2 < band < 4.5  # the highest tone, 4.3 Hz
    q = reduction_factor(r)
    assert q == int(1 / DT // (RATE_FACTOR * band)) and 1 / (q * DT) >= RATE_FACTOR * band


def test_a_reduced_record_replays_the_plant_as_the_full_one_does(fast_record):
    """The reduced record's input, linear between its samples, drives servofmu's g1 to the reduced output within
    1e-3 of its RMS; its samples are the full record's at the kept times within 1e-3 (the filter's flat pass band)."""
    reduced = reduced_rate(fast_record).records[0]
    q = reduction_factor(fast_record.records[0])
    assert reduced.hold == "foh" and reduced.time.size == fast_record.records[0].time[::q].size
    g1 = sf.load_plant("g1")
    model = BatchSimulator(g1).simulate_record(g1.parameter_vector()[None], reduced.time, reduced.u, hold="foh",
                                                  rtol=1e-10).v[0]
    scale = np.std(reduced.y)
    inner = slice(5, -5)  # the filter's ends
    assert np.sqrt(np.mean((model - reduced.y)[inner] ** 2)) < 1e-3 * scale
    assert np.sqrt(np.mean((reduced.y - fast_record.records[0].y[::q])[inner] ** 2)) < 1e-3 * scale


def test_long_records_are_shortened_to_their_budget_and_a_loop_only_in_time(fast_record):
    short = shortened(fast_record, 1000)
    assert sum(int(r.fitted.sum()) for r in short.records) <= 1000
    assert short.records[0].time[1] - short.records[0].time[0] > 10 * DT  # reduced in rate first
    assert shortened(fast_record, 10 ** 6) is fast_record
    t = np.arange(0.0, 2.0, 1e-3)
    loop = ClosedLoopData((ClosedLoopSeries("l", t, np.sin(t), np.sin(t), np.cos(t), np.ones(t.size, bool)),),
                          load_controller("axis_controller"), "loop")
    cut = shortened(loop, 500).records[0]
    assert np.allclose(np.diff(cut.time), 1e-3) and cut.time.size == 500


def _newey_west_segment_by_segment(r, jac, blocks, concurrent=None):
    """The leave-one-segment-out Newey–West covariance as long_run's docstring states it, one segment at a time."""
    from servofmu.identification.long_run import SEGMENT_GRIDS, bartlett_lags
    gram = jac.T @ jac
    bread, omega = np.linalg.pinv(gram), np.zeros((jac.shape[1],) * 2)
    for group in concurrent or [(k,) for k in range(len(blocks))]:
        parts = [blocks[k] for k in group]
        n = parts[0].stop - parts[0].start
        lags = max(bartlett_lags(r[b]) for b in parts)
        span = lags + 1
        offsets = sorted({k * span // SEGMENT_GRIDS for k in range(SEGMENT_GRIDS)})
        for offset in offsets:
            g = sum(jac[b] * r[b, None] for b in parts)
            edges = [0] + list(range(offset or span, n, span)) + [n]
            for start, stop in zip(edges[:-1], edges[1:]):
                rows = np.concatenate([np.arange(b.start + start, b.start + stop) for b in parts])
                js = jac[rows]
                shift = (js @ (np.linalg.pinv(gram - js.T @ js) @ (js.T @ r[rows]))).reshape(len(parts), -1)
                for b, d in zip(parts, shift):
                    g[start:stop] += jac[b.start + start:b.start + stop] * d[:, None]
            omega += (g.T @ g) / len(offsets)
            for lag in range(1, lags + 1):
                gamma = g[lag:].T @ g[:-lag]
                omega += (1 - lag / (lags + 1)) * (gamma + gamma.T) / len(offsets)
    return bread @ omega @ bread


@pytest.mark.parametrize("color", [0.0, 0.9])
@pytest.mark.parametrize("concurrent", [None, [(0, 1)]])
def test_the_batched_newey_west_covariance_is_the_segment_by_segment_one(color, concurrent):
    """The segments of a whole span are refitted in one batch (a 6·10⁵-sample record: 3·10⁵ segments per grid):
    the same covariance as segment by segment, white and coloured residuals, one signal or two sampled together."""
    from servofmu.identification.long_run import newey_west_covariance
    rng = np.random.default_rng(3)
    n = 1001
    e = rng.standard_normal(2 * n)
    for k in range(1, e.size):
        e[k] += color * e[k - 1]
    jac = rng.standard_normal((2 * n, 3))
    blocks = [slice(0, n), slice(n, 2 * n)]
    expected = _newey_west_segment_by_segment(e, jac, blocks, concurrent)
    assert np.allclose(newey_west_covariance(e, jac, blocks, concurrent), expected, rtol=1e-12, atol=0)


@pytest.mark.parametrize("n, q", [(600_000, 57), (6000, 5), (1001, 7), (192, 3)])
def test_the_decimator_is_scipys_resample_poly_to_rounding(n, q):
    """The reduced rate's low-pass and decimation, computed at the kept samples only, against scipy.signal."""
    from scipy.signal import resample_poly

    from servofmu.identification.shortening import KAISER_BETA, _decimated

    rng = np.random.default_rng(n)
    x = np.cumsum(rng.standard_normal(n)) + 3.0 * np.sin(np.arange(n) / 50.0) + 7.0
    expected = resample_poly(x, 1, q, window=("kaiser", KAISER_BETA), padtype="line")
    np.testing.assert_allclose(_decimated(x, q), expected, rtol=0, atol=1e-12 * np.max(np.abs(expected)))
