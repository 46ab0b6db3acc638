"""Broadband excitation and the BLA: exact on a linear plant (against an independent periodic steady state computed
in the state space), the noise variance as it was made, friction-like nonlinearities seen as distortions, and the
signals' grids and crest factors."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from servofmu.broadband import BroadbandPlan, crest_factor, estimate_bla, h1_estimate, split_periods
from servofmu.errors import UserError

RATE = 1000.0


def second_order(rate=RATE):
    """G(s) = ω²/(s² + 2ζωs + ω²), ω = 2π·5 Hz, ζ = 0.3, discretised exactly for a zero-order-held input."""
    w = 2 * np.pi * 5
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss([w * w], [1, 2 * 0.3 * w, w * w]), 1 / rate, "zoh")
    return a, b, c, d


def periodic_response(system, x: np.ndarray, samples: int) -> np.ndarray:
    """The output of the discrete state space to the periodic input x (period ``samples``) started in its periodic
    steady state: x0 = (I − A^N)⁻¹ x_N, x_N the state after one period from rest."""
    a, b, c, d = system
    state = np.zeros(a.shape[0])
    for k in range(samples):
        state = a @ state + b[:, 0] * x[k]
    x0 = np.linalg.solve(np.eye(a.shape[0]) - np.linalg.matrix_power(a, samples), state)
    return signal.dlsim((a, b, c, d, 1 / RATE), x, x0=x0)[1][:, 0]


def frequency_response(system, f: np.ndarray) -> np.ndarray:
    """G_zoh(e^{jωT}) = C (zI − A)⁻¹ B + D, line by line."""
    a, b, c, d = system
    z = np.exp(2j * np.pi * f / RATE)
    return np.array([(c @ np.linalg.solve(zi * np.eye(a.shape[0]) - a, b))[0, 0] + d[0, 0] for zi in z])


def plan(**kw):
    args = dict(kind="multisine", levels=(1.0,), band=(1.0, 60.0), rate=RATE, period=1.0, periods=4,
                transient_periods=1, realisations=6, seed=3)
    args.update(kw)
    return BroadbandPlan(**args)


def run_linear(p, noise=0.0, seed=0):
    sys_ = second_order()
    u = p.signals()[0]
    y = np.stack([periodic_response(sys_, x, p.samples) for x in u])
    y = y + noise * np.random.default_rng(seed).standard_normal(y.shape)
    b = estimate_bla(split_periods(u, p.samples, p.periods, p.transient_periods),
                     split_periods(y, p.samples, p.periods, p.transient_periods), p.lines, RATE, p.free_lines)
    return b, sys_


@pytest.mark.parametrize("grid", ["full", "odd", "odd-random"])
def test_the_bla_of_a_noise_free_linear_plant_is_its_frequency_response_at_every_excited_line(grid):
    b, sys_ = run_linear(plan(grid=grid))
    g = frequency_response(sys_, b.frequencies)
    assert b.frequencies.size > 20
    assert np.max(np.abs(b.G - g) / np.abs(g)) <= 1e-6
    assert np.all(b.coherence > 1 - 1e-9)


def test_the_noise_variance_is_the_one_made_within_20_percent():
    p = plan(periods=4, realisations=6)
    sigma = 0.01
    b, _ = run_linear(p, noise=sigma, seed=11)
    # white noise σ on every sample: a line's amplitude phasor (2/N scaling) has variance 4σ²/N per period;
    # averaged over P periods and M realisations, divided by |U|²
    true = 4 * sigma ** 2 / p.samples / p.periods / p.realisations / b.U ** 2
    assert abs(np.mean(b.var_noise) / np.mean(true) - 1) < 0.2
    assert abs(b.total_to_noise_db) < 1.0  # a linear plant: realisations differ only by the noise


def test_the_95_percent_band_holds_the_true_response_at_95_percent_of_the_lines_with_four_realisations():
    """A linear plant under noise, M = 4 realisations, 12 seeds pooled (≈ 1400 lines): G ± band_factor·σ holds
    the true response at 95 % ± 2 % of them, where ±2σ holds about 92 % (the σ is estimated from 4 realisations:
    the error over it follows F(2, 6), not a normal law)."""
    held, held_2s = [], []
    for seed in range(12):
        b, sys_ = run_linear(plan(realisations=4, periods=2, seed=seed), noise=0.02, seed=100 + seed)
        error = np.abs(b.G - frequency_response(sys_, b.frequencies))
        held.append(error <= b.band_factor() * b.std_band)
        held_2s.append(error <= 2 * b.std_total)
    share, share_2s = np.mean(np.concatenate(held)), np.mean(np.concatenate(held_2s))
    assert b.band_factor() == pytest.approx(np.sqrt(3 * (20 ** (1 / 3) - 1)), rel=1e-9)  # √F⁻¹(0.95; 2, 6)
    assert abs(share - 0.95) <= 0.02, share
    assert share_2s < share and abs(share_2s - 0.921) <= 0.03, share_2s


def coulomb_loop(u: np.ndarray, friction: float, rate=RATE) -> np.ndarray:
    """A mass (1 kg) with viscous (5 N·s/m) and Coulomb friction, Euler-discretised: v' = u − 5v − Fc·sign(v)."""
    v, out = 0.0, np.empty_like(u)
    h = 1 / rate
    for k, uk in enumerate(u):
        out[k] = v
        v = v + h * (uk - 5 * v - friction * np.sign(v))
    return out


@pytest.mark.parametrize("friction", [0.0, 0.5])
def test_coulomb_friction_shows_as_a_distortion_level_far_above_the_noise_and_none_without_it(friction):
    p = plan(band=(1.0, 40.0), periods=2, transient_periods=2, realisations=6, levels=(1.0,))
    u = p.signals()[0]
    y = np.stack([coulomb_loop(x, friction) for x in u])
    y = y + 1e-5 * np.random.default_rng(5).standard_normal(y.shape)
    b = estimate_bla(split_periods(u, p.samples, 2, 2), split_periods(y, p.samples, 2, 2), p.lines, RATE,
                     p.free_lines)
    if friction:
        assert b.distortion_to_noise_db > 20
        assert b.detection_to_noise_db("odd") > 20  # a sign is an odd nonlinearity ...
    else:
        assert b.distortion_to_noise_db < 0
        assert abs(b.detection_to_noise_db("odd")) < 2


def test_a_static_cubic_term_puts_power_at_the_odd_detection_lines_and_not_at_the_even_ones():
    p = plan(periods=2, realisations=4)
    u = p.signals()[0]
    y = u + 0.3 * u ** 3 + 1e-6 * np.random.default_rng(2).standard_normal(u.shape)
    b = estimate_bla(split_periods(u, p.samples, 2, 1), split_periods(y, p.samples, 2, 1), p.lines, RATE,
                     p.free_lines)
    assert b.detection_to_noise_db("odd") > 40 and abs(b.detection_to_noise_db("even")) < 3
    assert b.distortion_to_noise_db > 20


def test_the_multisine_has_a_flat_spectrum_on_its_grid_and_a_lower_crest_factor_than_random_phases():
    p = plan(band=(1.0, 200.0), grid="odd-random", realisations=4)
    plain = plan(band=(1.0, 200.0), grid="odd-random", realisations=4, crest_iterations=0)
    for r in range(4):
        x = p.realisation(r)
        spectrum = np.abs(np.fft.rfft(x))
        assert np.ptp(spectrum[p.lines]) < 1e-9 * spectrum[p.lines].max()
        assert np.max(np.delete(spectrum, p.lines)) < 1e-9 * spectrum[p.lines].max()
        assert np.sqrt(np.mean(x ** 2)) == pytest.approx(1.0)
        assert crest_factor(x) < crest_factor(plain.realisation(r)) - 0.5
    assert set(p.lines) & set(p.detection_lines) == set() and np.all(p.lines % 2 == 1)
    assert len(p.detection_lines) == (len(p.lines) + len(p.detection_lines)) // p.group


def test_realisations_differ_levels_scale_and_the_same_seed_gives_the_same_signal():
    p = plan(levels=(2.0, 0.5))
    s = p.signals()
    assert s.shape == (2, 6, 5 * p.samples)
    assert np.allclose(s[0], 4 * s[1])
    phases = np.angle(np.fft.rfft(s[0, :, :p.samples], axis=-1)[:, p.lines])
    assert np.min(np.abs(np.diff(phases, axis=0))) > 1e-6  # independent phases at every line
    assert np.array_equal(s, plan(levels=(2.0, 0.5)).signals())
    assert BroadbandPlan.from_description(p.describe()) == p


def test_a_chirp_and_a_prbs_are_periodic_and_their_h1_estimate_finds_the_plant():
    sys_ = second_order()
    for kind in ("chirp", "prbs"):
        p = BroadbandPlan(kind, (1.0,), (1.0, 40.0), RATE, periods=8, transient_periods=0, realisations=1,
                          period=None)
        x = p.signal(0, 0)
        y = periodic_response(sys_, x, p.samples)
        h = h1_estimate(x, y, RATE, segment=p.samples, band=(2.0, 30.0))
        g = frequency_response(sys_, h.frequencies)
        assert np.median(np.abs(h.G - g) / np.abs(g)) < 0.05, kind
        b = estimate_bla(split_periods(x[None], p.samples, 8, 0), split_periods(y[None], p.samples, 8, 0),
                         p.lines, RATE)
        assert np.max(np.abs(b.G - frequency_response(sys_, b.frequencies)) / np.abs(b.G)) < 1e-6, kind


@pytest.mark.parametrize("kw, fragment", [
    (dict(band=(1.0, 600.0)), "--band: f_max 600 Hz is not below the Nyquist frequency 500 Hz"),
    (dict(levels=(1.0, 0.0)), "--levels: must be a positive number, not 0.0"),
    (dict(levels=(-2.0,)), "--levels"),
    (dict(band=(1.2, 1.8)), "--band: no line"),
    (dict(period=0.0105), "--period: 0.0105 s is not a whole number"),
    (dict(kind="prbs", period=3.0), "--period: a PRBS's period follows from --band"),
])
def test_bad_plans_are_refused_naming_the_option(kw, fragment):
    with pytest.raises(UserError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        plan(**kw)


def test_a_record_of_another_length_than_whole_periods_is_refused():
    with pytest.raises(UserError, match="1001 samples is not 1 \\+ 2 periods of 500 samples"):
        split_periods(np.zeros(1001), 500, 2, 1)


def relay_loop(u: np.ndarray, friction: float, rate=RATE) -> np.ndarray:
    """A third-order G (poles −2.5 ± 31.5j and −10 1/s, G(0) = 1) with Coulomb friction Fc·sign(v) fed back from
    its output: G's phase crosses −180°, so the friction closes a relay loop that oscillates on its own unless
    the force drives it through."""
    poles = [-2.5 + 31.5j, -2.5 - 31.5j, -10.0]
    den = np.real(np.poly(poles))
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss([den[-1]], den), 1 / rate, "zoh")
    state, out = np.zeros(a.shape[0]), np.empty_like(u)
    for k, uk in enumerate(u):
        out[k] = (c @ state)[0]
        state = a @ state + b[:, 0] * (uk - friction * np.sign(out[k]))
    return out


def test_a_periodic_response_is_found_periodic_with_or_without_noise_and_friction():
    p = plan(band=(1.0, 40.0), periods=2, transient_periods=2, realisations=4)
    u = p.signals()[0]
    linear = plan(realisations=4, periods=3)
    x = linear.signals()[0]
    y = np.stack([periodic_response(second_order(), row, linear.samples) for row in x])
    for seed in range(40):  # noise alone between the lines: no false report
        noisy = y + 0.02 * np.random.default_rng(200 + seed).standard_normal(y.shape)
        b = estimate_bla(*(split_periods(z, linear.samples, 3, 1) for z in (x, noisy)), linear.lines, RATE)
        assert b.periodic, (seed, b.nonsynchronous_frequency, b.nonsynchronous_over_floor_db)
    assert run_linear(plan())[0].periodic  # noise-free
    y = np.stack([coulomb_loop(x, 0.5) for x in u]) + 1e-5 * np.random.default_rng(5).standard_normal(u.shape)
    b = estimate_bla(split_periods(u, p.samples, 2, 2), split_periods(y, p.samples, 2, 2), p.lines, RATE)
    assert b.distortion_to_noise_db > 20 and b.periodic  # friction's distortions are synchronous


def test_a_component_between_the_lines_is_reported_with_its_frequency_and_level():
    p = plan(periods=4, realisations=4)
    b, _ = run_linear(p, noise=0.001)
    t = np.arange((p.periods + p.transient_periods) * p.samples) / RATE
    y_extra = 0.05 * np.sin(2 * np.pi * 7.3 * t)  # 7.3 Hz: between the 1 Hz period's lines
    u = p.signals()[0]
    y = np.stack([periodic_response(second_order(), x, p.samples) for x in u]) + y_extra
    y = y + 0.001 * np.random.default_rng(1).standard_normal(y.shape)
    cut = [split_periods(x, p.samples, p.periods, p.transient_periods) for x in (u, y)]
    found = estimate_bla(*cut, p.lines, RATE)
    assert b.periodic and not found.periodic
    assert abs(found.nonsynchronous_frequency - 7.3) <= RATE / (p.periods * p.samples)  # within one bin (0.25 Hz)
    response = np.mean(np.sum(np.abs(np.fft.rfft(cut[1], axis=-1)[..., p.lines].mean(axis=1) * 2 / p.samples) ** 2,
                              axis=-1))
    # the strongest bin holds most of a sinusoid 0.05 Hz off its centre (a fifth of a bin: sinc² ≈ 0.88)
    expected = 10 * np.log10(0.05 ** 2 / response)
    assert expected - 1.5 <= found.nonsynchronous_re_response_db <= expected + 0.1
    assert found.nonsynchronous_over_floor_db > 40


def test_a_friction_limit_cycle_is_reported_not_taken_for_noise():
    # at a small force the friction's relay loop oscillates on its own; at a large one the force drives it through
    p = plan(band=(0.5, 40.0), periods=4, transient_periods=3, realisations=2, levels=(1.0,))
    u = p.signals()[0]
    rng = np.random.default_rng(2)
    found = {}
    for level in (0.3, 30.0):
        y = np.stack([relay_loop(level * x, 1.0) for x in u])
        y = y + 1e-4 * np.std(y) * rng.standard_normal(y.shape)
        cut = [split_periods(x, p.samples, p.periods, p.transient_periods) for x in (level * u, y)]
        found[level] = estimate_bla(*cut, p.lines, RATE)
    small = found[0.3]
    assert not small.periodic and small.nonsynchronous_re_response_db > -20, small.nonsynchronous_re_response_db
    assert found[30.0].periodic
