"""The uncertainty band of an identified G(jω): the result's parameter covariance carried to ln|G(jω)| and
arg G(jω) by linearisation (first-order propagation, the delta method).

The Jacobian of ln G(jω) over the identified parameters is taken by central differences of
servofmu.model.plant.Plant.frequency_response (G is a rational function of the roots and the gain, smooth where
it is finite, so a relative step of 1e-6 leaves a truncation error far below the band).  With J = ∂ln G/∂θ
(complex) and the covariance C: var ln|G| = Re J · C · Re Jᵀ and var arg G = Im J · C · Im Jᵀ; the band is
the estimate ± z·σ in dB (symmetric in dB: multiplicative in |G|) and in degrees, z the two-sided normal
quantile of the level (1.96 for 95 %).  Parameters G does not depend on (friction, load) drop out; a result
without a covariance, or whose covariance is not finite where G depends on it, has no band.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

__all__ = ["ResponseBand", "response_band", "log_response_jacobian", "RELATIVE_STEP"]

RELATIVE_STEP = 1e-6  # of each parameter's central difference


@dataclass(frozen=True)
class ResponseBand:
    """G(jω) at ``frequencies`` (Hz) with the standard deviations of ln|G| (``log_sigma``) and of arg G in rad
    (``phase_sigma``), and ``z``, the normal quantile of the band's level."""

    frequencies: np.ndarray
    G: np.ndarray
    log_sigma: np.ndarray
    phase_sigma: np.ndarray
    z: float

    def magnitude_db(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of 20·log10|G| in dB."""
        db, half = 20 * np.log10(np.abs(self.G)), 20 / math.log(10) * self.z * self.log_sigma
        return db - half, db + half

    def phase_deg(self, unwrapped: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of the phase in degrees around ``unwrapped`` (default: the unwrapped phase of G)."""
        centre = np.degrees(np.unwrap(np.angle(self.G))) if unwrapped is None else unwrapped
        half = np.degrees(self.z * self.phase_sigma)
        return centre - half, centre + half


def log_response_jacobian(plant, names, omega: np.ndarray) -> np.ndarray:
    """(frequencies, parameters) complex: ∂ln G(jω)/∂θ of ``plant`` over its parameters ``names`` (names of
    ``plant.parameter_names()``), by central differences; zero columns for parameters G does not depend on."""
    all_names = plant.parameter_names()
    base = plant.parameter_vector()
    G = plant.frequency_response(omega)
    J = np.zeros((np.size(omega), len(names)), dtype=complex)
    for j, name in enumerate(names):
        if name not in all_names:  # not a parameter of this plant: G does not depend on it
            continue
        i = all_names.index(name)
        h = RELATIVE_STEP * max(abs(base[i]), 1e-12)
        up, down = base.copy(), base.copy()
        up[i] += h
        down[i] -= h
        dG = plant.with_parameters(up).frequency_response(omega) - plant.with_parameters(down).frequency_response(omega)
        J[:, j] = dG / (2 * h) / G
    return J


def response_band(result, frequencies, level: float = 0.95) -> ResponseBand | None:
    """The ``level`` band of the identified G(jω) of ``result`` (servofmu.identification.results.Result) at
    ``frequencies`` (Hz), by linearisation of ln G over the identified parameters (module docstring); None
    without a covariance, or when it is not finite for a parameter G depends on."""
    if not 0 < level < 1:
        raise ValueError(f"level must lie in (0, 1), got {level!r}")
    f = np.asarray(frequencies, dtype=float).ravel()
    plant, cov = result.plant, result.covariance
    if cov is None:
        return None
    J = log_response_jacobian(plant, list(result.names), 2 * np.pi * f)
    used = np.flatnonzero(np.any(J != 0, axis=0))
    if used.size == 0:
        return None
    C = np.asarray(cov, dtype=float)[np.ix_(used, used)]
    if not np.all(np.isfinite(C)):
        return None
    J = J[:, used]
    var_log = np.einsum("fi,ij,fj->f", J.real, C, J.real)
    var_phase = np.einsum("fi,ij,fj->f", J.imag, C, J.imag)
    z = NormalDist().inv_cdf(0.5 + level / 2)
    return ResponseBand(f, plant.frequency_response(2 * np.pi * f), np.sqrt(np.maximum(var_log, 0)),
                        np.sqrt(np.maximum(var_phase, 0)), z)
