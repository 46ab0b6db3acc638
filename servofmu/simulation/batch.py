"""Batch simulator: one plant structure, many parameter sets, compiled once.

A :class:`BatchSimulator` generates C code for the plant's right-hand side and
Jacobian from the same CasADi model as the FMU (``servofmu.model.symbolic``), and
compiles it with a driver (``batch_c/batch_driver.c``) that uses the FMU core's
RODAS4 integrator (``fmu/c/servo_core.c``) into a shared library, kept in a
cache on disk (:func:`compiled_driver`) so that a process which finds it there
generates and compiles nothing.  It then runs

* :meth:`BatchSimulator.steady_state`: stepped-sine experiments.  Experiment k
  is u = 0 plus the excitation m·sin(2πf t), all states zero at t = 0 (or
  where a nearby parameter set's run ended: ``start``).  The plant is
  integrated period by period until a period ends where it began: every state
  within max(``tol``, 3·``rtol``) of its scale (the largest magnitude it has
  reached, the integrator's error scale) — steady periods integrated at rtol
  differ by up to about 2·rtol (the step sequence may alternate from period to
  period) — or ``max_time`` is reached; ``converged`` is then False and the
  features of the last period are returned.  Per experiment:

  - ``H`` = V1/U1 with S1 = j·(2/T)∫_period s(t)·exp(−j2πft) dt, so that
    s ≈ |S1|·sin(2πft + arg S1); U1 = m;
  - ``dc`` = mean of v over the period;
  - ``distortion`` = sqrt(Σ_{k≥2}|V_k|²)/|V1| over all harmonics, from
    Parseval: Σ_{k≥1}|V_k|²/2 = mean((v − dc)²) over the period.

  The integrals are quadrature states of the integrator (q' = v, v·cos, v·sin,
  v²), not sums over samples.  In steady state the features do not depend on
  which period they come from, nor on how the transient was computed, so
  four speed-ups leave them unchanged: a run from rest integrates its periods
  at rtol = 1e-4 until one ends within 1e-2 of where it began (only the
  periods after, at ``rtol``, decide convergence); ``start`` begins a run on a
  nearby orbit (:class:`WarmStarts`); ``accelerate`` finds the fixed point of
  the period map by Newton's method (shooting: the period's monodromy matrix
  from the variational equations integrated beside the states, or a nearby
  orbit's), stepping only towards an orbit whose multipliers lie within 0.99
  — an orbit that is not attracting is no steady state, a plain run never
  settles there — and undoing a step after which the period moves more than
  before; and ``give_up_early`` stops an experiment whose period-to-period
  change does not decay fast enough to converge within ``max_time``
  (converged = False, as at ``max_time``).  A warm start or Newton's step may
  in principle reach another attracting orbit than a run from rest would,
  where several coexist.  ``settle_time`` is the simulated time used, not
  that of a plain run.

* :meth:`BatchSimulator.simulate_record`: the response (v and the position)
  at the sample times to a sampled input u, held constant between samples
  (``hold="zoh"``: a digital drive's command) or linear between them
  (``"foh"``), all states zero at the first sample, the model's own excitation
  off; every sample interval is integrated on its own, so that no step
  straddles a jump of the input.  :meth:`BatchSimulator.simulate_sine` gives the
  same response to the exact sine of a stepped-sine experiment.

Parameter vectors follow ``plant.parameter_names()``.  A parameter set that the
plant file format would reject (non-finite, a pole with a positive real part,
negative friction, ... see :func:`valid_parameter_sets`) or whose integration
fails gives NaN results instead of an error.  Tasks (parameter set ×
experiment) run on ``threads`` POSIX threads inside the library (default: the
cores this process may use); results do not depend on the number of threads.
Speed and accuracy per tolerance: docs/bench-batch.md.
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import importlib.util
import os
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UserError
from ..model.plant import Plant, parameter_rules
from ..model.signals import INTERSAMPLE
from ..runtime import available_cores, cache_dir, compile_shared, compiler_signature, temporary_folder
from ..version import __version__

if TYPE_CHECKING:  # CasADi is loaded only to generate code, which a cached library spares
    import casadi as ca

    from ..model.symbolic import SymbolicModel

__all__ = ["BatchSimulator", "SteadyStateOptions", "SteadyStateFeatures", "WarmStarts", "RecordResponse",
           "valid_parameter_sets", "batch_functions", "ModelStructureError", "compiled_driver", "library_key",
           "write_batch_sources", "H_START", "c_doubles", "c_mask"]

PACKAGE = Path(__file__).resolve().parent.parent
DRIVER_DIR = PACKAGE / "simulation" / "batch_c"  # the C drivers of the batch and loop simulators
DRIVER = DRIVER_DIR / "batch_driver.c"
FMU_C_DIR = PACKAGE / "fmu" / "c"  # servo_core.c: the FMU's integrator, which the driver includes
# The Python modules whose code writes the generated C sources (with the C files, part of a library's cache key).
GENERATORS = ("model/plant.py", "model/symbolic.py", "model/signals.py", "fmu/sources.py", "fmu/variables.py",
              "simulation/batch.py")
EXTRA_CFLAGS = ("-pthread", "-O3")
# On x86-64 the library is built for this machine's processor: about 10 % faster steady states.  No contraction
# into fused multiply-adds, so that results stay bit for bit those of a portable build; the processor is part of
# the cache key, so that a cache shared by several machines never hands one a library it cannot run.
NATIVE_CFLAGS = ("-march=native", "-ffp-contract=off")
_HOLD_CODES = {"zoh": 0, "foh": 1, "sine": 2}  # the driver's HOLD_* values
N_RESULTS = 8  # per sine task: re S1, im S1, DC, mean square, converged, settle time, steps, rejected steps
H_START = 1e-4  # first step of every period, as a fraction of the period (the same each period: see the driver)


class ModelStructureError(UserError):
    """The plant's equations are not of the form the batch simulator integrates."""


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
    (exceeding it gives NaN).  ``accelerate``, ``give_up_early``: see the
    module docstring.
    """

    rtol: float = 1e-8
    tol: float = 1e-10
    max_time: float = 60.0
    min_periods: int = 1
    max_steps: int = 5_000_000
    accelerate: bool = True
    give_up_early: bool = True

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
        self.n_states = ns.value  # integrated states (all but the position)

    @staticmethod
    def _load(plant: Plant) -> ctypes.CDLL:
        """The compiled library (a subclass with a driver of its own loads that)."""
        return _library(plant)

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
        out = np.empty((n, n_exp, N_RESULTS))
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
                                   int(options.give_up_early), self.threads,
                                   None if start is None else c_doubles(start[lo:hi]), c_doubles(out[lo:hi]),
                                   c_doubles(orbit[lo:hi]))
            if rc != 0:
                raise RuntimeError(f"batch library rejected the call (code {rc})")
            if progress is not None:
                progress(hi, n)
        s1 = out[..., 0] + 1j * out[..., 1]
        dc, mean_square = out[..., 2], out[..., 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            harmonics = np.maximum(2 * (mean_square - dc ** 2) - np.abs(s1) ** 2, 0.0)
            distortion = np.sqrt(harmonics) / np.abs(s1)
        return SteadyStateFeatures(H=s1 / amp, dc=dc, distortion=distortion, converged=out[..., 4] == 1.0,
                                   settle_time=out[..., 5], steps=out[..., 6].astype(np.int64), orbit=orbit)

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
                                     c_doubles(t), c_doubles(u), _HOLD_CODES[hold], m, omega, rtol, H_START,
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
        self.params = self.orbits = None
        self.size = self.next = 0

    def add(self, params, features: SteadyStateFeatures) -> None:
        """Remember the runs of ``features`` (of the parameter sets ``params``) that converged."""
        params = np.atleast_2d(np.asarray(params, dtype=float))
        some = np.any(features.converged, axis=1)
        params = params[some][-self.capacity:]
        orbits = np.where(features.converged[some, :, None], features.orbit[some], np.nan)[-self.capacity:]
        if self.params is None:
            self.params = np.empty((self.capacity,) + params.shape[1:])
            self.orbits = np.empty((self.capacity,) + orbits.shape[1:])
        rows = (self.next + np.arange(len(params))) % self.capacity
        self.params[rows], self.orbits[rows] = params, orbits
        self.next = (self.next + len(params)) % self.capacity
        self.size = min(self.size + len(params), self.capacity)

    def start(self, params) -> np.ndarray | None:
        """``start`` for the parameter sets ``params`` (N, n_params): shape (N, n_exp, orbit), NaN where no
        run converged in an experiment; None before anything converged."""
        if self.size == 0:
            return None
        known, orbits = self.params[:self.size], self.orbits[:self.size]
        p = np.atleast_2d(np.asarray(params, dtype=float))[:, None, :]
        scale = np.abs(p) + np.abs(known)
        with np.errstate(invalid="ignore"):
            rel = np.divide(p - known, scale, out=np.zeros(scale.shape), where=scale != 0)  # 0 where both are 0
        distance = np.nan_to_num(np.sum(rel ** 2, axis=2), nan=np.inf)  # (N, M); a NaN set is near nothing
        usable = np.isfinite(orbits[..., 0])  # (M, n_exp)
        if usable.all():  # the usual case: one nearest set for all experiments
            nearest = np.argmin(distance, axis=1)
            start = orbits[nearest]
            start[~np.isfinite(distance[np.arange(len(nearest)), nearest])] = np.nan
            return start
        distance = np.where(usable.T[None], distance[:, None, :], np.inf)  # (N, n_exp, M)
        nearest = np.argmin(distance, axis=2)
        start = orbits[nearest, np.arange(usable.shape[1])]
        start[~np.isfinite(np.min(distance, axis=2))] = np.nan
        return start


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


# ---------------------------------------------------------------------------------------------------------------
# The compiled library
# ---------------------------------------------------------------------------------------------------------------
def batch_functions(model: SymbolicModel) -> tuple[ca.Function, ca.Function]:
    """The right-hand side the driver integrates, from the plant's symbolic model.

    ``sb_ode(x, u, p) -> xdot`` and ``sb_jac(x, u, p) -> (dxdot/dx, dxdot/du)`` (dense) for the states without
    the position, the plant's parameters ``p`` and the model's own excitation removed (the driver puts the sine
    into u).  Checks what the driver relies on: v is the first state and nothing depends on the position.
    """
    import casadi as ca

    names = model.parameter_names
    pos = model.state_names.index("position")
    keep = [i for i in range(model.nx) if i != pos]
    x = ca.vertcat(*[model.x[i] for i in keep])
    n_plant = len(model.plant.parameter_names())
    p = model.p[:n_plant]
    xdot = ca.substitute(model.xdot, model.p[names.index("excitation_amplitude")], ca.SX(0))
    xdot = ca.vertcat(*[xdot[i] for i in keep])
    if not ca.is_equal(model.y[0], model.x[0]) or pos == 0:
        raise ModelStructureError(f"{model.plant.name}: the batch simulator needs v as the first state")
    if ca.jacobian(model.xdot, model.x[pos]).nnz() != 0 or ca.depends_on(xdot, model.t):
        raise ModelStructureError(f"{model.plant.name}: the batch simulator needs equations that depend neither on the "
                         "position nor, apart from the excitation, on time")
    ode = ca.Function("sb_ode", [x, model.u, p], [ca.densify(xdot)], ["x", "u", "p"], ["xdot"])
    jacobians = [ca.densify(ca.jacobian(xdot, x)), ca.densify(ca.jacobian(xdot, model.u))]
    jac = ca.Function("sb_jac", [x, model.u, p], jacobians, ["x", "u", "p"], ["J", "B"])
    return ode, jac


def write_batch_sources(model: SymbolicModel, src: Path) -> None:
    """batch_eqs.c (CasADi) and batch_config.h (sizes) for the driver; the FMU's sources via generate_sources."""
    import casadi as ca

    from ..fmu.sources import generate_sources
    from ..fmu.variables import state_nominals

    generate_sources(model, src, model.plant.name)  # model_eqs.c, model_config.h: what servo_core.c needs
    functions = batch_functions(model)
    cg = ca.CodeGenerator("batch_eqs.c", {"with_header": False})
    for fn in functions:
        cg.add(fn)
    cg.generate(str(src) + os.sep)
    sizes = {k: max(getattr(f, k)() for f in functions) for k in ("sz_arg", "sz_res", "sz_iw", "sz_w")}
    nominal = [n for i, n in enumerate(state_nominals(model)) if model.state_names[i] != "position"]
    (src / "batch_config.h").write_text(
        f"/* Sizes of the batch simulator of plant {model.plant.name}. */\n"
        f"#define SB_NS {functions[0].size1_in(0)}\n#define SB_NP {functions[0].size1_in(2)}\n"
        f"#define SB_SZ_ARG {max(sizes['sz_arg'], 3)}\n#define SB_SZ_RES {max(sizes['sz_res'], 2)}\n"
        f"#define SB_SZ_IW {sizes['sz_iw']}\n#define SB_SZ_W {sizes['sz_w']}\n"
        f"#define SB_X_NOMINAL {{{', '.join(repr(float(v)) for v in nominal)}}}\n")


def compiled_driver(plant: Plant, driver: Path, extra: dict[str, str] | None = None) -> ctypes.CDLL:
    """The shared library of a driver C file compiled with the plant's batch sources (write_batch_sources) and
    ``extra`` generated files (name -> text).

    Libraries are kept in cache_dir() under a key of everything that determines them (:func:`library_key`), so
    that a process which finds its library there loads it without generating or compiling anything.  A new
    library is compiled in a temporary folder and renamed into the cache: processes building the same library
    at once all end with one complete file.  Deleting the folder is safe; libraries are rebuilt on demand.
    """
    extra = extra or {}
    name = f"{driver.stem}-{plant.name}-{library_key(plant, driver, extra)[:24]}.so"
    target = cache_dir() / name
    with temporary_folder("batch") as tmp:
        if not target.is_file():
            target = _build(plant, driver, extra, Path(tmp), target)
        lib = ctypes.CDLL(str(target))  # inside: a library left in the temporary folder is mapped before it goes
    _declare(lib)
    ns, n_p, nf = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
    lib.sb_sizes(ctypes.byref(ns), ctypes.byref(n_p), ctypes.byref(nf))
    if (n_p.value, nf.value) != (len(plant.parameter_names()), N_RESULTS):
        raise ModelStructureError(f"{target}: compiled library does not match plant {plant.name}")
    return lib


@functools.lru_cache(maxsize=None)
def driver_cflags() -> tuple[str, ...]:
    """The compiler flags of the batch drivers, beyond runtime.CFLAGS (see NATIVE_CFLAGS)."""
    if platform.machine().lower() in ("x86_64", "amd64"):
        return (*EXTRA_CFLAGS, *NATIVE_CFLAGS)
    return EXTRA_CFLAGS


@functools.lru_cache(maxsize=None)
def _processor() -> str:
    """What identifies this machine's processor for code built for it: its model and features (Linux), else
    what the platform module says."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return f"{platform.machine()} {platform.processor()}"
    first = {}
    for line in lines:
        key, _, value = line.partition(":")
        first.setdefault(key.strip(), value.strip())
    return " ".join(first.get(k, "") for k in ("vendor_id", "model name", "flags"))


def library_key(plant: Plant, driver: Path, extra: dict[str, str]) -> str:
    """The cache key (SHA-256, hex) of a compiled driver: the plant (its file text: the structure, and the
    nominal values that scale the states), servofmu's version, the Python code that generates the C sources
    (GENERATORS), every C file of the driver's, the batch driver's and the FMU core's folders, the ``extra``
    texts, the CasADi installation, the compiler with its flags, and the processor when built for it."""
    digest = hashlib.sha256()
    native = driver_cflags() != EXTRA_CFLAGS
    for text in (plant.to_toml(), __version__, compiler_signature(driver_cflags()), _casadi_stamp(),
                 _processor() if native else ""):
        digest.update(text.encode() + b"\0")
    folders = {FMU_C_DIR, DRIVER.parent, driver.parent}
    files = [PACKAGE / g for g in GENERATORS] + sorted(f for d in folders for f in d.iterdir()
                                                     if f.suffix in (".c", ".h"))
    for path in [*files, driver]:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    for name, text in sorted(extra.items()):
        digest.update(name.encode() + b"\0" + text.encode())
    return digest.hexdigest()


def _casadi_stamp() -> str:
    """Which CasADi generates the code, without importing it: its location, size and modification time."""
    spec = importlib.util.find_spec("casadi")
    if spec is None or spec.origin is None:
        return "no casadi"
    stat = os.stat(spec.origin)
    return f"{spec.origin} {stat.st_size} {stat.st_mtime_ns}"


def _build(plant: Plant, driver: Path, extra: dict[str, str], src: Path, target: Path) -> Path:
    """Generate the sources into ``src``, compile, and move the library to ``target`` (the library's path in the
    temporary folder ``src`` when the cache is not writable)."""
    from ..model.symbolic import build_model

    write_batch_sources(build_model(plant), src)
    for name, text in extra.items():
        (src / name).write_text(text)
    built = src / target.name
    # the driver's unit includes batch_eqs.c and servo_core.c; model_eqs.c serves servo_core.c
    compile_shared([driver, src / "model_eqs.c"], built, include=[src, FMU_C_DIR, DRIVER.parent, driver.parent],
                   extra_flags=driver_cflags(), what=f"the {driver.stem} of {plant.name}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(f".{target.name}.{os.getpid()}.part")
        partial.write_bytes(built.read_bytes())
        os.replace(partial, target)  # atomic: concurrent builders all end with a complete file
    except OSError:
        return built  # no writable cache
    return target


@functools.lru_cache(maxsize=None)
def _library(plant: Plant) -> ctypes.CDLL:
    return compiled_driver(plant, DRIVER)


def _declare(lib: ctypes.CDLL) -> None:
    d, pd, lng, i = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_long, ctypes.c_int
    pu = ctypes.POINTER(ctypes.c_ubyte)
    lib.sb_sizes.argtypes = [ctypes.POINTER(i)] * 3
    lib.sb_sine.argtypes = [lng, i, pd, pu, i, pd, pd, d, d, d, lng, d, lng, lng, lng, i, pd, pd, pd]
    lib.sb_sine.restype = i
    lib.sb_record.argtypes = [lng, i, pd, pu, lng, pd, pd, i, d, d, d, d, lng, i, pd]
    lib.sb_record.restype = i


def c_doubles(a: np.ndarray):
    assert a.flags.c_contiguous and a.dtype == np.float64  # internal invariant, not input validation
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def c_mask(mask: np.ndarray):
    assert mask.flags.c_contiguous and mask.dtype == np.uint8
    return mask.ctypes.data_as(ctypes.POINTER(ctypes.c_ubyte))


def _chunks(n: int, progress) -> list[tuple[int, int]]:
    """One call without progress reporting; about 50 calls with it (each call keeps all threads busy)."""
    size = n if progress is None else max(1, -(-n // 50))
    return [(lo, min(n, lo + size)) for lo in range(0, n, size)]
