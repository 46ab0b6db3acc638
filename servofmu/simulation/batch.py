"""Batch simulator: one plant structure, many parameter sets, compiled once (servofmu.simulation.compiled).

* :meth:`BatchSimulator.steady_state`: stepped-sine experiments u = m·sin(2πft) from rest (or from a nearby
  parameter set's orbit: :class:`WarmStarts`), integrated period by period until a period at ``rtol`` ends where
  it began, or ``max_time``.  Per experiment ``H`` = V1/U1 with S1 = j·(2/T)∫_period s(t)·exp(−j2πft) dt (so that
  s ≈ |S1|·sin(2πft + arg S1), U1 = m), ``dc`` = mean of v, and ``distortion`` = sqrt(Σ_{k≥2}|V_k|²)/|V1| from
  Parseval.  The integrals are quadrature states of the integrator, not sums over samples.  How a run gets
  there fast (a loose transient, warm starts, Newton's method on the period map with ``accelerate``, stopping
  hopeless runs with ``give_up_early``) is told at the top of ``batch_c/batch_driver.c`` and at its ``sine_task``;
  none of it changes the steady state's features beyond the tolerance, as long as the run reaches the same
  attracting orbit.  ``settle_time`` is the simulated time used, not that of a plain run.
* :meth:`BatchSimulator.simulate_record` / :meth:`BatchSimulator.simulate_sine`: the response (v and the
  position) at a record's sample times to its input, with the record's intersample hold, from rest.

Parameter vectors follow ``plant.parameter_names()``.  A parameter set that the plant file format would reject
(:func:`valid_parameter_sets`) or whose integration fails gives NaN results instead of an error.  Tasks run on
``threads`` POSIX threads inside the library; results do not depend on their number.  Speed and accuracy per
tolerance: docs/bench-batch.md.
"""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass, fields

import numpy as np

from ..errors import UserError
from ..model.plant import Plant, parameter_rules
from ..model.signals import INTERSAMPLE
from ..runtime import available_cores
from .compiled import (
    H_START,
    HOLD_CODES,
    ModelStructureError,
    SineResult,
    batch_library,
    c_doubles,
    c_mask,
)

__all__ = ["BatchSimulator", "SteadyStateOptions", "SteadyStateFeatures", "WarmStarts", "RecordResponse",
           "valid_parameter_sets", "ModelStructureError"]


@dataclass(frozen=True)
class SteadyStateOptions:
    """How a stepped-sine experiment is run to periodic steady state.

    ``rtol``: integrator relative tolerance; the absolute tolerance of each
    state is ``rtol`` times the largest magnitude the state has reached, so the
    features are accurate to a few ``rtol`` relative (docs/bench-batch.md).
    ``tol``: converged when a period at ``rtol`` ends within max(``tol``,
    3·``rtol``) of where it began, every state relative to its scale, after at
    least ``min_periods`` periods.  ``max_time`` (s): stop after the period that
    reaches it.  ``max_steps``: integrator step budget per experiment
    (exceeding it gives NaN).  ``accelerate`` (Newton's method on the period
    map), ``give_up_early`` (stop a run that cannot converge within
    ``max_time``): see batch_c/batch_driver.c's ``sine_task``.  ``whole_sets``: once an experiment of a
    parameter set ends without a steady state, the set's experiments not yet begun are not run (not converged,
    NaN features) — for a criterion that has no use for a set unless every experiment settles.
    """

    rtol: float = 1e-8
    tol: float = 1e-10
    max_time: float = 60.0
    min_periods: int = 1
    max_steps: int = 5_000_000
    accelerate: bool = True
    give_up_early: bool = True
    whole_sets: bool = False

    def __post_init__(self):
        if not 0 < self.rtol < 1e-2:
            raise UserError(f"rtol must be in (0, 0.01), not {self.rtol}")
        if not 0 < self.tol < 1:
            raise UserError(f"tol must be in (0, 1), not {self.tol}")
        if not self.max_time > 0:
            raise UserError(f"max_time must be positive, not {self.max_time}")
        if self.min_periods < 1:
            raise UserError(f"min_periods must be at least 1, not {self.min_periods}")
        if self.max_steps < 1:
            raise UserError(f"max_steps must be positive, not {self.max_steps}")


@dataclass(frozen=True)
class RecordResponse:
    """The response of N parameter sets at a record's sample times: ``v`` (m/s) and ``position`` (m, the integral
    of v from 0 at the first sample), both of shape (N, samples); NaN where a set is invalid or failed."""

    v: np.ndarray
    position: np.ndarray


@dataclass(frozen=True)
class SteadyStateFeatures:
    """Features of N parameter sets × n_exp experiments (arrays of shape (N, n_exp)).

    ``H`` (complex, m/s per N), ``dc`` (m/s), ``distortion`` (1), ``converged``
    (bool), ``settle_time`` (s: the simulated time up to the end of the period
    the features come from; NaN for an invalid set), ``steps`` (accepted
    integrator steps, for benchmarks), ``orbit`` (shape (N, n_exp, n_states·(n_states + 6)): where each run
    ended — the states at the end of its last period, the integrator's state scales, and the period's
    derivatives with respect to where it began (the monodromy matrix, then those of the four integrals; NaN
    when not computed) — which ``steady_state``'s ``start`` takes to begin a nearby parameter set's run there).
    """

    H: np.ndarray
    dc: np.ndarray
    distortion: np.ndarray
    converged: np.ndarray
    settle_time: np.ndarray
    steps: np.ndarray
    orbit: np.ndarray

    def experiments(self, index) -> "SteadyStateFeatures":
        """The features of the experiments ``index`` (an index array along the experiments' axis), in its order."""
        return SteadyStateFeatures(**{f.name: getattr(self, f.name)[:, index] for f in fields(self)})

    def failed(self) -> np.ndarray:
        """(N, n_exp): the runs that ended without a steady state (not those never run: an invalid set's, or a
        whole set's after one of its experiments failed)."""
        return ~self.converged & np.isfinite(self.settle_time)


class BatchSimulator:
    """Simulator of the structure of ``plant`` (its nominal values only fix the model's state scaling).

    ``threads``: worker threads per call (default: the cores this process may use; give 1 when several
    processes simulate at once).  A simulator can be sent to worker processes: it is rebuilt there from the
    plant (loading the compiled library from the cache).
    """

    def __init__(self, plant: Plant, threads: int | None = None):
        if threads is not None and threads < 1:
            raise UserError(f"threads must be at least 1, not {threads}")
        self.plant = plant
        self.threads = threads or available_cores()
        self.parameter_names = plant.parameter_names()
        self._lib = self._load(plant)
        ns, n_p, nf = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        self._lib.sb_sizes(ctypes.byref(ns), ctypes.byref(n_p), ctypes.byref(nf))
        self.n_states = ns.value  # integrated states (all but the position, unless a load's force depends on it)

    @staticmethod
    def _load(plant: Plant) -> ctypes.CDLL:
        """The compiled library (a subclass with a driver of its own loads that)."""
        return batch_library(plant)

    def __reduce__(self):
        return type(self), (self.plant, self.threads)

    # ---- inputs ---------------------------------------------------------------------------------------------
    def _parameter_sets(self, params) -> tuple[np.ndarray, np.ndarray]:
        p = np.asarray(params, dtype=float)
        if p.ndim == 1:
            p = p[None, :]
        if p.ndim != 2 or p.shape[1] != len(self.parameter_names):
            raise UserError(f"parameter sets must have shape (N, {len(self.parameter_names)}) "
                            f"({', '.join(self.parameter_names)}), not {np.shape(params)}")
        p = np.ascontiguousarray(p)
        return p, valid_parameter_sets(self.plant, p).astype(np.uint8)

    # ---- stepped sine ---------------------------------------------------------------------------------------
    def steady_state(self, params, amplitudes, frequencies, options: SteadyStateOptions = SteadyStateOptions(),
                     progress=None, start=None) -> SteadyStateFeatures:
        """Steady-state features of every parameter set (rows of ``params``) in every experiment.

        ``amplitudes`` (N) and ``frequencies`` (Hz): one experiment per pair.
        ``progress(done, total)``, if given, is called as parameter sets finish.
        ``start``: where to begin each run instead of at rest, shape of ``orbit`` — the ``orbit`` of an
        earlier call for nearby parameter sets (:class:`WarmStarts` picks them); NaN entries begin at rest.  A
        warm start shortens the transient, not the convergence test: the features agree with a run from rest to
        the tolerance, as long as both reach the same periodic orbit.
        """
        p, valid = self._parameter_sets(params)
        amp = np.ascontiguousarray(np.asarray(amplitudes, dtype=float).ravel())
        freq = np.ascontiguousarray(np.asarray(frequencies, dtype=float).ravel())
        if amp.size != freq.size or amp.size == 0:
            raise UserError(f"the plan needs as many amplitudes as frequencies (got {amp.size} and {freq.size})")
        if not (np.all(np.isfinite(amp)) and np.all(amp > 0)):
            raise UserError(f"excitation amplitudes must be positive and finite, not {amp.tolist()}")
        if not (np.all(np.isfinite(freq)) and np.all(freq > 0)):
            raise UserError(f"excitation frequencies must be positive and finite, not {freq.tolist()}")
        n, n_exp = p.shape[0], amp.size
        out = np.empty((n, n_exp, len(SineResult)))
        orbit = np.empty((n, n_exp, self.n_states * (self.n_states + 6)))  # the driver's ORBIT
        if start is not None:
            start = np.ascontiguousarray(start, dtype=float)
            if start.shape != orbit.shape:
                raise UserError(f"start must have shape {orbit.shape} (sets, experiments, orbit), not {start.shape}")
        for lo, hi in _chunks(n, progress):
            rc = self._lib.sb_sine(hi - lo, p.shape[1], c_doubles(p[lo:hi]), c_mask(valid[lo:hi]), n_exp,
                                   c_doubles(amp), c_doubles(freq), options.rtol, options.tol, options.max_time,
                                   options.min_periods,
                                   H_START, options.max_steps, int(options.accelerate),
                                   int(options.give_up_early), int(options.whole_sets), self.threads,
                                   None if start is None else c_doubles(start[lo:hi]), c_doubles(out[lo:hi]),
                                   c_doubles(orbit[lo:hi]))
            if rc != 0:
                raise RuntimeError(f"batch library rejected the call (code {rc})")
            if progress is not None:
                progress(hi, n)
        s1 = out[..., SineResult.RE_S1] + 1j * out[..., SineResult.IM_S1]
        dc, mean_square = out[..., SineResult.DC], out[..., SineResult.MEAN_SQUARE]
        with np.errstate(invalid="ignore", divide="ignore"):
            harmonics = np.maximum(2 * (mean_square - dc ** 2) - np.abs(s1) ** 2, 0.0)
            distortion = np.sqrt(harmonics) / np.abs(s1)
        return SteadyStateFeatures(H=s1 / amp, dc=dc, distortion=distortion,
                                   converged=out[..., SineResult.CONVERGED] == 1.0,
                                   settle_time=out[..., SineResult.SETTLE_TIME],
                                   steps=out[..., SineResult.STEPS].astype(np.int64), orbit=orbit)

    # ---- records ----------------------------------------------------------------------------------------------
    def simulate_record(self, params, time, u, hold: str = "zoh", rtol: float = 1e-8, max_steps: int = 50_000_000,
                        progress=None) -> RecordResponse:
        """The response at the sample times ``time`` (s) to the input ``u`` (N) with the record's ``hold``.

        ``hold="zoh"``: u[i] on [time[i], time[i+1]) (a drive's command, held for one sample); ``"foh"``: linear
        from u[i] to u[i+1].  All states are zero at ``time[0]``; the model's built-in excitation is off.
        """
        if hold not in INTERSAMPLE:
            raise UserError(f"intersample behaviour must be one of {', '.join(INTERSAMPLE)}, not {hold!r}")
        uu = np.ascontiguousarray(np.asarray(u, dtype=float).ravel())
        return self._record(params, time, uu, hold, 0.0, 0.0, rtol, max_steps, progress)

    def simulate_sine(self, params, time, amplitude: float, frequency: float, rtol: float = 1e-8,
                      max_steps: int = 50_000_000) -> RecordResponse:
        """The response at the times ``time`` (s) to u = amplitude·sin(2π·frequency·(t − time[0])) from rest: a
        stepped-sine experiment as a time series."""
        if not (np.isfinite(amplitude) and np.isfinite(frequency) and frequency > 0):
            raise UserError(f"a sine needs a finite amplitude and a positive frequency, not {amplitude}, {frequency}")
        t = np.asarray(time, dtype=float).ravel()
        return self._record(params, t, np.zeros_like(t), "sine", float(amplitude), 2 * np.pi * float(frequency),
                            rtol, max_steps, None)

    def _record(self, params, time, u, hold, m, omega, rtol, max_steps, progress) -> RecordResponse:
        p, valid = self._parameter_sets(params)
        t = np.ascontiguousarray(np.asarray(time, dtype=float).ravel())
        if t.size != u.size or t.size < 2:
            raise UserError(f"a record needs at least two samples and as many times as inputs "
                            f"(got {t.size} and {u.size})")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
            raise UserError("the record contains NaN or Inf values")
        if np.any(np.diff(t) <= 0):
            raise UserError(f"record time is not strictly increasing (at sample {int(np.argmax(np.diff(t) <= 0)) + 1})")
        if not 0 < rtol < 1e-2:
            raise UserError(f"rtol must be in (0, 0.01), not {rtol}")
        n = p.shape[0]
        out = np.empty((n, 2, t.size))
        for lo, hi in _chunks(n, progress):
            rc = self._lib.sb_record(hi - lo, p.shape[1], c_doubles(p[lo:hi]), c_mask(valid[lo:hi]), t.size,
                                     c_doubles(t), c_doubles(u), HOLD_CODES[hold], m, omega, rtol, H_START,
                                     max_steps, self.threads, c_doubles(out[lo:hi]))
            if rc != 0:
                raise RuntimeError(f"batch library rejected the call (code {rc})")
            if progress is not None:
                progress(hi, n)
        return RecordResponse(v=out[:, 0], position=out[:, 1])


class WarmStarts:
    """The orbits of parameter sets simulated so far, to begin each new set's run where the nearest one ended
    (``steady_state``'s ``start``): a search's candidates, a particle's next position, a Jacobian's perturbed
    points lie close to sets already simulated, and their transients are then short.

    Nearest: the smallest sum of squared relative differences of the parameters, chosen per experiment among
    the runs that converged in it.  The latest ``capacity`` parameter sets are kept.
    """

    def __init__(self, capacity: int = 1024):
        self.capacity = capacity
        # A ring of the latest `capacity` sets, filled in place (a search adds ten sets per call, and copying the
        # whole memory on every call cost a tenth of a fit): params (capacity, n_params), orbits (capacity, n_exp,
        # orbit) with NaN where the run did not converge; `size` rows hold sets, `next` is where the next goes.
        self.params = self.orbits = self.steps = self.rtols = None
        self.size = self.next = 0

    def add(self, params, features: SteadyStateFeatures, rtol: float = math.nan) -> None:
        """Remember the runs of ``features`` (of the parameter sets ``params``, simulated at ``rtol``) that
        converged."""
        params = np.atleast_2d(np.asarray(params, dtype=float))
        some = np.any(features.converged, axis=1)
        params = params[some][-self.capacity:]
        orbits = np.where(features.converged[some, :, None], features.orbit[some], np.nan)[-self.capacity:]
        steps = features.steps[some][-self.capacity:]
        if self.params is None:
            self.params = np.empty((self.capacity,) + params.shape[1:])
            self.orbits = np.empty((self.capacity,) + orbits.shape[1:])
            self.steps = np.zeros((self.capacity,) + steps.shape[1:], dtype=np.int64)
            self.rtols = np.full(self.capacity, math.nan)
        rows = (self.next + np.arange(len(params))) % self.capacity
        self.params[rows], self.orbits[rows], self.steps[rows], self.rtols[rows] = params, orbits, steps, rtol
        self.next = (self.next + len(params)) % self.capacity
        self.size = min(self.size + len(params), self.capacity)

    def start(self, params) -> np.ndarray | None:
        """``start`` for the parameter sets ``params`` (N, n_params): shape (N, n_exp, orbit), NaN where no
        run converged in an experiment; None before anything converged."""
        return self.nearest(params)[0]

    def nearest(self, params, rtol: float = math.nan) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(``start``, as :meth:`start` gives it; the integrator steps the runs begun there took, shape (N, n_exp),
        NaN where there is no start): what a run from each start may be expected to cost — at ``rtol``, where the
        run was at a looser one: (its rtol / ``rtol``)^(1/4) times its steps (RODAS4's error is of order 4: a polish
        at 1e-10 from a search's run at 1e-5 takes about 18 times the steps; with a budget of 20 times the search's
        steps, a gms_servo polish found no steady state at the search's best and ended there)."""
        if self.size == 0:
            return None, None
        known, orbits = self.params[:self.size], self.orbits[:self.size]
        p = np.atleast_2d(np.asarray(params, dtype=float))[:, None, :]
        scale = np.abs(p) + np.abs(known)
        with np.errstate(invalid="ignore"):
            rel = np.divide(p - known, scale, out=np.zeros(scale.shape), where=scale != 0)  # 0 where both are 0
        distance = np.nan_to_num(np.sum(rel ** 2, axis=2), nan=np.inf)  # (N, M); a NaN set is near nothing
        usable = np.isfinite(orbits[..., 0])  # (M, n_exp)
        if usable.all():  # the usual case: one nearest set for all experiments
            nearest = np.argmin(distance, axis=1)
            start, steps = orbits[nearest], self.steps[nearest].astype(float)
            far = ~np.isfinite(distance[np.arange(len(nearest)), nearest])
            nearest = nearest[:, None]
        else:
            distance = np.where(usable.T[None], distance[:, None, :], np.inf)  # (N, n_exp, M)
            nearest = np.argmin(distance, axis=2)
            start = orbits[nearest, np.arange(usable.shape[1])]
            steps = self.steps[:self.size][nearest, np.arange(usable.shape[1])].astype(float)
            far = ~np.isfinite(np.min(distance, axis=2))
        with np.errstate(invalid="ignore"):
            steps = steps * np.maximum(1.0, np.nan_to_num((self.rtols[nearest] / rtol) ** 0.25, nan=1.0))
        start[far], steps[far] = np.nan, np.nan
        return start, steps


def valid_parameter_sets(plant: Plant, params) -> np.ndarray:
    """Which rows of ``params`` (N × n_params) are plants that the plant file format accepts (docs/plant-format.md):
    the rules of servofmu.model.plant.parameter_rules, vectorised."""
    p = np.atleast_2d(np.asarray(params, dtype=float))
    rules = parameter_rules(plant)
    with np.errstate(invalid="ignore"):
        ok = np.all(np.isfinite(p), axis=1)
        low, high = np.array(rules.low), np.array(rules.high)
        ok &= np.all(np.where(rules.low_open, p > low, p >= low) & (p <= high), axis=1)
        ok &= np.all((p != 0) | ~np.array(rules.nonzero), axis=1)
        for a, b in rules.at_least:
            ok &= p[:, a] >= p[:, b]
        for re, im in rules.not_zero_root:
            ok &= (p[:, re] != 0) | ((p[:, im] != 0) if im >= 0 else False)
    return ok


def _chunks(n: int, progress) -> list[tuple[int, int]]:
    """One call without progress reporting; about 50 calls with it (each call keeps all threads busy)."""
    size = n if progress is None else max(1, -(-n // 50))
    return [(lo, min(n, lo + size)) for lo in range(0, n, size)]
