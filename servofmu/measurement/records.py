"""Import records measured on a machine (CSV or MAT) into a data file.

A record is a time column, the input force u and either the velocity or the position.  Position records
(encoder counts converted to metres, quantised) get a velocity estimate kept beside the raw signal:
a zero-phase 4th-order Butterworth low-pass (applied forward and backward) followed by a fourth-order
central difference — no phase lag, and an amplitude error below 1e-5 for frequencies up to a fifth of
the cut-off (docs/measurement.md).  Records whose input is a sinusoid get the first-harmonic analysis of
measured experiments (servofmu.measurement.frf).

A drive's log (:class:`LoopChannels`) adds the reference the controller followed and a known signal the drive
injected after its output limit, with the force constants that turn the logged command and signal into newtons:
a closed-loop record.  Time stamps are stored as logged; those of position records and drive logs must lie on a
regular grid (servofmu.measurement.clock), whose step and jitter are stored with the record.
"""
from __future__ import annotations

import math
from pathlib import Path
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import MAX_MAGNITUDE, UserError
from ..fileio import claim_output, file_sha256, output_mode
from ..model.signals import INTERSAMPLE
from ..runtime import RunOptions, utc_now
from ..version import __version__
from .clock import ClockFit, fit_clock
from .columns import MIN_SAMPLES, columns_from_arrays, read_columns
from .datafile import DataFile, Record, RecordAnalysis, Series, read_data_file, write_records
from .duplicates import TWICE, file_items, first_repeat, series_digest
from .frf import HARMONICS, estimate_frequency, harmonics, settle_noisy

__all__ = ["import_records", "load_record", "record_from_arrays", "read_columns", "velocity_from_position", "analyse_record",
           "LoopChannels", "KINDS", "other_tone", "periodic_note"]

KINDS = ("velocity", "position")
SINE_FRACTION = 0.8  # a record is sinusoidal when its input has at least this share of its AC power at one f
MIN_PERIODS = 2
# ...and no other tone (not a harmonic of f) holds this share: two tones are not one sine with a little noise
OTHER_TONE = 0.01
PERIODIC = 0.98  # the input repeats after N samples when its normalised autocorrelation at lag N is at least this


# ---------------------------------------------------------------------------
# Velocity from position
# ---------------------------------------------------------------------------
def velocity_from_position(t: np.ndarray, x: np.ndarray, cutoff: float) -> np.ndarray:
    """Zero-phase low-pass (4th-order Butterworth at ``cutoff`` Hz, forward and backward) of the position,
    then its derivative by the fourth-order central difference (second order at the two ends)."""
    from scipy.signal import butter, filtfilt

    dt = float(np.mean(np.diff(t)))
    fs = 1.0 / dt
    if not 0 < cutoff < fs / 2:
        raise UserError(f"cutoff must be between 0 and half the sample rate ({fs / 2:g} Hz), not {cutoff:g}")
    b, a = butter(4, cutoff, fs=fs)
    xf = filtfilt(b, a, x)
    v = np.gradient(xf, dt, edge_order=2)
    v[2:-2] = (-xf[4:] + 8 * xf[3:-1] - 8 * xf[1:-3] + xf[:-4]) / (12 * dt)
    return v


# ---------------------------------------------------------------------------
# Analysis of sinusoidal records
# ---------------------------------------------------------------------------
def analyse_record(t: np.ndarray, u: np.ndarray, v: np.ndarray, frequency: float | None = None
                   ) -> tuple[RecordAnalysis | None, str]:
    """The first-harmonic analysis when u is a sinusoid (or ``frequency`` is given), with a note why not: an input
    of several tones is never taken for one sine (:func:`other_tone`), a periodic multisine is named as such."""
    f_est, fraction = estimate_frequency(t, u)
    if frequency is None:
        if fraction < SINE_FRACTION:
            return None, (f"input is not a sinusoid ({fraction:.0%} of its AC power at {f_est:.4g} Hz"
                          f"{periodic_note(t, u)}); no first-harmonic analysis")
        tone = other_tone(t, u, f_est, fraction)
        if tone is not None:
            return None, (f"input is not one sinusoid: {fraction:.0%} of its AC power at {f_est:.4g} Hz and "
                          f"{tone[1]:.1%} at {tone[0]:.4g} Hz (not a harmonic); no first-harmonic analysis")
        frequency = f_est
    else:
        fraction = _fraction_at(t, u, frequency)
    fs = 1.0 / float(np.median(np.diff(t)))
    n_harm = max(1, min(HARMONICS, int(fs / 2 // frequency)))
    periods = int(math.floor((t[-1] - t[0]) * frequency * (1 + 1e-12)))
    if periods < MIN_PERIODS:
        return None, f"only {periods} whole periods of {frequency:.4g} Hz; no first-harmonic analysis"
    settle = settle_noisy(t, v, frequency, float(t[0]))
    start = float(t[0]) + settle.first_period / frequency
    n = settle.periods - settle.first_period
    hu = harmonics(t, u, frequency, start=start, periods=n, n_harmonics=1)
    hv = harmonics(t, v, frequency, start=start, periods=n, n_harmonics=n_harm)
    analysis = RecordAnalysis(frequency=frequency, sine_fraction=fraction, amplitude=abs(hu.first), U1=hu.first,
                              V1=hv.first, H=hv.first / hu.first if hu.first != 0 else complex(math.nan, math.nan),
                              dc_u=hu.dc, dc=hv.dc, harmonics=hv.phasors, distortion=hv.distortion,
                              converged=settle.converged, settling_time=start - float(t[0]), window_start=start,
                              window_periods=n)
    note = "" if settle.converged else "the response did not settle over the first half of the record"
    return analysis, note


def other_tone(t: np.ndarray, u: np.ndarray, frequency: float, fraction: float) -> tuple[float, float] | None:
    """(frequency, share of u's AC power) of the strongest tone of u besides the sine at ``frequency`` (which holds
    ``fraction``), when that share is at least OTHER_TONE and it is not a harmonic of ``frequency``; else None."""
    duration = float(t[-1] - t[0])
    basis = np.column_stack([np.sin(2 * np.pi * frequency * (t - t[0])), np.cos(2 * np.pi * frequency * (t - t[0])),
                             np.ones_like(t)])
    rest = u - basis @ np.linalg.lstsq(basis, u, rcond=None)[0]
    if not np.any(rest):
        return None
    f2, share = estimate_frequency(t, rest)
    share *= 1.0 - fraction
    k = max(1, round(f2 / frequency))
    if share < OTHER_TONE or abs(f2 - k * frequency) * duration < 2:
        return None
    return f2, share


def periodic_note(t: np.ndarray, u: np.ndarray) -> str:
    """", a periodic multisine of K lines, period P s (servofmu import --excitation)" when u repeats after some
    N samples (its last two periods correlated ≥ PERIODIC; uniform samples) with its power on K ≥ 2 lines of
    that period; "" else."""
    n = u.size
    if n < 64 or np.ptp(np.diff(t)) > 1e-6 * float(np.median(np.diff(t))):
        return ""
    x = u - np.mean(u)
    spectrum = np.fft.rfft(x, 2 * n)
    r = np.fft.irfft(np.abs(spectrum) ** 2)[:n // 2]
    if r[0] <= 0:
        return ""
    r = r / (r[0] * (n - np.arange(n // 2)) / n)  # unbiased, normalised
    # candidates: the autocorrelation's peaks (realisations of other phases lower them), checked on the last two
    # periods, which must repeat
    peaks = np.flatnonzero((r[9:-1] >= 0.3) & (r[9:-1] >= r[8:-2]) & (r[9:-1] >= r[10:])) + 9
    period = next((int(k) for k in peaks[:20]
                   if np.corrcoef(x[-k:], x[-2 * k:-k])[0, 1] >= PERIODIC), None)
    if period is None:
        return ""
    one = np.abs(np.fft.rfft(x[-period:])) ** 2
    lines = int(np.sum(one > 1e-3 * one.max()))
    if lines < 2:
        return ""
    dt = float(np.median(np.diff(t)))
    return (f"; a periodic multisine of {lines} lines, period {period * dt:.6g} s: import it with --excitation "
            "SIGNAL.csv for its BLA")


def _fraction_at(t, u, frequency) -> float:
    periods = int(math.floor((t[-1] - t[0]) * frequency * (1 + 1e-12)))
    if periods < 1:
        return 0.0
    h = harmonics(t, u, frequency, periods=periods, n_harmonics=1)
    mask = t <= t[0] + periods / frequency
    ac = float(np.var(u[mask]))
    return (abs(h.first) ** 2 / 2) / ac if ac > 0 else 0.0


# ---------------------------------------------------------------------------
# Import
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class LoopChannels:
    """The closed-loop channels of a drive's log and the factors that make forces of its columns.

    ``reference``: the column of the reference position (m) the drive's controller followed; ``disturbance``: the
    column of a known signal the drive adds to its controller's output after the output limit (an injected test
    signal: force pulses, a noise burst), so that the input column is the total command; ``input_scale`` and
    ``disturbance_scale``: N per unit of those columns (a force constant in N/V or N/A; 1 when they are forces).
    """

    reference: str | None = None
    disturbance: str | None = None
    input_scale: float = 1.0
    disturbance_scale: float = 1.0

    def check(self) -> None:
        """A UserError naming the option whose value cannot be used."""
        for option, value in (("--input-scale", self.input_scale), ("--disturbance-scale", self.disturbance_scale)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value != 0):
                raise UserError(f"{option} must be a finite number other than 0 (N per unit of the column), "
                                f"not {value}")
        if self.disturbance_scale != 1.0 and self.disturbance is None:
            raise UserError("--disturbance-scale needs --disturbance COLUMN")


def _clock(path, t: np.ndarray, required: bool) -> ClockFit | None:
    """The stamps' grid; a UserError naming the first bad stamp when the record needs a regular clock (position
    records and closed-loop logs), else None when there is none."""
    try:
        return fit_clock(t, where=lambda i: f"{path}: sample {i + 1} (t = {t[i]:.9g} s)")
    except UserError:
        if required:
            raise
        return None


# A step of a position record between two samples this many times its 99th-percentile step, and a tenth of its
# whole travel or more, is no motion but an encoder counter's overflow (or a reset)
WRAP_RATIO = 50.0


def check_wrap(path, t: np.ndarray, x: np.ndarray, column: str) -> None:
    """Refuse a position record that jumps between two samples by far more than it ever moves in one (an encoder
    counter that wrapped: every simulation of the axis would have to follow the jump)."""
    step = np.abs(np.diff(x))
    travel = float(np.ptp(x))
    if step.size < 2 or travel == 0:
        return
    jumps = np.flatnonzero((step > WRAP_RATIO * np.percentile(step, 99)) & (step >= 0.1 * travel))
    if jumps.size:
        i = int(jumps[0])
        raise UserError(f"{path}: column {column!r} jumps by {x[i + 1] - x[i]:+.6g} m from sample {i + 1} to {i + 2} "
                        f"(t = {t[i + 1]:.9g} s), {step[i] / np.percentile(step, 99):.3g} times its usual step "
                        f"({jumps.size} such jumps): an encoder counter's overflow? unwrap the position first")


def _scaled(path, values: np.ndarray, column: str, scale: float, option: str) -> np.ndarray:
    """``values * scale``, refused when a product leaves what servofmu's files hold (±MAX_MAGNITUDE)."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = values * scale
    bad = np.flatnonzero(~(np.abs(out) <= MAX_MAGNITUDE))
    if bad.size:
        i = int(bad[0])
        raise UserError(f"{path}: sample {i + 1}: column {column!r} ({values[i]:g}) times {option} {scale:g} is "
                        f"{out[i]:g}, beyond ±{MAX_MAGNITUDE:g}, which servofmu does not read")
    return out


def load_record(path: str | Path, time: str, input: str, output: str, kind: str = "velocity",
                cutoff: float | None = None, frequency: float | None = None, index: int = 0,
                intersample: str = "zoh", loop: LoopChannels | None = None) -> Record:
    """One record from a CSV or MAT file (columns/variables named ``time``, ``input``, ``output``, and those of
    ``loop``: the reference and the injected disturbance of a drive's log, and the scales of the forces)."""
    path, loop = Path(path), loop or LoopChannels()
    _check_options(kind, intersample, frequency)
    loop.check()
    names = [time, input, output] + [c for c in (loop.reference, loop.disturbance) if c is not None]
    if len(set(names)) < len(names):
        raise UserError("the time, input and output columns must be three different columns" if len(names) == 3
                        else "the time, input, output, reference and disturbance columns must be different columns")
    options = ["--time", "--input", "--output-variable"] + [o for c, o in ((loop.reference, "--reference"), (
        loop.disturbance, "--disturbance")) if c is not None]
    cols = read_columns(path, names, options)
    columns = {"time": time, "u": input, "position" if kind == "position" else "v": output}
    columns.update({role: name for role, name in (("reference", loop.reference), ("disturbance", loop.disturbance))
                    if name is not None})
    return _record(str(path), path.stem, path.name, file_sha256(path), columns, cols, kind, cutoff, frequency,
                   index, intersample, loop)


def record_from_arrays(name: str, time, input, output, kind: str = "velocity", reference=None, disturbance=None,
                       cutoff: float | None = None, frequency: float | None = None, index: int = 0,
                       intersample: str = "zoh", input_scale: float = 1.0, disturbance_scale: float = 1.0) -> Record:
    """One record from arrays in memory, made and checked exactly as :func:`load_record` makes one from a file's
    columns (``name`` stands for the file in the record and in the messages; its source digest is that of the
    samples)."""
    _check_options(kind, intersample, frequency)
    loop = LoopChannels(reference=None if reference is None else "reference",
                        disturbance=None if disturbance is None else "disturbance",
                        input_scale=input_scale, disturbance_scale=disturbance_scale)
    loop.check()
    arrays = {"time": time, "input": input, "output": output}
    arrays.update({k: v for k, v in (("reference", reference), ("disturbance", disturbance)) if v is not None})
    cols = columns_from_arrays(name, arrays)
    _check_time_column(name, cols["time"])
    digest = series_digest(Series(time=cols["time"], u=cols["input"], v=cols["output"]))
    columns = {"time": "time", "u": "input", "position" if kind == "position" else "v": "output"}
    columns.update({role: role for role in ("reference", "disturbance") if role in cols})
    return _record(name, name, "memory", digest, columns, cols, kind, cutoff, frequency, index, intersample,
                   loop, time="time", input="input", output="output")


def _check_options(kind: str, intersample: str, frequency: float | None) -> None:
    if kind not in KINDS:
        raise UserError(f"kind must be velocity or position, not {kind!r}")
    if intersample not in INTERSAMPLE:
        raise UserError(f"intersample must be one of {', '.join(INTERSAMPLE)}, not {intersample!r}")
    if frequency is not None and not (math.isfinite(frequency) and frequency > 0):
        raise UserError(f"frequency must be positive, not {frequency:g}")


def _check_time_column(where: str, t: np.ndarray) -> None:
    """A time column as a file's must be: at least MIN_SAMPLES samples, strictly increasing."""
    if len(t) < MIN_SAMPLES:
        raise UserError(f"{where}: needs at least {MIN_SAMPLES} samples, has {len(t)}")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise UserError(f"{where}: sample {i + 1}: time is not strictly increasing ({t[i]!r} s after {t[i - 1]!r} s)")


def _record(where: str, name: str, source: str, sha256: str, columns: dict, cols: dict, kind: str, cutoff,
            frequency, index: int, intersample: str, loop: LoopChannels, time: str | None = None,
            input: str | None = None, output: str | None = None) -> Record:
    """The record of checked columns ``cols`` (named as ``columns`` says: role -> column)."""
    time, input = time or columns["time"], input or columns["u"]
    output = output or columns.get("position", columns.get("v"))
    t, u, y = cols[time], _scaled(where, cols[input], input, loop.input_scale, "--input-scale"), cols[output]
    clock = _clock(where, t, required=kind == "position" or loop.reference is not None)
    fs = 1.0 / float(np.median(np.diff(t)))
    position = None
    if kind == "position":
        check_wrap(where, t, y, output)
        cutoff = fs / 10 if cutoff is None else cutoff
        position, v = y, velocity_from_position(t, y, cutoff)
        how = (f"zero-phase 4th-order Butterworth low-pass at {cutoff:g} Hz (forward-backward) of position, "
               "then 4th-order central difference")
    else:
        if cutoff is not None:
            raise UserError("a velocity cutoff applies to position records only")
        v, how = y, "measured"
    analysis, note = analyse_record(t, u, v, frequency)
    disturbance = None if loop.disturbance is None else _scaled(where, cols[loop.disturbance], loop.disturbance,
                                                                 loop.disturbance_scale, "--disturbance-scale")
    series = Series(time=t, u=u, v=v, position=position,
                    reference=None if loop.reference is None else cols[loop.reference], disturbance=disturbance)
    return Record(index=index, name=name, source=source, source_sha256=sha256, kind=kind,
                  columns=columns, series=series, sample_rate=fs, velocity_estimate=how,
                  velocity_cutoff=cutoff if kind == "position" else None, analysis=analysis, note=note,
                  intersample=intersample, time_step=clock and clock.step, time_jitter=clock and clock.jitter_rms,
                  time_jitter_max=clock and clock.jitter_max,
                  input_scale=None if loop.input_scale == 1.0 else float(loop.input_scale),
                  disturbance_scale=None if disturbance is None else float(loop.disturbance_scale))


def import_records(paths: Sequence[str | Path], output: str | Path, time: str, input: str, output_column: str,
                   kind: str = "velocity", cutoff: float | None = None, frequency: float | None = None,
                   append: bool = False, intersample: str = "zoh", run: RunOptions | None = None,
                   loop: LoopChannels | None = None) -> DataFile:
    """Import records measured on a machine (CSV or MAT files, one record each) into a data file.

    Parameters
    ----------
    paths : sequence of str or Path
        The record files.
    output : str or Path
        The data file (HDF5) to write.
    time, input, output_column : str
        Names of the time (s), input force (N, or the unit ``loop.input_scale`` converts) and velocity (m/s) or
        position (m) columns.
    kind : {"velocity", "position"}
        What the output column is; a position gets a zero-phase velocity estimate beside it.
    cutoff : float, optional
        Low-pass cut-off (Hz) of that velocity estimate; default a tenth of the sample rate.
    frequency : float, optional
        The excitation frequency of sinusoidal records, when it is not to be detected.
    append : bool
        Add the records to an existing records file.
    intersample : {"zoh", "foh"}
        How the input behaves between samples: held (a digital drive's command; the default) or linear.  Every
        replay of the record (identify, validate) applies it.
    run : RunOptions, optional
        ``overwrite``: replace an existing ``output``; ``command``: the command line, for provenance;
        ``progress``: called with the files read.
    loop : LoopChannels, optional
        A drive's log: its reference and injected-disturbance columns and the force constants of the command and
        the disturbance; records with a reference are closed-loop records (``identify --closed-loop``).

    Returns
    -------
    DataFile
        The data file read back.

    Raises
    ------
    UserError
        For unreadable files, missing columns, NaN or non-increasing time, time stamps of a position record or a
        drive's log off a regular grid (servofmu.measurement.clock), a scale that is not a finite non-zero
        number, an existing output (without ``append`` or ``run.overwrite``), an output that is one of ``paths``, a
        record whose samples are those of another record given or already in the output (one measurement twice).
    """
    from ..api_checks import check_arguments

    check_arguments(import_records, locals())  # a wrong type: UserError naming it
    run, loop = run or RunOptions(), loop or LoopChannels()
    loop.check()
    output = claim_output(output, output_mode(run.overwrite, append), inputs=paths, can_continue="append")
    existing = file_items(read_data_file(output), f"{output} (--append)") if append and output.exists() else []
    records = []
    for i, p in enumerate(paths):  # progress: files read
        run.report(i, len(paths))
        records.append(load_record(p, time, input, output_column, kind, cutoff, frequency, index=len(existing) + i,
                                   intersample=intersample, loop=loop))
    run.report(len(paths), len(paths))
    repeat = first_repeat(existing + [(f"{p}", series_digest(r.series)) for p, r in zip(paths, records)],
                          start=len(existing))
    if repeat is not None:
        raise UserError(f"{repeat[0]}: holds the same samples as {repeat[1]}: {TWICE}; import each record once")
    provenance = {"package": "servofmu", "package_version": __version__, "command": run.command,
                  "created": utc_now(), "sources": [r.source for r in records]}
    write_records(output, records, provenance, append=append, overwrite=run.overwrite)
    return read_data_file(output)
