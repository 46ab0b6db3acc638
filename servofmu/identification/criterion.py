"""The output-error criterion: what the identifier, the baselines, compare and report all score a plant by.

A candidate plant is simulated under the data's own conditions and compared with what was measured:

- stepped-sine data (:class:`SineData`): per experiment the relative error of the first-harmonic response
  H = V1/U1 and of the mean velocity (:func:`sine_residuals`), from the batch simulator's periodic steady state;
- time-domain records (:class:`RecordData`): the model driven by the recorded input (with the record's own
  intersample behaviour) against the recorded output at every sample: the velocity of a velocity record, the raw
  position of a position record (an encoder's counts are the measurement; the velocity estimated from them is
  low-pass filtered and would bias the fit), with its unknown initial value projected out.

The fitness is the RMS of the residuals (:func:`rms`).  The 95 % intervals of a fit come from the Gauss–Newton
covariance of these residuals (:func:`intervals_from_jacobian`); for records with a heteroscedasticity- and
autocorrelation-consistent (Newey–West) estimate, so that residuals that are not white (a filtered signal, a
small model error, a closed loop's noise) do not make the intervals too narrow: on the residuals a fit without
each segment of the record would have left (the noise the parameters absorbed given back), the signals sampled
together (a closed loop's position and command) taken jointly, with the degrees of freedom of the estimate.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError
from ..measurement.datafile import DataFile
from ..model.laws.registry import law_key_names
from ..model.plant import Plant
from ..simulation.batch import BatchSimulator, SteadyStateOptions, WarmStarts
from .prior import check_identifiable, full_vectors
from .long_run import bartlett_lags, long_run_dof, newey_west_covariance
from .student_t import t_quantile

__all__ = ["SineData", "RecordData", "RecordSeries", "sine_data", "record_data", "fitted_samples", "check_structure",
           "record_errors", "fit_percent", "newey_west_covariance", "bartlett_lags", "long_run_dof",
           "sine_residuals", "sine_residual_jacobian",
           "SineCriterion", "RecordCriterion", "TimeDomainCriterion", "rms", "steady_state_options",
           "central_jacobian", "with_finite_columns", "intervals_from_jacobian", "covariance_from_jacobian",
           "intervals_from_covariance", "undetermined", "output_error_fitness", "SEARCH_RTOL",
           "POLISH_RTOL", "JACOBIAN_RTOL", "JACOBIAN_STEP"]

# Integrator tolerances (relative): the swarm only needs to rank candidates; the polish's residuals must be far
# more exact than the 1e-6 the parameters are to reach.  Its forward-difference Jacobian (relative step 1e-5) only
# steers the steps and scales the intervals: at 1e-9 it is exact to ~1e-4 relative, and a polish step costs half
# of what it does at 1e-10 (docs/bench-speed.md).  The price is a polish that stops a little earlier on a few
# plants, still far inside 1e-6: worst relative error 1.3e-9 over bench-identify's 100 random g2 plants, median
# 2e-10 (docs/bench-identify.md).  A perturbed candidate without steady state is stepped the other way
# (servofmu.identification.polish).
SEARCH_RTOL = 1e-5
POLISH_RTOL = 1e-10
JACOBIAN_RTOL = 1e-9
JACOBIAN_STEP = 1e-5


# ---- What is fitted ----
@dataclass(frozen=True)
class SineData:
    """Stepped-sine observations the identifier fits: the converged experiments of a data file.

    amplitudes, frequencies (n,): the plan (N, Hz); H (n,) complex: V1/U1; dc (n,): mean velocity (m/s).
    ``noisy``: whether H and dc are the noisy measurement (when the file has noise, that is what is fitted).
    ``noise`` (n,): the standard deviation the measurement noise gives each residual of an experiment (Re, Im and
    mean of :func:`sine_residuals`), from the noise level the file records; None (or zeros) for noise-free data.
    """

    amplitudes: np.ndarray
    frequencies: np.ndarray
    H: np.ndarray
    dc: np.ndarray
    noisy: bool
    source: str
    skipped: int  # experiments without steady state, left out
    noise: np.ndarray | None = None

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        n, a, f = self.amplitudes.size, self.amplitudes, self.frequencies
        spans = (figure("amplitudes", f"{a.min():.4g}–{a.max():.4g}", "N"),
                 figure("frequencies", f"{f.min():.4g}–{f.max():.4g}", "Hz")) if n else ()
        return Shown(type(self).__name__, f"{n} experiments ({'noisy' if self.noisy else 'noise-free'}, {self.skipped} "
                     f"without steady state left out) from {self.source!r}", spans)

    @property
    def plan(self) -> np.ndarray:
        """(2, n): amplitudes and frequencies — the layout an ANN is bound to."""
        return np.vstack([self.amplitudes, self.frequencies])


@dataclass(frozen=True)
class RecordSeries:
    """One record as it is fitted: time (s), input u (N), the measured output ``y`` — velocity (m/s) when
    ``output`` is "v", position (m) when it is "position" — the input's ``hold`` between samples ("zoh" or "foh"),
    and ``fitted``, the samples that enter the fit (all but a skipped settling segment)."""

    name: str
    time: np.ndarray
    u: np.ndarray
    y: np.ndarray
    output: str
    hold: str
    fitted: np.ndarray


@dataclass(frozen=True)
class RecordData:
    """Time-domain records to identify from, fitted jointly (see :class:`RecordCriterion` for the weights)."""

    records: tuple[RecordSeries, ...]
    source: str


def check_structure(structure: Plant, data: DataFile, what: str) -> None:
    """Refuse a structure that does not match the plant the data was measured on (a measurement of a servofmu
    FMU records its parameters; records of a machine say nothing, and any structure may be tried on them), and a
    structure that leaves nothing to identify."""
    check_identifiable(structure)
    measured = [n for n in data.parameters if n.startswith(("pole", "zero", "gain", "dc_gain")) or n in law_key_names()]
    if measured and set(measured) - set(structure.parameter_names()):
        raise UserError(f"{data.path}: {what} ({', '.join(structure.parameter_names())}) does not match the plant "
                        f"the data was measured on ({', '.join(measured)})")


def fitted_samples(data: DataFile, skip: float) -> list[np.ndarray]:
    """Per record of ``data``, the samples after its first ``skip`` seconds (a UserError for a file without
    records, a negative skip, or fewer than 10 samples left)."""
    if not data.records:
        raise UserError(f"{data.path}: the file holds no records")
    if not (np.isfinite(skip) and skip >= 0):
        raise UserError(f"skip must be 0 or a positive number of seconds, not {skip}")
    out = []
    for r in data.records:
        fitted = r.series.time >= r.series.time[0] + skip
        if fitted.sum() < 10:
            raise UserError(f"{data.path}: record {r.name} has {fitted.sum()} samples after skipping {skip:g} s; "
                            "it needs at least 10")
        out.append(fitted)
    return out


def record_data(data: DataFile, skip: float = 0.0) -> RecordData:
    """The records of a records file as the criterion fits them.

    Parameters
    ----------
    data : DataFile
        A records file (``servofmu import``).
    skip : float
        Seconds at the start of every record left out of the fit: the model starts at rest at the first sample,
        so a record that does not start at rest is fitted once the initial state has died away.

    Returns
    -------
    RecordData
        One RecordSeries per record: position records are fitted on their raw position, velocity records on
        their velocity.

    Raises
    ------
    UserError
        For a file without records, a negative skip, or a skip that leaves fewer than 10 samples of a record.
    """
    out = []
    for r, fitted in zip(data.records, fitted_samples(data, skip)):
        s = r.series
        if not np.any(s.u):  # the plant stays at rest: every parameter fits, none is determined
            raise UserError(f"{data.path}: record {r.name}: its input u is zero throughout: nothing excites the "
                            "plant, so nothing can be identified from it")
        position = r.kind == "position" and s.position is not None
        out.append(RecordSeries(name=r.name, time=s.time, u=s.u, y=s.position if position else s.v,
                                output="position" if position else "v", hold=r.intersample, fitted=fitted))
    return RecordData(records=tuple(out), source=str(data.path))


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
    from ..api_checks import check_arguments

    check_arguments(sine_data, locals())  # a wrong type: UserError naming it
    exps = [e for e in data.experiments if e.converged]
    if not exps:
        raise UserError(f"{data.path}: no stepped-sine experiment with a steady state to identify from")
    noisy = all(e.H_noisy is not None for e in exps)
    H = np.array([e.H_noisy if noisy else e.H for e in exps], dtype=complex)
    dc = np.array([e.dc_noisy if noisy else e.dc for e in exps], dtype=float)
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(dc))):
        raise UserError(f"{data.path}: the stored first harmonics contain NaN or Inf")
    amps = np.array([e.amplitude for e in exps])
    magnitudes = sorted(set(amps.tolist()))  # (np.unique would load numpy.ma)
    if len(magnitudes) < 2:
        raise UserError(f"{data.path}: identification needs experiments at two or more excitation magnitudes "
                        f"with a steady state (has {', '.join(map(str, magnitudes))})")
    # white noise of std σ on N window samples puts σ·√(2/N) on Re and Im of V1 and σ/√N on the mean
    noise = np.array([e.noise_sigma * math.sqrt(2 / (e.samples_per_period * e.window_periods)) / abs(e.U1 * h)
                      for e, h in zip(exps, H)]) if noisy else np.zeros(len(exps))
    return SineData(amplitudes=amps, frequencies=np.array([e.frequency for e in exps]), H=H, dc=dc, noisy=noisy,
                    source=str(data.path), skipped=len(data.experiments) - len(exps), noise=noise)


# ---- Residuals ----
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


# A polish's run begun on a nearby set's orbit may take this many times that run's steps (at least the floor), else
# it has no steady state and the polish steps back: trials into far stiffer friction took millions of steps each
# (noise-free lugre_servo: 116 of a selection's 123 s); an optimum there is reached by shorter steps.
STEP_BUDGET_FACTOR = 20
STEP_BUDGET_FLOOR = 20_000


def steady_state_options(rtol: float) -> SteadyStateOptions:
    """Batch-simulator settings for an integrator tolerance: periods compared to a tenth of it (within limits).

    Giving up early on an experiment that seems not to settle saves the search much time, and a wrong verdict
    there only costs a candidate its rank; the polish's few candidates run to max_time instead, since a wrong
    verdict there stalls the fit (seen on g2-like plants whose 4 Hz response settles slowly)."""
    return SteadyStateOptions(rtol=rtol, tol=min(max(rtol / 10, 1e-10), 1e-6), give_up_early=rtol >= SEARCH_RTOL)


class SineCriterion:
    """Residuals of candidates (rows of identified parameters) against stepped-sine data.

    What the identifier needs of a criterion: ``residuals(theta, rtol)`` (N candidates → (N, m)) and
    ``evaluations``.  Time-domain criteria (RecordCriterion, and the closed loop's) also give ``blocks`` (slices
    of residuals that are consecutive samples of one signal, for the Newey–West intervals), ``reweight``,
    ``relative_rms`` and ``fit_percent``.
    """

    blocks = None

    def __init__(self, structure: Plant, data: SineData, simulator: BatchSimulator):
        self.structure, self.data, self.simulator = structure, data, simulator
        self.evaluations = 0
        self.warm_starts = WarmStarts()  # every candidate's runs begin on the orbits of the nearest one before
        self.failures = np.zeros(len(data.amplitudes))  # per experiment: those that fail most run first (whole_sets)

    def residuals(self, theta: np.ndarray, rtol: float) -> np.ndarray:
        """(N, 3n) residuals of the N candidates ``theta``; NaN rows for candidates without a steady state."""
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        full = full_vectors(self.structure, theta)
        start, steps = self.warm_starts.nearest(full, rtol)
        # a candidate is compared only where every experiment settles: one without steady state ends its others
        options = replace(steady_state_options(rtol), whole_sets=True)
        if rtol < SEARCH_RTOL and steps is not None and np.all(np.isfinite(steps)):
            options = replace(options, max_steps=int(max(STEP_BUDGET_FLOOR, STEP_BUDGET_FACTOR * steps.max())))
        order = np.argsort(-self.failures, kind="stable")
        feats = self.simulator.steady_state(full, self.data.amplitudes[order], self.data.frequencies[order], options,
                                            start=None if start is None else start[:, order])
        feats = feats.experiments(np.argsort(order))
        self.failures += feats.failed().sum(axis=0)
        self.warm_starts.add(full, feats, rtol)
        r = sine_residuals(self.data, feats.H, feats.dc)
        r[~np.all(feats.converged, axis=1)] = np.nan  # a candidate without steady state cannot be compared
        return r


def record_errors(record: RecordSeries, response) -> np.ndarray:
    """Model minus measurement at the record's fitted samples, for N responses (shape (N, fitted samples)).  For a
    position the mean is removed: the encoder's zero is arbitrary, and the best constant offset is the mean."""
    simulated = response.position if record.output == "position" else response.v
    e = simulated[:, record.fitted] - record.y[record.fitted]
    return e - e.mean(axis=1, keepdims=True) if record.output == "position" else e


def fit_percent(y: np.ndarray, error: np.ndarray) -> float:
    """The fit as MATLAB's ``compare`` defines it, 100·(1 − ‖y − ŷ‖/‖y − mean(y)‖), from y and ŷ − y; NaN for a
    measured signal that does not vary (no fit is defined: compare would say −inf or NaN, which reads as a
    number)."""
    spread = np.linalg.norm(y - np.mean(y))
    return float(100.0 * (1.0 - np.linalg.norm(error) / spread)) if spread > 0 else math.nan


class TimeDomainCriterion:
    """Residuals of candidates against sampled signals, each signal weighted by its noise.

    A subclass gives ``signals()`` — the measured values of every signal at its fitted samples, with their names —
    and ``errors(theta, rtol)`` — model minus measurement for N candidates, one (N, samples) array per signal.
    The residuals of signal k are divided by ``scales[k]``, an estimate of its noise level, so that every sample
    counts by how exactly it was measured: the maximum-likelihood weighting for signals of different units,
    noise levels and lengths.  Before a fit the scale is the spread of the signal (relative errors);
    :meth:`reweight` sets it to the RMS error of a fit, after which the fit is repeated (feasible generalised
    least squares).  ``blocks``: the residuals of each signal, consecutive samples (Newey–West intervals);
    ``concurrent``: groups of blocks sampled at the same instants, whose noise may be correlated (None: none).
    """

    def __init__(self, structure: Plant):
        self.structure = structure
        self.evaluations = 0
        measured = [y for _, y in self.signals()]
        self.spreads = np.array([float(np.std(y)) or 1.0 for y in measured])
        self.scales = self.spreads.copy()
        sizes = [y.size for y in measured]
        self.blocks = [slice(a, a + n) for a, n in zip(np.cumsum([0] + sizes[:-1]), sizes)]
        self.concurrent: list[tuple[int, ...]] | None = None  # blocks sampled at the same instants (a subclass's)
        self._last = None  # (rtol, theta, errors) of the last single candidate: a fit's end asks for it repeatedly

    def signals(self) -> list[tuple[str, np.ndarray]]:
        """The measured signals at their fitted samples, as (name, values) pairs (the subclass's)."""
        raise NotImplementedError

    def errors(self, theta: np.ndarray, rtol: float) -> list[np.ndarray]:
        """Model minus measurement for the N candidates ``theta``: one (N, samples) array per signal, simulated
        at relative tolerance ``rtol`` (the subclass's :meth:`simulate_errors`); a single candidate asked for
        again at the same tolerance is not simulated again (the polish's end, the fitness, the fit % and the
        scores all ask for the fit's errors)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        last = self._last
        if last is not None and theta.shape[0] == 1 and last[0] == rtol and np.array_equal(last[1], theta):
            return [e.copy() for e in last[2]]
        out = self.simulate_errors(theta, rtol)
        if theta.shape[0] == 1:
            self._last = (rtol, theta.copy(), [e.copy() for e in out])
        return out

    def simulate_errors(self, theta: np.ndarray, rtol: float) -> list[np.ndarray]:
        """:meth:`errors` simulated (the subclass's)."""
        raise NotImplementedError

    def residuals(self, theta: np.ndarray, rtol: float) -> np.ndarray:
        """(N, samples) weighted residuals of the N candidates ``theta``, all signals one after the other."""
        return np.concatenate([e / s for e, s in zip(self.errors(theta, rtol), self.scales)], axis=1)

    def relative_rms(self, theta: np.ndarray, rtol: float) -> float:
        """The fitness of one candidate whatever the weights: RMS of every signal's error relative to its spread."""
        return float(rms(np.concatenate([e / s for e, s in zip(self.errors(theta, rtol), self.spreads)], axis=1))[0])

    def reweight(self, theta: np.ndarray, rtol: float) -> None:
        """Scales from the errors at ``theta``: each signal's RMS error (its noise level, if the model fits)."""
        for k, e in enumerate(self.errors(theta, rtol)):
            self.scales[k] = max(float(np.sqrt(np.mean(e[0] ** 2))), 1e-12 * self.spreads[k])

    def fit_percent(self, theta: np.ndarray, rtol: float) -> dict[str, float]:
        """The fit (%) of every signal at ``theta``, by name."""
        return {name: fit_percent(y, e[0]) for (name, y), e in zip(self.signals(), self.errors(theta, rtol))}


class RecordCriterion(TimeDomainCriterion):
    """Records simulated with their own hold, each compared on the signal it measures (record_errors)."""

    def __init__(self, structure: Plant, data: RecordData, simulator: BatchSimulator):
        self.data, self.simulator = data, simulator
        super().__init__(structure)

    def signals(self) -> list[tuple[str, np.ndarray]]:
        """Per record its measured output (velocity in m/s or position in m) at the fitted samples, by name."""
        return [(r.name, r.y[r.fitted]) for r in self.data.records]

    def simulate_errors(self, theta: np.ndarray, rtol: float) -> list[np.ndarray]:
        """Per record, model minus measurement at its fitted samples for the N candidates ``theta``."""
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        full = full_vectors(self.structure, theta)
        return [record_errors(r, self.simulator.simulate_record(full, r.time, r.u, hold=r.hold, rtol=rtol))
                for r in self.data.records]


def rms(r: np.ndarray) -> np.ndarray:
    """The fitness: root mean square of the residuals per candidate (inf where a simulation failed)."""
    out = np.sqrt(np.mean(np.square(r), axis=-1))
    return np.where(np.isfinite(out), out, np.inf)


def output_error_fitness(structure: Plant, data: SineData, theta: np.ndarray, threads: int | None = None) -> float:
    """The RMS output error of ``theta`` by the identifier's own criterion (batch simulator, tight tolerance)."""
    crit = SineCriterion(structure, data, BatchSimulator(structure, threads=threads))
    return float(rms(crit.residuals(np.asarray(theta, dtype=float)[None], POLISH_RTOL))[0])


# ---- Derivatives and intervals ----
def central_jacobian(crit: SineCriterion | RecordCriterion, theta: np.ndarray) -> np.ndarray:
    """d residuals / d theta by central differences (one batch call)."""
    p = theta.size
    h = JACOBIAN_STEP * np.maximum(np.abs(theta), 1e-3)
    r = crit.residuals(np.concatenate([theta + np.diag(h), theta - np.diag(h)]), JACOBIAN_RTOL)
    return ((r[:p] - r[p:]) / (2 * h[:, None])).T


def with_finite_columns(crit: SineCriterion | RecordCriterion, theta: np.ndarray, jac: np.ndarray) -> np.ndarray:
    """``jac`` (d residuals / d theta) with each column that is not finite made again by differences in the
    parameters themselves: at the edge of a parameter's domain the search's coordinates have no finite derivative
    (a collapsed Stribeck bump, fs = fc: log(fs − fc) = −∞), while the residuals are smooth in the parameters.
    Central differences where both sides are plants, one-sided ones where only one is (fs below fc is none)."""
    bad = np.flatnonzero(~np.all(np.isfinite(jac), axis=0))
    if not bad.size:
        return jac
    h = JACOBIAN_STEP * np.maximum(np.abs(theta[bad]), 1e-3)
    steps = np.zeros((bad.size, theta.size))
    steps[np.arange(bad.size), bad] = h
    r = crit.residuals(np.vstack([theta[None], theta + steps, theta - steps]), JACOBIAN_RTOL)
    r0, up, down = r[0], r[1:bad.size + 1], r[bad.size + 1:]
    out = np.array(jac, dtype=float)
    for i, k in enumerate(bad):
        ok_up, ok_down = np.all(np.isfinite(up[i])), np.all(np.isfinite(down[i]))
        if ok_up and ok_down:
            out[:, k] = (up[i] - down[i]) / (2 * h[i])
        elif ok_up or ok_down:
            out[:, k] = (up[i] - r0) / h[i] if ok_up else (r0 - down[i]) / h[i]
    return out


def intervals_from_jacobian(theta: np.ndarray, r: np.ndarray, jac: np.ndarray, level: float = 0.95,
                            blocks: list[slice] | None = None,
                            concurrent: list[tuple[int, ...]] | None = None) -> np.ndarray:
    """(p, 2) intervals with a Student t quantile, from :func:`covariance_from_jacobian` (the Gauss–Newton
    covariance s²(JᵀJ)⁻¹ or, with ``blocks``, the Newey–West sandwich and its degrees of freedom)."""
    cov, dof = covariance_from_jacobian(r, jac, blocks, concurrent)
    return intervals_from_covariance(theta, cov, dof, jac, level)


def covariance_from_jacobian(r: np.ndarray, jac: np.ndarray, blocks: list[slice] | None = None,
                             concurrent: list[tuple[int, ...]] | None = None) -> tuple[np.ndarray, int]:
    """The estimates' (p, p) covariance and its degrees of freedom: s²(JᵀJ)⁻¹ with n − p, or with ``blocks`` (the
    residuals of each signal, consecutive samples) :func:`newey_west_covariance` (``concurrent``: the blocks sampled
    at the same instants, e.g. a closed-loop record's position and command) with the degrees of freedom of its
    long-run covariance, 1.5·n/L per group of n samples and bandwidth L (at most n − p).  NaN for residuals or a
    Jacobian that are not finite."""
    p = jac.shape[1]
    dof = max(r.size - p, 1)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        return np.full((p, p), np.nan), dof
    if blocks is None:
        return float(r @ r) / dof * np.linalg.pinv(jac.T @ jac), dof
    cov = newey_west_covariance(r, jac, blocks, concurrent) * r.size / dof
    return cov, min(dof, long_run_dof(r, blocks, concurrent))


def intervals_from_covariance(theta: np.ndarray, cov: np.ndarray, dof: int, jac: np.ndarray,
                              level: float = 0.95) -> np.ndarray:
    """(p, 2) intervals θ ± t(level, dof)·√diag(cov), unbounded for the parameters :func:`undetermined` by ``jac``
    (NaN when ``cov`` is)."""
    if not np.all(np.isfinite(cov)):
        return np.full((theta.size, 2), np.nan)
    half = t_quantile(level, dof) * np.sqrt(np.clip(np.diag(cov), 0, None))
    half[undetermined(jac, theta=theta)] = np.inf
    return np.stack([theta - half, theta + half], axis=1)


# A parameter whose whole value moves the residuals by less than this share of what the most effective one's does
# has no effect the data shows (a Stribeck level whose Stribeck velocity went to 1e-86 m/s: 1e-10 of the gain's)
NO_EFFECT = 1e-8


def undetermined(jac: np.ndarray, rtol: float = 1e-10, theta: np.ndarray | None = None) -> np.ndarray:
    """(p,) bool: the parameters the data does not determine — those with a share in a direction of parameter
    space that leaves the residuals unchanged (a null direction of the column-scaled Jacobian), and with ``theta``
    those whose effect (a column times the value) is below NO_EFFECT of the largest.  Their intervals are
    unbounded: the pseudo-inverse's zero variance there would claim the opposite of the truth."""
    scale = np.linalg.norm(jac, axis=0)
    dead = scale == 0
    if theta is not None:
        effect = scale * np.abs(theta)
        dead |= (effect <= NO_EFFECT * effect.max()) & (theta != 0)
    if dead.all():
        return dead
    _, sv, vt = np.linalg.svd(jac[:, ~dead] / scale[~dead], full_matrices=False)
    null = sv <= rtol * sv[0]
    out = dead.copy()
    out[~dead] = np.any(np.abs(vt[null]) > 1e-6, axis=0)
    return out
