"""The Cramér–Rao bound of an output-error fit: how exactly white measurement noise of a known level lets the data
determine each parameter, whatever the estimator.

For measurements y = f(θ) + e with independent Gaussian e_i of standard deviation s_i, the Fisher information is
I(θ) = Jᵀ diag(s⁻²) J with J = ∂f/∂θ, and no unbiased estimator has a covariance below I⁻¹: the bound of parameter
k is √(I⁻¹)_kk.  J is the criterion's own Jacobian (servofmu.identification.criterion.central_jacobian: central
differences of the simulated responses at a tight tolerance): the residuals of every criterion are model minus
data, so their derivatives are the model's.  scripts/bench_cramer_rao.py compares servofmu's estimates with it.
"""
from __future__ import annotations

import numpy as np

from ..errors import UserError
from ..model.plant import Plant
from ..simulation.batch import BatchSimulator
from .criterion import SineCriterion, SineData, central_jacobian, undetermined

__all__ = ["fisher_information", "cramer_rao_bound", "sine_fisher_information", "time_domain_fisher_information"]


def fisher_information(jacobian: np.ndarray, noise) -> np.ndarray:
    """Jᵀ diag(s⁻²) J: the Fisher information of measurements with sensitivities ``jacobian`` (m, p) and independent
    Gaussian noise of standard deviation ``noise`` (a scalar or (m,), all positive)."""
    jacobian = np.asarray(jacobian, dtype=float)
    s = np.broadcast_to(np.asarray(noise, dtype=float), jacobian.shape[:1])
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise UserError("the Fisher information needs a positive, finite noise level for every measurement")
    weighted = jacobian / s[:, None]
    return weighted.T @ weighted


def cramer_rao_bound(fisher: np.ndarray, jacobian: np.ndarray | None = None) -> np.ndarray:
    """(p,) the bound √(I⁻¹)_kk on the standard deviation of each parameter; inf for a parameter the data does not
    determine (a null direction of I, or of ``jacobian`` when given: servofmu.identification.criterion.undetermined)."""
    fisher = np.asarray(fisher, dtype=float)
    scale = np.sqrt(np.clip(np.diag(fisher), 0, None))
    dead = scale == 0
    if jacobian is not None:
        dead |= undetermined(np.asarray(jacobian, dtype=float))
    bound = np.full(fisher.shape[0], np.inf)
    live = ~dead
    if live.any():
        # equilibrated (well conditioned); the pseudo-inverse is the bound of every parameter outside the null space
        scaled = fisher[np.ix_(live, live)] / np.outer(scale[live], scale[live])
        bound[live] = np.sqrt(np.clip(np.diag(np.linalg.pinv(scaled)), 0, None)) / scale[live]
    bound[dead] = np.inf
    return bound


def sine_fisher_information(structure: Plant, data: SineData, theta: np.ndarray,
                            threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(Fisher information (p, p), Jacobian (3n, p)) of stepped-sine data at the parameters ``theta`` (identified
    names' order): the first harmonics and means of the experiments, each with the noise ``data.noise`` records
    (servofmu.identification.criterion.sine_data: white noise σ on the window's samples), sensitivities from the
    simulated steady states."""
    if data.noise is None or not np.all(np.asarray(data.noise) > 0):
        raise UserError(f"{data.source}: the data records no noise level (noise-free data has no finite bound)")
    crit = SineCriterion(structure, data, BatchSimulator(structure, threads=threads))
    jac = central_jacobian(crit, np.asarray(theta, dtype=float))
    noise = np.tile(np.asarray(data.noise, dtype=float), jac.shape[0] // data.amplitudes.size)
    return fisher_information(jac, noise), jac


def time_domain_fisher_information(criterion, theta: np.ndarray, noise) -> tuple[np.ndarray, np.ndarray]:
    """(Fisher information, Jacobian) of a time-domain criterion (records, closed loop) whose signals carry white
    noise of standard deviation ``noise`` (one level per signal, in its unit): the criterion's weights are set to
    those levels, so that its residuals are the measurements over their noise."""
    noise = np.asarray(noise, dtype=float)
    if noise.shape != criterion.scales.shape or not np.all(noise > 0):
        raise UserError(f"one positive noise level per signal needed ({criterion.scales.size} signals)")
    criterion.scales = noise.copy()
    jac = central_jacobian(criterion, np.asarray(theta, dtype=float))
    return fisher_information(jac, 1.0), jac
