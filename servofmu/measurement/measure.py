"""Stepped-sine measurement of an FMU into a data file (docs/measurement.md).

For every (amplitude m, frequency f) of the plan the FMU runs in Co-Simulation from rest with the input
m·sin(2πft) until the response is periodic — detected from the signal: the first harmonic and the mean
of the last periods change by less than ``threshold`` — and then for ``window_periods`` more periods,
sampled finely, from which H = V1/U1, the DC component and the distortion are computed (servofmu.measurement.frf).

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
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..display import options_html, options_repr
from ..errors import ServofmuWarning, UserError, check_int
from ..fileio import claim_output, holds_outputs, output_mode
from ..runtime import RunOptions, check_memory, utc_now
from ..simulation.fmpy_runs import EXCITATION, FmuInfo, read_fmu
from ..simulation.fmu_runner import FmuRunner, FmuRunnerFactory
from ..simulation.parallel import WorkerResource, Workers, report
from ..version import __version__
from .datafile import (DataFile, ExperimentResult, Series, add_experiments, create_measurement, mark_complete,
                       read_data_file)
from .excitation import (DEFAULT_AMPLITUDES, MAX_STEPS, ExperimentSpec, Plan, default_frequencies,
                         estimate_bandwidth)
from .frf import HARMONICS, SteadyStateDetector, harmonics

__all__ = ["MeasureOptions", "measure", "run_experiment", "Job", "check_fmu", "check_work",
           "MAX_STEPS", "PROGRESS_SCALE"]

SOLVER = "the FMU's own Co-Simulation solver (servofmu FMUs: adaptive RODAS4), driven through FMPy"
REAL_TYPES = ("Real", "Float64")
REPORT_EVERY = 1.0  # s between progress reports of a running experiment
PROGRESS_SCALE = 1000  # measure's progress counts thousandths of an experiment


@dataclass(frozen=True)
class MeasureOptions:
    """How experiments are run and analysed (all stored in the file's provenance).

    Parameters
    ----------
    input, output : str
        The FMU's input variable (driven when the FMU has no built-in excitation) and output variable.
    tolerance : float
        Relative tolerance passed to the FMU's solver.
    samples_per_period, settle_samples_per_period : int
        Sampling of the analysed window (and of the input hold), and while waiting for steady state.
    window_periods : int
        Whole periods analysed after steady state.
    threshold, consecutive, min_periods : float, int, int
        Steady state: the first harmonic and mean change by less than ``threshold`` per period, for
        ``consecutive`` periods in a row, after at least ``min_periods``.
    max_time : float
        Simulated seconds before an experiment counts as not settled.
    harmonics : int
        Highest harmonic kept for the distortion.
    noise_snr_db, seed : float, int, optional
        Measurement noise on v at this SNR (stored beside the clean signal), and its seed.
    """

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
    _units = {"max_time": "s", "noise_snr_db": "dB"}
    __repr__, _repr_html_ = options_repr, options_html

    def validate(self) -> "MeasureOptions":
        """These options, after checking every value (UserError naming the first bad one)."""
        if not 0 < self.tolerance < 1:
            raise UserError(f"tolerance must be in (0, 1), not {self.tolerance:g}")
        if self.samples_per_period < 16 or self.settle_samples_per_period < 8:
            raise UserError("samples per period must be at least 16 (window) and 8 (settling)")
        if self.window_periods < 1 or self.consecutive < 1 or self.min_periods < 2:
            raise UserError("window_periods and consecutive must be at least 1, min_periods at least 2")
        if not self.threshold > 0:
            raise UserError(f"threshold must be positive, not {self.threshold:g}")
        if not (math.isfinite(self.max_time) and self.max_time > 0):
            raise UserError(f"max_time must be a positive number of seconds, not {self.max_time:g}")
        if self.noise_snr_db is not None and not math.isfinite(self.noise_snr_db):
            raise UserError(f"noise_snr_db must be a finite number of dB, not {self.noise_snr_db}")
        if self.seed is not None:
            check_int("seed", self.seed, 0)
        return self


# ---------------------------------------------------------------------------
# One experiment (runs in a worker)
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Job:
    """One experiment to measure and the options to measure it with (what a worker receives)."""

    spec: ExperimentSpec
    options: MeasureOptions


class _Periods:
    """Runs whole periods of one experiment on a started FMU and keeps the last output value."""

    def __init__(self, runner: FmuRunner, spec: ExperimentSpec, opt: MeasureOptions):
        self.runner, self.m, self.f, self.index = runner, spec.amplitude, spec.frequency, spec.index
        # the most periods the experiment may run (settling up to max_time, then the window): what progress is of
        self.budget = max(opt.min_periods, math.ceil(opt.max_time * self.f)) + opt.window_periods
        self._reported = time.monotonic()
        if runner.builtin:
            self.settle_samples = opt.settle_samples_per_period
            runner.start(opt.tolerance, {runner.input_name: 0.0, EXCITATION[0]: self.m, EXCITATION[1]: self.f})
        else:
            self.settle_samples = opt.samples_per_period  # the input is held per sample: one sampling throughout
            runner.start(opt.tolerance, {runner.input_name: 0.0})
        self.last = runner.value()

    def times(self, period: int, i, n: int):
        """Sample times from integers, so that period boundaries are the same number however they are reached."""
        return (period + np.asarray(i) / n) / self.f

    def excitation(self, t: np.ndarray, n: int) -> np.ndarray:
        """Built-in: the exact sine; input port: the held value (the sine at the middle of the interval)."""
        return self.m * np.sin(2 * np.pi * self.f * (t if self.runner.builtin else t + 0.5 / (n * self.f)))

    def run(self, period: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Period ``period`` sampled ``n`` times: times and outputs (n + 1 values, both ends included)."""
        t = self.times(period, np.arange(n + 1), n)
        v = np.empty(n + 1)
        v[0] = self.last
        held = self.excitation(t, n)
        for i in range(n):
            if not self.runner.builtin:
                self.runner.set_input(float(held[i]))
            v[i + 1] = self.runner.step(t[i], t[i + 1] - t[i])
            if time.monotonic() - self._reported > REPORT_EVERY:  # for a long experiment's progress
                report(self.index, min(1.0, (period + (i + 1) / n) / self.budget))
                self._reported = time.monotonic()
        self.last = v[-1]
        return t, v


def _settle(periods: _Periods, opt: MeasureOptions) -> tuple[Series, int, SteadyStateDetector]:
    """Periods until the response is periodic (or max_time); the decimated transient, the number of periods."""
    n = periods.settle_samples
    detector = SteadyStateDetector(periods.f, threshold=opt.threshold, consecutive=opt.consecutive)
    max_periods = max(opt.min_periods, int(math.ceil(opt.max_time * periods.f)))
    keep = max(1, n // opt.settle_samples_per_period)  # decimation of the stored transient
    trans_t, trans_v = [np.array([0.0])], [np.array([periods.last])]
    period = 0
    while period < max_periods:
        t, v = periods.run(period, n)
        detector.add_period(t, v)
        trans_t.append(t[keep::keep])
        trans_v.append(v[keep::keep])
        period += 1
        if period >= opt.min_periods and detector.converged:
            break
    tt = np.concatenate(trans_t)
    return Series(time=tt, u=periods.excitation(tt, n), v=np.concatenate(trans_v)), period, detector


def _window(periods: _Periods, first: int, opt: MeasureOptions) -> Series:
    """The analysed window: ``window_periods`` periods from period ``first``, finely sampled."""
    n = opt.samples_per_period
    window_t, window_v = [], []
    for p in range(first, first + opt.window_periods):
        t, v = periods.run(p, n)
        window_t.append(t if not window_t else t[1:])
        window_v.append(v if not window_v else v[1:])
    wt = np.concatenate(window_t)
    return Series(time=wt, u=periods.excitation(wt, n), v=np.concatenate(window_v))


def run_experiment(runner: FmuRunner, job: Job) -> ExperimentResult:
    """Run one experiment to steady state and analyse its window (a pure function of job and FMU)."""
    spec, opt = job.spec, job.options
    periods = _Periods(runner, spec, opt)
    transient, settled_periods, detector = _settle(periods, opt)
    window = _window(periods, settled_periods, opt)
    runner.finish()
    start = float(periods.times(settled_periods, 0, 1))
    h = harmonics(window.time, window.v, spec.frequency, start=start, periods=opt.window_periods,
                  n_harmonics=opt.harmonics)
    if runner.builtin:
        u1, hold_error = complex(spec.amplitude), 0.0
    else:
        # first harmonic of the midpoint-held staircase; its rms deviation from the sine, relative
        sinc = float(np.sinc(1.0 / opt.samples_per_period))
        u1, hold_error = complex(spec.amplitude * sinc), math.sqrt(2 * (1 - sinc))
    noise = {}
    if opt.noise_snr_db is not None:
        transient, window, noise = _add_noise(transient, window, opt, spec, u1, start)
    return ExperimentResult(
        index=spec.index, amplitude=spec.amplitude, frequency=spec.frequency,
        excitation="builtin" if runner.builtin else "input",
        U1=u1, V1=h.first, H=h.first / u1, dc=h.dc, harmonics=h.phasors, distortion=h.distortion,
        converged=detector.converged, settling_time=start, last_change=detector.last_change,
        remaining_error=detector.remaining_error, window_start=start, window_periods=opt.window_periods,
        samples_per_period=opt.samples_per_period, hold_error=hold_error, transient=transient, window=window,
        **noise)


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
                            f"{', '.join(reals) or 'none'})")
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


# Provenance entries that must agree for a resumed run to continue a file.
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


def check_work(plan: Plan, options: MeasureOptions, builtin: bool, max_steps: float = MAX_STEPS) -> None:
    """Refuse up front a plan whose work is unbounded in practice, with the estimate in the message.

    Per experiment: the ``min_periods`` a steady state needs must fit in ``max_time`` (so that max_time is honoured
    at low frequencies); the FMU steps of settling (up to ``max_time``) and of the window must stay within
    ``max_steps``; and the file of all experiments must fit in memory (it is rewritten, in memory, after each)."""
    settle_n = options.settle_samples_per_period if builtin else options.samples_per_period
    window = options.window_periods * options.samples_per_period + 1
    file_bytes = 0.0
    for f in plan.frequencies:
        needed = options.min_periods / f
        if needed > options.max_time:
            raise UserError(f"frequency {f:g} Hz: the {options.min_periods} periods a steady state needs last "
                            f"{needed:.3g} s, more than max_time {options.max_time:g} s (raise --max-time to "
                            f"{needed:.3g}, or measure above {options.min_periods / options.max_time:.3g} Hz)")
        periods = max(options.min_periods, math.ceil(options.max_time * f))
        steps = periods * settle_n + window
        if steps > max_steps:
            raise UserError(f"frequency {f:g} Hz: an experiment may take {steps:.3g} FMU steps ({periods:.3g} "
                            f"periods of {settle_n} steps within max_time {options.max_time:g} s, plus the window), "
                            f"more than max_steps {max_steps:.3g} (lower --max-time, --samples-per-period or the "
                            "frequency, or raise --max-steps)")
        # window and transient: time, u, v (and v_noisy) as float64
        file_bytes += len(plan.amplitudes) * 8 * 4 * (window + periods * options.settle_samples_per_period)
    check_memory(f"a measurement of {len(plan)} experiments", 3 * file_bytes,
                 "lower --samples-per-period or --max-time, or measure fewer frequencies")


@holds_outputs  # a long run: its outputs are its own until it ends (fileio.output_claims)
def measure(fmu: str | Path, output: str | Path, amplitudes: Sequence[float] | None = None,
            frequencies: Sequence[float] | None = None,
            options: MeasureOptions | None = None, run: RunOptions | None = None,
            warn: Callable[[str], None] | None = None, max_steps: float = MAX_STEPS) -> DataFile:
    """Stepped-sine measurement of an FMU into a data file.

    For every (amplitude, frequency) the FMU runs in Co-Simulation from rest until its response is periodic; the
    first harmonics of a finely sampled window are stored with the time series.

    Parameters
    ----------
    fmu : str or Path
        A Co-Simulation FMU with a real input and output (servofmu's or any other).
    output : str or Path
        The data file (HDF5) to write; it grows experiment by experiment, so a killed run loses little.
    amplitudes : sequence of float, optional
        Excitation amplitudes (N); default the paper's 2.0 and 0.6.
    frequencies : sequence of float, optional
        Frequencies (Hz); default a 1-2-5 grid around the bandwidth estimated from a step response (or, when
        resuming, the file's).
    options : MeasureOptions, optional
        Variable names, tolerances, sampling, noise.
    run : RunOptions, optional
        ``scheduler`` (a Dask scheduler address; default local worker processes), ``workers`` (default one per
        core; 0: this process), ``resume`` (continue an existing ``output`` where an interrupted run stopped),
        ``overwrite`` (replace an existing ``output``: it is replaced when the new file is first written),
        ``command`` (the command line, for provenance), ``progress`` (called with (done, total) in thousandths of
        an experiment, PROGRESS_SCALE: as experiments run, each counting the periods it has run out of the most it
        may run, and when each is stored).
    max_steps : float
        Refuse a plan any of whose experiments could take more FMU steps than this (see :func:`check_work`).
    warn : callable, optional
        ``warn(text)`` receives what is otherwise issued with ``warnings.warn`` as a
        :class:`~servofmu.errors.ServofmuWarning`: an experiment that reached no steady state.

    Returns
    -------
    DataFile
        The measurement, read back from ``output``.

    Raises
    ------
    UserError
        For an unusable FMU, bad options, an existing output (without ``run.resume`` or ``run.overwrite``) or
        the FMU itself as the output, work beyond
        the bounds of :func:`check_work`, or a failing simulation.
    """
    from ..api_checks import check_arguments

    check_arguments(measure, locals())  # a wrong type: UserError naming it
    options = (options or MeasureOptions()).validate()
    if options.noise_snr_db is not None and options.seed is None:
        options = replace(options, seed=0)  # recorded in the provenance like a given seed
    run = run or RunOptions()
    out = claim_output(output, output_mode(run.overwrite, run.resume), inputs=(fmu,), can_continue="resume")
    existing = read_data_file(out) if out.exists() and run.resume else None
    info = read_fmu(fmu)
    check_fmu(info, options)
    data = info.path.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    factory = FmuRunnerFactory(data=data, name=info.path.name, input=options.input, output=options.output)
    factory().close()  # an FMU whose binary cannot be loaded fails here, before anything is written

    plan, source = _plan(amplitudes, frequencies, existing, factory, options)
    check_work(plan, options, info.has_builtin_excitation, max_steps)
    prov = provenance_for(info, sha, options, run.command, source)
    if existing is not None:
        _check_resume(out, existing, prov, plan)
    todo = existing.missing() if existing is not None else plan.experiments
    resource = WorkerResource(key=f"fmu:{sha}:{options.input}:{options.output}", factory=factory)
    create = None if existing is not None else lambda: create_measurement(out, plan, prov, fmu_parameters(info))
    _run_jobs(out, [Job(spec, options) for spec in todo], resource, len(plan), create, options, run, warn)
    mark_complete(out)
    return read_data_file(out)


def _plan(amplitudes: Sequence[float] | None, frequencies: Sequence[float] | None, existing: DataFile | None,
          factory: FmuRunnerFactory, options: MeasureOptions) -> tuple[Plan, str]:
    """:func:`measure`'s plan (amplitudes and frequencies given, else a resumed file's, else the defaults) and
    where its frequencies come from (given, the resumed file's source, or a 1-2-5 grid around the bandwidth
    estimated from a step response)."""
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
    return Plan(tuple(amplitudes), tuple(frequencies)), source


def _run_jobs(out: Path, jobs: list[Job], resource: WorkerResource, total: int, create: Callable[[], None] | None,
              options: MeasureOptions, run: RunOptions, warn: Callable[[str], None] | None) -> None:
    """:func:`measure`'s experiments ``jobs`` (of ``total`` in the plan) run on workers, each added to ``out`` as it
    ends.  ``create``, when given, makes the file once the workers are connected (a bad scheduler writes nothing);
    a run that stores no experiment then leaves no empty file.  An experiment without steady state is warned of."""
    done = total - len(jobs)
    running: dict[int, float] = {}  # experiment index -> fraction done

    def show(index: int | None = None, fraction: float = 0.0) -> None:
        if index is not None:
            running[index] = fraction
        run.report(int(PROGRESS_SCALE * (done + sum(running.values()))), PROGRESS_SCALE * total)

    with Workers(scheduler=run.scheduler, workers=run.workers, on_report=show) as pool:  # connects first
        if create is not None:
            create()
        try:
            show()
            for _, result in pool.imap(run_experiment, jobs, resource=resource):
                add_experiments(out, [result])
                done += 1
                running.pop(result.index, None)
                if not result.converged:
                    text = (f"experiment {result.index} (amplitude {result.amplitude:g}, frequency "
                            f"{result.frequency:g} Hz) reached no steady state within {options.max_time:g} s (last "
                            f"change per period {result.last_change:.2g}); it is stored with converged = false")
                    if warn is not None:
                        warn(text)
                    else:
                        warnings.warn(text, ServofmuWarning, stacklevel=4)  # (past measure and holds_outputs)
                show()
        except BaseException:
            if create is not None and done == 0:  # nothing measured: leave no empty file to trip over
                out.unlink(missing_ok=True)
            raise
