"""The output-error criterion: what the identifier, the baselines, compare and report all score a plant by.

A candidate plant is simulated under the data's own conditions and compared with what was measured:

- stepped-sine data (:class:`SineData`): per experiment the relative error of the first-harmonic response
  H = V1/U1 and of the mean velocity (:func:`sine_residuals`), from the batch simulator's periodic steady state;
- time-domain records (:class:`RecordData`): the simulated velocity against the measured one at every sample.

The fitness is the RMS of the residuals (:func:`rms`).  The 95 % intervals of a fit come from the Gauss–Newton
covariance of these residuals (:func:`intervals_from_jacobian`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from ..measurement.datafile import DataFile
from ..model.plant import Plant
from ..simulation.batch import BatchSimulator, SteadyStateOptions
from .prior import full_vectors

__all__ = ["SineData", "RecordData", "sine_data", "sine_residuals", "sine_residual_jacobian", "SineCriterion",
           "RecordCriterion", "rms", "steady_state_options", "central_jacobian", "intervals_from_jacobian",
           "output_error_fitness", "SEARCH_RTOL", "POLISH_RTOL", "JACOBIAN_RTOL", "JACOBIAN_STEP"]

# Integrator tolerances (relative): the swarm only needs to rank candidates; the polish's residuals must be far
# more exact than the 1e-6 the parameters are to reach.  Its forward-difference Jacobian (relative step 1e-5) is
# evaluated at the same tight tolerance: looser ones (1e-8) made g2's steady-state test fail for single
# perturbed candidates, which spoils a whole Jacobian.
SEARCH_RTOL = 1e-5
POLISH_RTOL = 1e-10
JACOBIAN_RTOL = POLISH_RTOL
JACOBIAN_STEP = 1e-5


# ---------------------------------------------------------------------------
# What is fitted
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SineData:
    """Stepped-sine observations the identifier fits: the converged experiments of a data file.

    amplitudes, frequencies (n,): the plan (N, Hz); H (n,) complex: V1/U1; dc (n,): mean velocity (m/s).
    ``noisy``: whether H and dc are the noisy measurement (when the file has noise, that is what is fitted).
    """

    amplitudes: np.ndarray
    frequencies: np.ndarray
    H: np.ndarray
    dc: np.ndarray
    noisy: bool
    source: str
    skipped: int  # experiments without steady state, left out

    @property
    def plan(self) -> np.ndarray:
        """(2, n): amplitudes and frequencies — the layout an ANN is bound to."""
        return np.vstack([self.amplitudes, self.frequencies])


@dataclass(frozen=True)
class RecordData:
    """Time-domain records to identify from: per record time (s), input u (N) and measured velocity v (m/s)."""

    records: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]
    source: str


def sine_data(data: DataFile) -> SineData:
    """The stepped-sine observations of a measurement file: its experiments with a steady state.

    Parameters
    ----------
    data : DataFile
        A measurement file read with :func:`servofmu.read_data_file`.

    Returns
    -------
    SineData
        H and dc of the converged experiments (the noisy ones when the file has noise).

    Raises
    ------
    UserError
        When no experiment settled, fewer than two magnitudes remain, or the stored harmonics are not finite.
    """
    exps = [e for e in data.experiments if e.converged]
    if not exps:
        raise UserError(f"{data.path}: no stepped-sine experiment with a steady state to identify from")
    noisy = all(e.H_noisy is not None for e in exps)
    H = np.array([e.H_noisy if noisy else e.H for e in exps], dtype=complex)
    dc = np.array([e.dc_noisy if noisy else e.dc for e in exps], dtype=float)
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(dc))):
        raise UserError(f"{data.path}: the stored first harmonics contain NaN or Inf")
    amps = np.array([e.amplitude for e in exps])
    if len(np.unique(amps)) < 2:
        raise UserError(f"{data.path}: identification needs experiments at two or more excitation magnitudes "
                        f"with a steady state (has {', '.join(map(str, np.unique(amps)))})")
    return SineData(amplitudes=amps, frequencies=np.array([e.frequency for e in exps]), H=H, dc=dc, noisy=noisy,
                    source=str(data.path), skipped=len(data.experiments) - len(exps))


# ---------------------------------------------------------------------------
# Residuals
# ---------------------------------------------------------------------------
def _weighted(data: SineData, dH, ddc, axis: int) -> np.ndarray:
    """Deviations of the response phasor and of the mean velocity, weighted and stacked along ``axis``
    (the experiments' axis: last for residuals, first for Jacobians)."""
    shape = (-1,) + (1,) * (np.ndim(dH) - 1) if axis == 0 else (-1,)
    scale = np.abs(data.H).reshape(shape)
    m = data.amplitudes.reshape(shape)
    rel = np.asarray(dH) / scale
    return np.concatenate([rel.real, rel.imag, np.sqrt(2) * np.asarray(ddc) / (scale * m)], axis=axis)


def sine_residuals(data: SineData, H: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """The output-error residuals of responses ``H``, ``dc`` (shape (..., n)) against ``data``: per experiment
    Re and Im of (H − H_data)/|H_data| and √2·(dc − dc_data)/(|H_data|·m) — relative errors of the response
    phasor and of the mean velocity, weighted so that white measurement noise gives each about the same
    variance.  Their RMS is the fitness."""
    return _weighted(data, np.asarray(H) - data.H, np.asarray(dc) - data.dc, axis=-1)


def sine_residual_jacobian(data: SineData, dH: np.ndarray, ddc: np.ndarray) -> np.ndarray:
    """The Jacobian of :func:`sine_residuals` from those of H and dc (shape (n, p)): shape (3n, p)."""
    return _weighted(data, dH, ddc, axis=0)


def steady_state_options(rtol: float) -> SteadyStateOptions:
    """Batch-simulator settings for an integrator tolerance: periods compared to a tenth of it (within limits).

    Giving up early on an experiment that seems not to settle saves the search much time, and a wrong verdict
    there only costs a candidate its rank; the polish's few candidates run to max_time instead, since a wrong
    verdict there stalls the fit (seen on g2-like plants whose 4 Hz response settles slowly)."""
    return SteadyStateOptions(rtol=rtol, tol=min(max(rtol / 10, 1e-10), 1e-6), give_up_early=rtol >= SEARCH_RTOL)


class SineCriterion:
    """Residuals of candidates (rows of identified parameters) against stepped-sine data."""

    def __init__(self, structure: Plant, data: SineData, simulator: BatchSimulator):
        self.structure, self.data, self.simulator = structure, data, simulator
        self.evaluations = 0

    def residuals(self, theta: np.ndarray, rtol: float) -> np.ndarray:
        """(N, 3n) residuals of the N candidates ``theta``; NaN rows for candidates without a steady state."""
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        feats = self.simulator.steady_state(full_vectors(self.structure, theta), self.data.amplitudes,
                                            self.data.frequencies, steady_state_options(rtol))
        r = sine_residuals(self.data, feats.H, feats.dc)
        r[~np.all(feats.converged, axis=1)] = np.nan  # a candidate without steady state cannot be compared
        return r


class RecordCriterion:
    """Residuals of candidates against time-domain records: (v_model − v)/rms(v) at every sample."""

    def __init__(self, structure: Plant, data: RecordData, simulator: BatchSimulator):
        self.structure, self.data, self.simulator = structure, data, simulator
        self.evaluations = 0

    def residuals(self, theta: np.ndarray, rtol: float) -> np.ndarray:
        """(N, samples) residuals of the N candidates ``theta``, all records one after the other."""
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        full = full_vectors(self.structure, theta)
        parts = []
        for t, u, v in self.data.records:
            sim = self.simulator.simulate_record(full, t, u, rtol=rtol)
            parts.append((sim - v) / np.sqrt(np.mean(v**2)))
        return np.concatenate(parts, axis=1)


def rms(r: np.ndarray) -> np.ndarray:
    """The fitness: root mean square of the residuals per candidate (inf where a simulation failed)."""
    out = np.sqrt(np.mean(np.square(r), axis=-1))
    return np.where(np.isfinite(out), out, np.inf)


def output_error_fitness(structure: Plant, data: SineData, theta: np.ndarray, threads: int | None = None) -> float:
    """The RMS output error of ``theta`` by the identifier's own criterion (batch simulator, tight tolerance)."""
    crit = SineCriterion(structure, data, BatchSimulator(structure, threads=threads))
    return float(rms(crit.residuals(np.asarray(theta, dtype=float)[None], POLISH_RTOL))[0])


# ---------------------------------------------------------------------------
# Derivatives and intervals
# ---------------------------------------------------------------------------
def central_jacobian(crit: SineCriterion | RecordCriterion, theta: np.ndarray) -> np.ndarray:
    """d residuals / d theta by central differences (one batch call)."""
    p = theta.size
    h = JACOBIAN_STEP * np.maximum(np.abs(theta), 1e-3)
    r = crit.residuals(np.concatenate([theta + np.diag(h), theta - np.diag(h)]), JACOBIAN_RTOL)
    return ((r[:p] - r[p:]) / (2 * h[:, None])).T


def intervals_from_jacobian(theta: np.ndarray, r: np.ndarray, jac: np.ndarray, level: float = 0.95) -> np.ndarray:
    """(p, 2) intervals from the Gauss–Newton covariance s²(JᵀJ)⁻¹ with a Student t quantile."""
    from scipy.stats import t as student

    p = theta.size
    dof = max(r.size - p, 1)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        return np.full((p, 2), np.nan)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    half = student.ppf(0.5 + level / 2, dof) * np.sqrt(np.clip(np.diag(cov), 0, None))
    return np.stack([theta - half, theta + half], axis=1)
