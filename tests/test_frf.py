"""Harmonic analysis from samples (servofmu.measurement.frf) against signals whose phasors are known in closed form."""
from __future__ import annotations

import math

import numpy as np
import pytest

from servofmu.errors import UserError
from servofmu.measurement.frf import (
    SteadyStateDetector,
    distortion,
    estimate_frequency,
    harmonics,
    period_phasor,
    settle_noisy,
)


def multisine(t, f):
    """0.3 + 2 sin(wt + 0.4) + 0.5 sin(3wt - 1) + 0.1 sin(7wt + 2): DC 0.3, S1 = 2e^{0.4j}, S3 = 0.5e^{-1j},
    S7 = 0.1e^{2j} in the convention s = DC + sum |S_k| sin(k w t + arg S_k)."""
    w = 2 * np.pi * f
    return 0.3 + 2 * np.sin(w * t + 0.4) + 0.5 * np.sin(3 * w * t - 1) + 0.1 * np.sin(7 * w * t + 2)


def test_phasors_of_a_multisine_on_a_uniform_grid_are_exact():
    f = 3.7
    start = 11 / f  # far from 0: the phase refers to absolute time
    t = start + np.arange(3 * 64 + 1) / (64 * f)
    h = harmonics(t, multisine(t, f), f, start=start, periods=3)
    assert h.dc == pytest.approx(0.3, abs=1e-13)
    expected = np.zeros(10, complex)
    expected[0], expected[2], expected[6] = 2 * np.exp(0.4j), 0.5 * np.exp(-1j), 0.1 * np.exp(2j)
    np.testing.assert_allclose(h.phasors, expected, atol=1e-12)
    assert h.distortion == pytest.approx(math.hypot(0.5, 0.1) / 2, rel=1e-12)
    assert h.periods == 3 and h.start == start


def test_phase_convention_for_a_plain_sine_and_cosine():
    f = 2.0
    t = np.linspace(0, 1, 1001)
    assert harmonics(t, np.sin(2 * np.pi * f * t), f).first == pytest.approx(1.0, abs=1e-12)
    assert harmonics(t, np.cos(2 * np.pi * f * t), f).first == pytest.approx(1j, abs=1e-12)  # cos = sin(. + pi/2)


def test_non_uniform_samples_and_a_window_between_samples():
    f = 1.3
    rng = np.random.default_rng(5)
    t = np.sort(np.concatenate([[0.0, 4.0], rng.uniform(0, 4, 40000)]))
    h = harmonics(t, multisine(t, f), f, start=0.37, periods=4)
    # trapezoid error for this smooth signal with ~1e-4 s spacing is O(h^2) ~ 1e-6
    assert abs(h.first - 2 * np.exp(0.4j)) < 1e-5
    assert abs(h.dc - 0.3) < 1e-5


def test_window_outside_the_samples_or_bad_frequency_is_a_user_error():
    t = np.linspace(0, 1, 101)
    with pytest.raises(UserError, match="outside the samples"):
        harmonics(t, np.sin(t), 1.0, start=0.5, periods=1)
    with pytest.raises(UserError, match="less than one period"):
        harmonics(t, np.sin(t), 0.5)
    with pytest.raises(UserError, match="positive"):
        harmonics(t, np.sin(t), 0.0)


def test_distortion_of_a_pure_sine_is_zero_and_nan_without_fundamental():
    assert distortion(np.array([1.0, 0, 0])) == 0.0
    assert math.isnan(distortion(np.array([0.0, 1.0])))


def test_steady_state_detector_stops_where_a_geometric_transient_predicts():
    """s = sin(wt) + c·exp(-t/tau): the change of S1 between periods p-1 and p is
    |S1 of the decaying part| (1 - q) q^(p-1) with q = exp(-T/tau); the detector must stop at the first
    period where two successive changes are below the threshold, and estimate the remaining error."""
    f, tau, threshold, n = 2.0, 0.8, 1e-10, 256
    T = 1 / f
    det = SteadyStateDetector(f, threshold=threshold, consecutive=2)
    p = 0
    while not det.converged:
        t = p * T + np.arange(n + 1) * T / n
        det.add_period(t, np.sin(2 * np.pi * f * t) + 0.7 * np.exp(-t / tau))
        p += 1
        assert p < 200
    # analytic per-period S1 and DC of the exponential part, period k: A·q^k
    q = math.exp(-T / tau)
    t0 = np.arange(n + 1) * T / n
    s1_exp, dc_exp = period_phasor(t0, 0.7 * np.exp(-t0 / tau), f)
    changes = [max(abs(s1_exp), abs(dc_exp)) * (1 - q) * q ** (k - 1) for k in range(1, 200)]
    below = [c < threshold * 1.0 for c in changes]  # |S1| of the steady part is 1
    expected = next(k for k in range(1, len(below)) if below[k - 1] and below[k]) + 1 + 1
    assert det.periods == expected
    remaining = max(abs(s1_exp), abs(dc_exp)) * q ** (det.periods - 1)  # distance of the last period from 0 transient
    assert det.remaining_error == pytest.approx(remaining, rel=0.05)


def test_steady_state_detector_never_converges_on_a_beat():
    f, n = 1.0, 128
    det = SteadyStateDetector(f, threshold=1e-10)
    for p in range(50):
        t = p + np.arange(n + 1) / n
        det.add_period(t, np.sin(2 * np.pi * t) + 0.3 * np.sin(2 * np.pi * math.sqrt(2) * t))
    assert not det.converged and det.last_change > 1e-3 and det.remaining_error == math.inf


def test_frequency_of_a_noisy_sine_and_its_power_fraction():
    rng = np.random.default_rng(1)
    t = np.arange(5000) / 1000.0
    u = 1.5 * np.sin(2 * np.pi * 3.217 * t + 0.3) + 0.05 * rng.standard_normal(t.size)
    f, fraction = estimate_frequency(t, u)
    assert f == pytest.approx(3.217, rel=1e-4)
    assert fraction > 0.99
    _, fraction_noise = estimate_frequency(t, rng.standard_normal(t.size))
    assert fraction_noise < 0.2


def test_settling_of_a_noisy_record_starts_after_the_transient():
    rng = np.random.default_rng(2)
    f = 2.0
    t = np.arange(20000) / 1000.0
    v = np.sin(2 * np.pi * f * t) + 2.0 * np.exp(-t / 0.5) + 0.01 * rng.standard_normal(t.size)
    s = settle_noisy(t, v, f, 0.0)
    # the transient's first harmonic drops below the noise band (~1e-3) after about 0.5·ln(2000) ≈ 3.8 s
    assert 4 <= s.first_period <= 12 and s.converged and s.periods == 39  # t ends at 19.999 s
