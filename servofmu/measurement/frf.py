"""Steady state, first harmonic, DC and distortion from samples.

Phasor convention (docs/measurement.md).  For a signal s on a window [t0, t0 + N·T] of N whole periods
T = 1/f of the excitation:

    S_k = j · (2/(N·T)) · ∫ s(t) · exp(−j·2π·k·f·t) dt      (k ≥ 1, absolute time t)
    DC  =     (1/(N·T)) · ∫ s(t) dt

so that s(t) ≈ DC + Σ_k |S_k| · sin(2π·k·f·t + arg S_k); the built-in excitation m·sin(2πft) has S_1 = m.
Distortion = sqrt(Σ_{k=2..K} |S_k|²) / |S_1| with K = ``HARMONICS`` (10) unless the sampling limits it.

The integrals are trapezoid sums over the samples.  On a uniform grid over whole periods of a periodic signal
the trapezoid sum is the DFT, whose only error is aliasing of harmonics near the sampling rate; for the servo
FMUs it falls as the cube of the sample spacing, to about 1e-9 relative at 8192 samples per period
(docs/bench-measure.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import MAX_MAGNITUDE, UserError

__all__ = ["Harmonics", "harmonics", "distortion", "trapezoid_weights", "window_samples", "period_phasor",
           "SteadyStateDetector", "estimate_frequency", "RecordSettling", "settle_noisy", "HARMONICS",
           "checked_samples"]

HARMONICS = 10  # highest harmonic kept for the distortion (S_2..S_10)
SEARCH_SAMPLES = 2 ** 17  # samples the frequency search of a record fits at most (estimate_frequency)


@dataclass(frozen=True)
class Harmonics:
    """DC and phasors S_1..S_K of one signal on a window of ``periods`` whole periods from ``start``."""

    frequency: float
    start: float
    periods: int
    dc: float
    phasors: np.ndarray  # complex, shape (K,): S_1..S_K

    @property
    def first(self) -> complex:
        """S_1, the first harmonic's phasor (the signal's unit)."""
        return complex(self.phasors[0])

    @property
    def distortion(self) -> float:
        """sqrt(Σ_{k≥2} |S_k|²) / |S_1| of these phasors (:func:`distortion`)."""
        return distortion(self.phasors)


def distortion(phasors: np.ndarray) -> float:
    """sqrt(Σ_{k≥2} |S_k|²) / |S_1| (nan when S_1 = 0)."""
    phasors = np.asarray(phasors)
    s1 = abs(phasors[0])
    rest = float(np.sqrt(np.sum(np.abs(phasors[1:]) ** 2)))
    return rest / s1 if s1 > 0 else math.nan


def checked_samples(t, s, frequency: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``t`` and ``s`` as float arrays of one length, the times finite and every value within ±MAX_MAGNITUDE
    (NaN values pass: they give NaN results, which the callers flag), and ``frequency`` (when given) positive and
    within it: the analysis's sums and period counts then stay finite (a time or value of 1e308 made a period
    count of inf or a sum of squares beyond the floats, an OverflowError).  A violation is a UserError."""
    t, s = np.asarray(t, dtype=float), np.asarray(s, dtype=float)
    if t.ndim != 1 or t.shape != s.shape or t.size < 2:
        raise UserError(f"the samples must be two vectors of one length, at least 2 (times {t.shape}, values "
                        f"{s.shape})")
    with np.errstate(invalid="ignore"):
        if not np.all(np.abs(t) <= MAX_MAGNITUDE):
            raise UserError(f"the samples' times hold NaN, Inf or a value beyond ±{MAX_MAGNITUDE:g}")
        if np.any(np.abs(s) > MAX_MAGNITUDE):
            raise UserError(f"the samples' values hold Inf or a value beyond ±{MAX_MAGNITUDE:g}")
    if frequency is not None and not 0 < frequency <= MAX_MAGNITUDE:
        raise UserError(f"frequency must be positive and at most {MAX_MAGNITUDE:g} Hz, not {frequency}")
    return t, s


def _whole_periods(t: np.ndarray, start: float, frequency: float) -> int:
    """Whole periods of ``frequency`` from ``start`` to t[-1]; more than one per sample is refused (each period
    is analysed from its samples)."""
    periods = int(math.floor((t[-1] - start) * frequency * (1 + 1e-12)))
    if periods > t.size:
        raise UserError(f"{periods} periods of {frequency:g} Hz in {t.size} samples: fewer than one sample per "
                        "period")
    return periods


def _unit_phase(frequency: float, k: int, t: np.ndarray, start: float) -> np.ndarray:
    """exp(−j2πkft) computed as exp(−j2πk·frac(f·start))·exp(−j2πkf(t − start)) to keep the phase exact
    for large t."""
    frac = math.fmod(frequency * start, 1.0)
    return np.exp(-2j * np.pi * k * (frac + frequency * (t - start)))


def trapezoid_weights(t: np.ndarray) -> np.ndarray:
    """Weights w with Σ w·s = trapezoid integral of samples s at times t."""
    dt = np.diff(t)
    w = np.zeros_like(t)
    w[:-1] += dt / 2
    w[1:] += dt / 2
    return w


def window_samples(t: np.ndarray, s: np.ndarray, start: float, stop: float) -> tuple[np.ndarray, np.ndarray]:
    """The samples in [start, stop], with linearly interpolated end points where they fall between samples."""
    span = max(abs(stop), 1.0)
    inside = (t > start + 1e-12 * span) & (t < stop - 1e-12 * span)
    tw = np.concatenate([[start], t[inside], [stop]])
    sw = np.concatenate([[np.interp(start, t, s)], s[inside], [np.interp(stop, t, s)]])
    return tw, sw


def harmonics(t, s, frequency: float, start: float | None = None, periods: int | None = None,
              n_harmonics: int = HARMONICS) -> Harmonics:
    """DC and S_1..S_K of samples ``s`` at times ``t`` over ``periods`` whole periods from ``start``.

    Default window: from t[0], as many whole periods as the samples cover.  Samples need not be uniform.
    """
    t, s = checked_samples(t, s, frequency)
    period = 1.0 / frequency
    if start is None:
        start = float(t[0])
    if not abs(start) <= MAX_MAGNITUDE:
        raise UserError(f"window start {start} is not a finite time")
    if periods is None:
        periods = _whole_periods(t, start, frequency)
    if periods < 1:
        raise UserError(f"the samples cover less than one period of {frequency:g} Hz")
    stop = start + periods * period
    span = max(abs(stop), 1.0)
    if start < t[0] - 1e-12 * span or stop > t[-1] + 1e-9 * span:
        raise UserError(f"window [{start:g}, {stop:g}] s is outside the samples [{t[0]:g}, {t[-1]:g}] s")
    tw, sw = window_samples(t, s, start, min(stop, t[-1]))
    tw[-1] = stop  # within rounding of t[-1]
    w = trapezoid_weights(tw)
    length = periods * period
    dc = float(np.dot(w, sw) / length)
    phasors = np.array([1j * 2.0 / length * np.dot(w * sw, _unit_phase(frequency, k, tw, start))
                        for k in range(1, n_harmonics + 1)])
    return Harmonics(frequency=frequency, start=start, periods=periods, dc=dc, phasors=phasors)


def period_phasor(t: np.ndarray, s: np.ndarray, frequency: float) -> tuple[complex, float]:
    """(S_1, DC) of the samples of one period (t[0] .. t[-1] = t[0] + T)."""
    if not (abs(t[0]) <= MAX_MAGNITUDE and abs(t[-1]) <= MAX_MAGNITUDE):  # (per period: the values unchecked)
        raise UserError(f"the period [{t[0]}, {t[-1]}] s is not a finite time")
    w = trapezoid_weights(t)
    length = t[-1] - t[0]
    return (complex(1j * 2.0 / length * np.dot(w * s, _unit_phase(frequency, 1, t, t[0]))),
            float(np.dot(w, s) / length))


@dataclass
class SteadyStateDetector:
    """Decides, period by period, when a response has reached its periodic steady state.

    After each period the first harmonic S_1 and the mean of that period are compared with those of the
    previous period; the change max(|ΔS_1|, |ΔDC|)/|S_1| must stay below ``threshold`` for ``consecutive``
    periods in a row.  ``remaining_error`` extrapolates the geometric decay of the last changes to estimate
    how far the last period still is from the true steady state.
    """

    frequency: float
    threshold: float = 1e-10
    consecutive: int = 2
    s1: list = field(default_factory=list)
    dc: list = field(default_factory=list)
    changes: list = field(default_factory=list)

    def add_period(self, t: np.ndarray, s: np.ndarray) -> bool:
        """Add the samples of one more period; True once the steady state is reached."""
        s1, dc = period_phasor(np.asarray(t, float), np.asarray(s, float), self.frequency)
        if self.s1:
            diff = max(abs(s1 - self.s1[-1]), abs(dc - self.dc[-1]))
            self.changes.append(diff / abs(s1) if abs(s1) > 0 else (0.0 if diff == 0 else math.inf))
        self.s1.append(s1)
        self.dc.append(dc)
        return self.converged

    @property
    def periods(self) -> int:
        """Periods seen so far."""
        return len(self.s1)

    @property
    def converged(self) -> bool:
        """Whether the last ``consecutive`` changes were all below ``threshold``."""
        last = self.changes[-self.consecutive:]
        return len(last) == self.consecutive and all(c < self.threshold for c in last)

    @property
    def last_change(self) -> float:
        """The relative change of the last period (inf before the second period)."""
        return self.changes[-1] if self.changes else math.inf

    @property
    def remaining_error(self) -> float:
        """Estimated relative distance of the last period's S_1 from the steady state: c·r/(1 − r) for the
        last change c and decay ratio r of the last three changes.  Once converged, changes that no longer
        decay are the solver's noise floor and the largest of them is the estimate; otherwise inf."""
        if len(self.changes) < 3:
            return math.inf
        c = np.asarray(self.changes[-3:])
        if np.all(c == 0):
            return 0.0
        r = float(np.max(c[1:] / np.maximum(c[:-1], 1e-300)))
        if r < 0.9:
            return float(c[-1] * r / (1 - r))
        return float(np.max(c)) if self.converged else math.inf


# ---------------------------------------------------------------------------
# Records: frequency of a sinusoidal excitation and settling of a noisy response
# ---------------------------------------------------------------------------
def estimate_frequency(t: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """(frequency, fraction of u's AC power in that one sinusoid) for samples of a (nearly) sinusoidal u.

    The frequency is that of the least-squares sine fit (sine, cosine and constant): an FFT peak refined by
    golden-section search.
    """
    t, u = checked_samples(t, u)
    u = u - np.mean(u)
    duration = t[-1] - t[0]
    dt = float(np.median(np.diff(t)))
    n = len(t)
    grid = np.linspace(t[0], t[-1], n)
    ug = np.interp(grid, t, u)
    # padded 8x for a fine peak on ordinary records; a long one (a 16 kHz log of minutes) has bins fine enough
    n_fft = 8 * n if n <= SEARCH_SAMPLES else n
    spectrum = np.abs(np.fft.rfft(ug, n_fft))
    freqs = np.fft.rfftfreq(n_fft, d=duration / (n - 1))
    spectrum[freqs < 1.0 / duration] = 0  # below one period over the record
    i = int(np.argmax(spectrum))
    # The search fits every sample of an ordinary record; a long record is thinned evenly to SEARCH_SAMPLES, kept
    # at eight samples a period or more (no aliasing): the fit's frequency then differs by far less than its
    # noise, and the search takes a fixed time however long the record.
    stride = max(1, min(n // SEARCH_SAMPLES, int(1.0 / (8 * dt * max(freqs[i], 1e-300)))))
    tt, u_search = t[::stride], u[::stride]
    w = trapezoid_weights(tt)

    def power(f):  # the part of u a sine of frequency f (any phase, plus a constant) explains
        basis = np.column_stack([np.sin(2 * np.pi * f * (tt - tt[0])), np.cos(2 * np.pi * f * (tt - tt[0])),
                                 np.ones_like(tt)])
        coef = np.linalg.lstsq(basis * np.sqrt(w)[:, None], u_search * np.sqrt(w), rcond=None)[0]
        return float(np.dot(w, (basis @ coef) ** 2))

    lo, hi = max(freqs[max(i - 1, 0)], 0.5 / duration), freqs[min(i + 1, len(freqs) - 1)]
    g = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    pc, pd = power(c), power(d)  # one new evaluation per step: the other point's is kept
    for _ in range(60):
        if pc > pd:
            b, d, pd = d, c, pc
            c = b - g * (b - a)
            pc = power(c)
        else:
            a, c, pc = c, d, pd
            d = a + g * (b - a)
            pd = power(d)
    f = (a + b) / 2
    if not 0 < f < 0.5 / dt:
        return f, 0.0
    periods = int(math.floor(duration * f))
    if periods < 1:
        return f, 0.0
    h = harmonics(t, u, f, periods=periods, n_harmonics=1)
    ac = float(np.var(window_samples(t, u, h.start, h.start + periods / f)[1]))
    return f, (abs(h.first) ** 2 / 2) / ac if ac > 0 else 0.0


@dataclass(frozen=True)
class RecordSettling:
    """Where a (noisy) periodic response has settled: periods from ``first_period`` on are steady."""

    first_period: int
    periods: int          # whole periods in the record
    converged: bool
    tolerance: float      # the band around the final first harmonic the settled periods stay in


def settle_noisy(t: np.ndarray, s: np.ndarray, frequency: float, start: float) -> RecordSettling:
    """First whole period from which the per-period first harmonic of ``s`` stays within a band around the
    mean of the last half of the record: the band is 4 standard deviations of the last half (noise) or
    1e-3 relative, whichever is larger.  Converged when at least half of the periods are steady."""
    t, s = checked_samples(t, s, frequency)
    period = 1.0 / frequency
    n = _whole_periods(t, start, frequency)
    values = []
    for p in range(n):
        tw, sw = window_samples(t, s, start + p * period, start + (p + 1) * period)
        values.append(period_phasor(tw, sw, frequency)[0])
    values = np.asarray(values)
    tail = values[n // 2:]
    ref = np.mean(tail)
    band = max(4 * float(np.std(np.abs(tail - ref))) if len(tail) > 1 else 0.0, 1e-3 * abs(ref))
    outside = np.nonzero(np.abs(values - ref) > band)[0]
    first = int(outside[-1]) + 1 if len(outside) else 0
    first = min(first, n - 1)
    return RecordSettling(first_period=first, periods=n, converged=(n - first) >= max(1, n // 2), tolerance=band)
