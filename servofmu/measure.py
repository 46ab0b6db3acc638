"""Stepped-sine measurement of an FMU into a data file (docs/measurement.md).

For every (amplitude m, frequency f) of the plan the FMU runs in Co-Simulation from rest with the input
m·sin(2πft) until the response is periodic — detected from the signal: the first harmonic and the mean
of the last periods change by less than ``threshold`` — and then for ``window_periods`` more periods,
sampled finely, from which H = V1/U1, the DC component and the distortion are computed (servofmu.frf).

Our FMUs have the excitation built in (parameters excitation_amplitude/excitation_frequency): the solver
sees the exact sine.  Any other FMU is driven through its input port, held for one sample interval at a
time (the value at the middle of the interval); U1 is then the first harmonic of that staircase and the
stored ``hold_error`` is its relative deviation from the sine.

Each worker extracts and instantiates the FMU once (FmuRunner) and resets it between experiments.
"""
from __future__ import annotations

import hashlib
import math
import platform
import shutil
import tempfile
import weakref
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from . import __version__
from .errors import UserError
from .excitation import DEFAULT_AMPLITUDES, ExperimentSpec, Plan, corner_frequency, default_frequencies
from .fileio import check_output_path
from .frf import HARMONICS, SteadyStateDetector, harmonics
from .parallel import WorkerResource, Workers
from .simulate import EXCITATION, FmuInfo, read_fmu
from .store import (ExperimentResult, Series, add_experiments, create_measurement, load_dataset, mark_complete,
                    utc_now)

SOLVER = "the FMU's own Co-Simulation solver (servofmu FMUs: adaptive RODAS4), driven through FMPy"
REAL_TYPES = ("Real", "Float64")


@dataclass(frozen=True)
class MeasureOptions:
    """How experiments are run and analysed (all stored in the file's provenance)."""

    input: str = "u"                  # FMU input variable (driven when the FMU has no built-in excitation)
    output: str = "v"                 # FMU output variable
    tolerance: float = 1e-12          # relative tolerance passed to the FMU's solver
    samples_per_period: int = 8192    # window sampling (and input hold) per period
    settle_samples_per_period: int = 64  # sampling while waiting for steady state (built-in excitation)
    window_periods: int = 1           # whole periods analysed after steady state
    threshold: float = 1e-10          # steady state: relative change of S1 and mean per period below this ...
    consecutive: int = 2              # ... for this many periods in a row
    min_periods: int = 3
    max_time: float = 60.0            # s of simulated time before giving up on a steady state
    harmonics: int = HARMONICS
    noise_snr_db: float | None = None  # optional measurement noise on v, stored beside the clean signal
    seed: int | None = None

    def validate(self) -> "MeasureOptions":
        if not 0 < self.tolerance < 1:
            raise UserError(f"--tolerance must be in (0, 1), not {self.tolerance:g}")
        if self.samples_per_period < 16 or self.settle_samples_per_period < 8:
            raise UserError("samples per period must be at least 16 (window) and 8 (settling)")
        if self.window_periods < 1 or self.consecutive < 1 or self.min_periods < 2:
            raise UserError("window_periods and consecutive must be at least 1, min_periods at least 2")
        if not self.threshold > 0:
            raise UserError(f"--threshold must be positive, not {self.threshold:g}")
        if not (math.isfinite(self.max_time) and self.max_time > 0):
            raise UserError(f"--max-time must be a positive number of seconds, not {self.max_time:g}")
        if self.noise_snr_db is not None and not math.isfinite(self.noise_snr_db):
            raise UserError(f"--noise-snr must be a finite number of dB, not {self.noise_snr_db}")
        if self.seed is not None and self.seed < 0:
            raise UserError(f"--seed must be 0 or positive, not {self.seed}")
        return self


# ---------------------------------------------------------------------------
# The FMU in a worker
# ---------------------------------------------------------------------------
class FmuError(UserError):
    """The FMU reported an error or refused a call."""


@dataclass(frozen=True)
class FmuRunnerFactory:
    """Picklable recipe for an FmuRunner: the FMU's bytes travel to the worker, which extracts them once."""

    data: bytes
    name: str
    input: str
    output: str

    def __call__(self) -> "FmuRunner":
        return FmuRunner(self.data, self.name, self.input, self.output)


class FmuRunner:
    """One extracted, instantiated Co-Simulation FMU; ``start`` resets it for the next run."""

    def __init__(self, data: bytes, name: str, input_name: str, output_name: str):
        from fmpy import extract, read_model_description

        self.name = name
        self._dir = tempfile.mkdtemp(prefix="servofmu-fmu-")
        self._cleanup = weakref.finalize(self, shutil.rmtree, self._dir, True)
        archive = Path(self._dir) / "model.fmu"
        archive.write_bytes(data)
        unzipdir = extract(str(archive), unzipdir=str(Path(self._dir) / "unzipped"))
        md = read_model_description(unzipdir, validate=False)
        self.fmi3 = md.fmiVersion.startswith("3")
        self.variables = {v.name: v for v in md.modelVariables}
        self.vr = {n: v.valueReference for n, v in self.variables.items()}
        self.input_name, self.output_name = input_name, output_name
        self.builtin = all(n in self.vr for n in EXCITATION)
        self.messages: list[str] = []
        self._fresh = True
        args = dict(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="servofmu")
        if self.fmi3:
            from fmpy.fmi3 import FMU3Slave
            self.fmu = FMU3Slave(**args)
            self._call("instantiate", lambda: self.fmu.instantiate(logMessage=self._log3))
            self._get, self._set = self.fmu.getFloat64, self.fmu.setFloat64
        else:
            from ctypes import byref

            from fmpy import calloc, free
            from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                                   fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
            from fmpy.logging import addLoggerProxy
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = fmi2CallbackLoggerTYPE(self._log2)
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            addLoggerProxy(byref(callbacks))
            self._callbacks = callbacks  # keep alive while the FMU lives
            self.fmu = FMU2Slave(**args)
            self._call("instantiate", lambda: self.fmu.instantiate(callbacks=callbacks))
            self._get, self._set = self.fmu.getReal, self.fmu.setReal
        self._vr_in, self._vr_out = self.vr[input_name], self.vr[output_name]

    # FMU log messages are collected, never printed; the last one explains a failure.
    def _log3(self, env, status, category, message):
        self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))

    def _log2(self, env, instance, status, category, message):
        self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))

    def _call(self, what: str, fn):
        try:
            return fn()
        except Exception as exc:  # fmpy raises FMICallException or plain Exception
            raise self._failure(what, exc) from None

    def _failure(self, what: str, exc: Exception) -> FmuError:
        detail = self.messages[-1] if self.messages else (str(exc).splitlines() or [type(exc).__name__])[0]
        return FmuError(f"{self.name}: {what} failed: {detail}")

    def start(self, tolerance: float, values: dict[str, float]) -> None:
        """Reset (after the first run), set ``values``, initialise at t = 0 with ``tolerance``."""
        self.messages.clear()
        if not self._fresh:
            self._call("fmiReset", self.fmu.reset)
        self._fresh = False
        refs = [self.vr[n] for n in values]
        self._call("setting start values", lambda: self._set(refs, [float(x) for x in values.values()]))
        if self.fmi3:
            self._call("initialisation", lambda: self.fmu.enterInitializationMode(tolerance=tolerance,
                                                                                 startTime=0.0))
        else:
            self._call("initialisation", lambda: (self.fmu.setupExperiment(tolerance=tolerance, startTime=0.0),
                                                  self.fmu.enterInitializationMode()))
        self._call("initialisation", self.fmu.exitInitializationMode)

    def value(self) -> float:
        """The output now."""
        return self._get([self._vr_out])[0]

    def set_input(self, value: float) -> None:
        self._set([self._vr_in], [value])

    def step(self, t: float, h: float) -> float:
        """One communication step from t to t + h; returns the output at t + h."""
        try:
            self.fmu.doStep(t, h)
        except Exception as exc:
            raise self._failure(f"doStep at t = {t:.9g} s", exc) from None
        return self._get([self._vr_out])[0]

    def finish(self) -> None:
        self._call("fmiTerminate", self.fmu.terminate)

    def close(self) -> None:
        try:
            self.fmu.freeInstance()
        finally:
            self._cleanup()


# ---------------------------------------------------------------------------
# One experiment (runs in a worker)
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Job:
    spec: ExperimentSpec
    options: MeasureOptions


def run_experiment(runner: FmuRunner, job: Job) -> ExperimentResult:
    """Run one experiment to steady state and analyse its window (a pure function of job and FMU)."""
    spec, opt = job.spec, job.options
    m, f = spec.amplitude, spec.frequency
    n_win = opt.samples_per_period
    if runner.builtin:
        n_set = opt.settle_samples_per_period
        runner.start(opt.tolerance, {runner.input_name: 0.0, EXCITATION[0]: m, EXCITATION[1]: f})
    else:
        n_set = n_win  # the input is held per sample: one sampling from start to end
        runner.start(opt.tolerance, {runner.input_name: 0.0})

    def time_at(period: int, i, n: int):
        # from integers, so that period boundaries are the same number however they are reached
        return (period + i / n) / f

    def excitation(t: np.ndarray, n: int) -> np.ndarray:
        # built-in: the exact sine; input port: the held value (the sine at the middle of the interval)
        return m * np.sin(2 * np.pi * f * (t if runner.builtin else t + 0.5 / (n * f)))

    def run_period(period: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        t = time_at(period, np.arange(n + 1), n)
        v = np.empty(n + 1)
        v[0] = last[0]
        held = excitation(t, n)
        for i in range(n):
            if not runner.builtin:
                runner.set_input(float(held[i]))
            v[i + 1] = runner.step(t[i], t[i + 1] - t[i])
        last[0] = v[-1]
        return t, v

    last = [runner.value()]
    detector = SteadyStateDetector(f, threshold=opt.threshold, consecutive=opt.consecutive)
    max_periods = max(opt.min_periods, int(math.ceil(opt.max_time * f)))
    keep = max(1, n_set // opt.settle_samples_per_period)  # decimation of the stored transient
    trans_t, trans_v = [np.array([0.0])], [np.array([last[0]])]
    period = 0
    while period < max_periods:
        t, v = run_period(period, n_set)
        detector.add_period(t, v)
        trans_t.append(t[keep::keep])
        trans_v.append(v[keep::keep])
        period += 1
        if period >= opt.min_periods and detector.converged:
            break
    window_t, window_v = [], []
    for p in range(period, period + opt.window_periods):
        t, v = run_period(p, n_win)
        window_t.append(t if not window_t else t[1:])
        window_v.append(v if not window_v else v[1:])
    runner.finish()
    wt, wv = np.concatenate(window_t), np.concatenate(window_v)
    start = time_at(period, 0, 1)
    h = harmonics(wt, wv, f, start=start, periods=opt.window_periods, n_harmonics=opt.harmonics)
    if runner.builtin:
        u1, hold_error = complex(m), 0.0
    else:
        # first harmonic of the midpoint-held staircase; its rms deviation from the sine, relative
        sinc = float(np.sinc(1.0 / n_win))
        u1, hold_error = complex(m * sinc), math.sqrt(2 * (1 - sinc))
    tt, tv = np.concatenate(trans_t), np.concatenate(trans_v)
    transient = Series(time=tt, u=excitation(tt, n_set), v=tv)
    window = Series(time=wt, u=excitation(wt, n_win), v=wv)
    noise = {}
    if opt.noise_snr_db is not None:
        transient, window, noise = _add_noise(transient, window, opt, spec, u1, start)
    return ExperimentResult(
        index=spec.index, amplitude=m, frequency=f, excitation="builtin" if runner.builtin else "input",
        U1=u1, V1=h.first, H=h.first / u1, dc=h.dc, harmonics=h.phasors, distortion=h.distortion,
        converged=detector.converged, settling_time=start, last_change=detector.last_change,
        remaining_error=detector.remaining_error, window_start=start, window_periods=opt.window_periods,
        samples_per_period=n_win, hold_error=hold_error, transient=transient, window=window, **noise)


def _add_noise(transient: Series, window: Series, opt: MeasureOptions, spec: ExperimentSpec, u1: complex,
               start: float):
    """White Gaussian noise on v at the given SNR (power of v's variation over the window / noise power);
    the generator is seeded with (seed, experiment index), so the noise does not depend on which worker
    runs the experiment."""
    rng = np.random.default_rng([opt.seed or 0, spec.index])  # seed None (library use) means 0
    sigma = math.sqrt(float(np.var(window.v)) / 10 ** (opt.noise_snr_db / 10))
    tn = transient.v + sigma * rng.standard_normal(transient.v.shape)
    wn = window.v + sigma * rng.standard_normal(window.v.shape)
    h = harmonics(window.time, wn, spec.frequency, start=start, periods=opt.window_periods, n_harmonics=1)
    return (Series(transient.time, transient.u, transient.v, v_noisy=tn),
            Series(window.time, window.u, window.v, v_noisy=wn),
            dict(noise_sigma=sigma, H_noisy=h.first / u1, dc_noisy=h.dc))


def run_step_response(runner: FmuRunner, amplitude: float, tolerance: float, max_time: float = 1000.0):
    """v(t) after a step of ``amplitude`` on the input at t = 0, long enough to be settled
    (the horizon grows ×4 from 1 s until the last quarter varies by < 2 % and the 63 % point is early)."""
    values = {runner.input_name: amplitude}
    if runner.builtin:
        values[EXCITATION[0]] = 0.0
    runner.start(tolerance, values)
    ts, vs = [0.0], [runner.value()]
    horizon, t = 1.0, 0.0
    while True:
        grid = np.linspace(t, horizon, 1001)[1:]
        for tn in grid:
            vs.append(runner.step(t, tn - t))
            ts.append(tn)
            t = tn
        tt, vv = np.asarray(ts), np.asarray(vs)
        tail = vv[tt >= 0.75 * horizon]
        final = float(np.mean(tail))
        spread = float(np.max(tail) - np.min(tail))
        early = np.any(np.abs(vv[tt <= 0.25 * horizon]) >= (1 - math.exp(-1)) * abs(final))
        if abs(final) > 0 and spread < 0.02 * abs(final) and early:
            runner.finish()
            return tt, vv
        if horizon >= max_time:
            runner.finish()
            raise UserError(f"{runner.name}: the step response of {runner.output_name!r} does not settle within "
                            f"{max_time:g} s: cannot estimate the bandwidth (give --frequencies)")
        horizon *= 4


# ---------------------------------------------------------------------------
# The whole measurement (main process)
# ---------------------------------------------------------------------------
def check_fmu(info: FmuInfo, options: MeasureOptions) -> None:
    """The FMU can be measured: Co-Simulation, a real input and a real output of the given names."""
    if "cs" not in info.interfaces:
        raise UserError(f"{info.path}: the FMU has no Co-Simulation interface (measure needs one)")
    for role, name in (("input", options.input), ("output", options.output)):
        var = info.variables.get(name)
        if var is None:
            reals = sorted(n for n, v in info.variables.items()
                           if v.type in REAL_TYPES and v.causality == role)
            raise UserError(f"{info.path}: the FMU has no variable named {name!r} (its real {role}s: "
                            f"{', '.join(reals) or 'none'}; choose one with --{role})")
        if var.type not in REAL_TYPES:
            raise UserError(f"{info.path}: variable {name!r} is of type {var.type}, not a real number")
        if role == "input" and var.causality != "input":
            raise UserError(f"{info.path}: variable {name!r} has causality {var.causality}, not input")


def fmu_parameters(info: FmuInfo) -> dict[str, float]:
    """Start values of the FMU's real parameters (what it runs with unless measure sets them)."""
    out = {}
    for name, var in info.variables.items():
        if var.causality == "parameter" and var.type in REAL_TYPES and var.start is not None:
            try:
                out[name] = float(var.start)
            except (TypeError, ValueError):
                continue
    return out


# Provenance entries that must agree for --resume to continue a file.
RESUME_KEYS = ("fmu_sha256", "input", "output", "excitation", "tolerance", "samples_per_period",
               "settle_samples_per_period", "window_periods", "threshold", "consecutive", "min_periods",
               "max_time", "harmonics", "noise_snr_db", "seed")


def provenance_for(info: FmuInfo, sha: str, options: MeasureOptions, command: str, frequency_source: str) -> dict:
    import fmpy
    import h5py

    opts = asdict(options)
    prov = {
        "package": "servofmu", "package_version": __version__, "command": command,
        "created": utc_now(), "fmu_file": info.path.name, "fmu_sha256": sha, "fmu_model_name": info.model_name,
        "fmi_version": info.fmi_version, "interface": "CoSimulation", "solver": SOLVER,
        "excitation": "builtin" if info.has_builtin_excitation else "input",
        "frequency_source": frequency_source,
        "python": platform.python_version(), "fmpy_version": fmpy.__version__, "numpy_version": np.__version__,
        "h5py_version": h5py.__version__,
    }
    prov.update({k: v for k, v in opts.items() if v is not None})
    return prov



def _check_resume(path: Path, existing, prov: dict, plan: Plan) -> None:
    if existing.kind != "measurement":
        raise UserError(f"{path}: is a {existing.kind} file, not a measurement to resume")
    for key in RESUME_KEYS:
        old, new = existing.provenance.get(key), prov.get(key)
        if isinstance(old, float) or isinstance(new, float):
            same = old is not None and new is not None and float(old) == float(new)
        else:
            same = old == new
        if not same:
            what = "a different FMU" if key == "fmu_sha256" else f"{key} = {old}, not {new}"
            raise UserError(f"{path}: cannot resume: it was measured with {what}")
    if existing.plan != plan:
        raise UserError(f"{path}: cannot resume: its plan is amplitudes {_fmt(existing.plan.amplitudes)} × "
                        f"frequencies {_fmt(existing.plan.frequencies)}, not {_fmt(plan.amplitudes)} × "
                        f"{_fmt(plan.frequencies)}")


def _fmt(values) -> str:
    return ",".join(f"{v:g}" for v in values)


def estimate_bandwidth(factory: FmuRunnerFactory, amplitude: float, tolerance: float) -> float:
    """The plant's bandwidth (Hz) from its step response (excitation.corner_frequency)."""
    runner = factory()
    try:
        t, v = run_step_response(runner, amplitude, tolerance)
    finally:
        runner.close()
    return corner_frequency(t, v)


def measure(fmu: str | Path, output: str | Path, amplitudes=None, frequencies=None,
            options: MeasureOptions | None = None, scheduler: str | None = None, workers: int | None = None,
            resume: bool = False, command: str = "", progress: Callable[[int, int], None] | None = None,
            warn: Callable[[str], None] | None = None):
    """Measure ``fmu`` at every (amplitude, frequency) into the data file ``output``; returns the Dataset.

    ``frequencies=None``: a 1-2-5 grid around the bandwidth estimated from a step response (or, when
    resuming, the file's).  ``progress(done, total)`` after every stored experiment; ``warn(text)`` for
    experiments that did not reach a steady state.
    """
    options = (options or MeasureOptions()).validate()
    if options.noise_snr_db is not None and options.seed is None:
        options = replace(options, seed=0)  # recorded in the provenance like a given seed
    out = check_output_path(output)
    existing = None
    if out.exists():
        if not resume:
            raise UserError(f"{out}: exists already (use --resume to continue it, or choose another name)")
        existing = load_dataset(out)
    info = read_fmu(fmu)
    check_fmu(info, options)
    data = info.path.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    factory = FmuRunnerFactory(data=data, name=info.path.name, input=options.input, output=options.output)

    if amplitudes is None:
        amplitudes = existing.plan.amplitudes if existing is not None and existing.plan else DEFAULT_AMPLITUDES
    amplitudes = Plan(tuple(amplitudes), (1.0,)).amplitudes  # validates
    if frequencies is not None:
        source = "given"
    elif existing is not None and existing.plan:
        frequencies, source = existing.plan.frequencies, existing.provenance.get("frequency_source", "given")
    else:
        bandwidth = estimate_bandwidth(factory, max(amplitudes), options.tolerance)
        frequencies = default_frequencies(bandwidth)
        source = f"1-2-5 grid over 0.25..15 x the bandwidth {bandwidth:.6g} Hz estimated from a step response"
    plan = Plan(tuple(amplitudes), tuple(frequencies))
    prov = provenance_for(info, sha, options, command, source)
    if existing is not None:
        _check_resume(out, existing, prov, plan)
    todo = existing.missing() if existing is not None else plan.experiments
    total, done = len(plan), len(plan) - len(todo)
    jobs = [Job(spec, options) for spec in todo]
    resource = WorkerResource(key=f"fmu:{sha}:{options.input}:{options.output}", factory=factory)
    with Workers(scheduler=scheduler, workers=workers) as pool:  # connects first: a bad scheduler writes nothing
        if existing is None:
            create_measurement(out, plan, prov, fmu_parameters(info))
        if progress:
            progress(done, total)
        for _, result in pool.imap(run_experiment, jobs, resource=resource):
            add_experiments(out, [result])
            done += 1
            if warn and not result.converged:
                warn(f"experiment {result.index} (amplitude {result.amplitude:g}, frequency {result.frequency:g} Hz)"
                     f" reached no steady state within {options.max_time:g} s (last change per period "
                     f"{result.last_change:.2g}); it is stored with converged = false")
            if progress:
                progress(done, total)
    mark_complete(out)
    return load_dataset(out)
