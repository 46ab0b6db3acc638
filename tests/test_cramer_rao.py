"""The Cramér–Rao bound (servofmu.identification.cramer_rao) against closed forms."""
import numpy as np
import pytest

from servofmu.errors import UserError
from servofmu.identification.cramer_rao import cramer_rao_bound, fisher_information, sine_fisher_information
from servofmu.identification.criterion import POLISH_RTOL, SineData, steady_state_options
from servofmu.identification.prior import full_vectors
from servofmu.model.plant import load_plant
from servofmu.simulation.batch import BatchSimulator


def test_a_first_order_step_response():
    """y(t) = K(1 − e^(−at)) sampled with white noise σ: I = Σ ∇y ∇yᵀ / σ² in closed form, and the bound of K
    alone (a known) is σ/√Σ(1 − e^(−at))²."""
    K, a, sigma = 2.0, 3.0, 0.05
    t = np.linspace(0.01, 2.0, 200)
    g = np.stack([1 - np.exp(-a * t), K * t * np.exp(-a * t)], axis=1)  # ∂y/∂K, ∂y/∂a
    fisher = fisher_information(g, sigma)
    expected = np.array([[np.sum(g[:, 0] ** 2), np.sum(g[:, 0] * g[:, 1])],
                         [np.sum(g[:, 0] * g[:, 1]), np.sum(g[:, 1] ** 2)]]) / sigma**2
    assert fisher == pytest.approx(expected, rel=1e-12)
    det = expected[0, 0] * expected[1, 1] - expected[0, 1] ** 2
    bound = cramer_rao_bound(fisher)
    assert bound == pytest.approx(np.sqrt([expected[1, 1] / det, expected[0, 0] / det]), rel=1e-10)
    only_k = cramer_rao_bound(fisher_information(g[:, :1], sigma))
    assert only_k[0] == pytest.approx(sigma / np.sqrt(np.sum(g[:, 0] ** 2)), rel=1e-12)


def test_an_undetermined_parameter_has_no_finite_bound():
    g = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 1.0], [3.0, 6.0, 0.0]])  # columns 0 and 1 are one direction
    bound = cramer_rao_bound(fisher_information(g, 0.1), g)
    assert np.isinf(bound[:2]).all() and bound[2] == pytest.approx(0.1)
    with pytest.raises(UserError, match="positive"):
        fisher_information(g, 0.0)


def test_stepped_sine_of_a_first_order_plant_against_the_closed_form():
    """g1 with a Coulomb friction too small to change the response: H = K·a/(jω + a) with pole p = −a, and a
    friction level's first harmonic is that of a square wave in phase with v (2/π of it for each side) and its
    mean ±1/2, so every sensitivity is known in closed form."""
    plant = load_plant("g1")
    K, p, fc = 1.0, -10.0, 1e-4
    theta = np.array([p, K, fc, fc])
    amps, freqs = np.array([2.0, 2.0, 0.6, 0.6]), np.array([0.5, 2.0, 0.5, 2.0])
    feats = BatchSimulator(plant).steady_state(full_vectors(plant, theta[None]), amps, freqs,
                                               steady_state_options(POLISH_RTOL))
    H, dc, noise = feats.H[0], feats.dc[0], np.array([1e-3, 2e-3, 1e-3, 3e-3])
    data = SineData(amplitudes=amps, frequencies=freqs, H=H, dc=dc, noisy=True, source="test", skipped=0,
                    noise=noise)
    fisher, _ = sine_fisher_information(plant, data, theta, threads=1)

    jw = 2j * np.pi * freqs
    G = -K * p / (jw - p)
    dH = np.stack([-K * jw / (jw - p) ** 2, -p / (jw - p),  # d/dp, d/dK
                   -G * (2 / np.pi) * G / np.abs(G) / amps, -G * (2 / np.pi) * G / np.abs(G) / amps], axis=1)
    ddc = np.stack([np.zeros(4), np.zeros(4), np.full(4, -K / 2), np.full(4, K / 2)], axis=1)
    scale = np.abs(G)[:, None]
    jac = np.concatenate([(dH / scale).real, (dH / scale).imag, np.sqrt(2) * ddc / (scale * amps[:, None])])
    expected = fisher_information(jac, np.tile(noise, 3))
    assert fisher == pytest.approx(expected, rel=2e-2, abs=1e-3 * np.max(np.abs(expected)))
    assert cramer_rao_bound(fisher) == pytest.approx(cramer_rao_bound(expected), rel=2e-2)
