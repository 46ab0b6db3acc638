"""Periodic broadband excitations (docs/broadband.md): random-phase multisines, periodic chirps and PRBS.

A :class:`BroadbandPlan` describes one experiment: for every RMS level (N) and every realisation, the periodic
signal is played for ``transient_periods`` periods (discarded: the plant reaches its periodic steady state) and
then ``periods`` periods (analysed).  One period holds ``samples`` = period·rate samples, so the frequency
resolution is 1/period and line k of the DFT of one period lies at k/period Hz.

Level l, realisation r is ``levels[l]`` times the normalised realisation r (RMS 1): the levels differ only by
their scale, so that what changes between them is the plant's response to the level, not the signal.

* ``multisine``: equal amplitudes at the excited lines of the band, random phases per realisation (uniform on
  [0, 2π) from a numpy Generator seeded with (seed, realisation)), then ``crest_iterations`` rounds of clipping
  (Van der Ouderaa et al. 1988: the time signal clipped at ``CLIP_FRACTION`` of its peak, back to the frequency
  domain, the phases kept and the amplitudes reset) to lower the crest factor; the amplitude spectrum stays
  exactly flat and the excited lines exactly those of the grid.
* grids: ``full`` (every line in the band), ``odd`` (odd lines), ``odd-random`` (odd lines, one of each group of
  ``group`` consecutive odd lines left out at random: a detection line for odd distortions; the even lines detect
  even ones).
* ``chirp``: a linear sweep over the band, periodic with a continuous phase (its end frequency moved by at most
  one line so that the phase closes), realisations = random circular shifts.
* ``prbs``: a maximum-length binary sequence (scipy.signal.max_len_seq) of 2^n − 1 bits, each held for
  ``rate``/clock samples, the clock 2.5·f_max (−3.3 dB at f_max), n the smallest with a resolution ≤ f_min;
  its period follows from the band and the rate; realisations = random circular shifts.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

from ..display import Shown, figure, options_shown, shown_html, shown_repr
from ..errors import UserError, check_int

__all__ = ["BroadbandPlan", "KINDS", "GRIDS", "crest_factor", "CLIP_FRACTION", "DEFAULT_CREST_ITERATIONS",
           "PRBS_CLOCK_FACTOR"]

KINDS = ("multisine", "chirp", "prbs")
GRIDS = ("full", "odd", "odd-random")
CLIP_FRACTION = 0.8           # clipping level of one iteration, relative to the peak
DEFAULT_CREST_ITERATIONS = 100
PRBS_CLOCK_FACTOR = 2.5       # PRBS clock / f_max: the spectrum is 3.3 dB down at f_max
MAX_SAMPLES = 50_000_000      # of the whole plan: beyond this the plan is a mistake (about 400 MB per signal)


def crest_factor(x: np.ndarray) -> float:
    """max|x| / RMS(x) of a signal (√2 for a sine)."""
    x = np.asarray(x, float)
    return float(np.max(np.abs(x)) / np.sqrt(np.mean(x ** 2)))


def _positive(option: str, value) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise UserError(f"{option}: must be a positive number, not {value!r}")
    return float(value)


@dataclass(frozen=True)
class BroadbandPlan:
    """One broadband experiment (see the module's docstring); ``option`` names in errors are the CLI's.

    Parameters
    ----------
    kind : str
        ``multisine``, ``chirp`` or ``prbs``.
    levels : tuple of float
        RMS levels of the force (N), each > 0.
    band : (float, float)
        [f_min, f_max] (Hz), 0 < f_min < f_max < rate/2.
    rate : float
        Sample rate (Hz); the signal is held between samples (zero-order hold).
    period : float or None
        Period (s), a whole number of samples; default 1/f_min (multisine, chirp), from the band (PRBS, which
        refuses another value).
    periods, transient_periods, realisations : int
        Analysed periods P ≥ 1 (≥ 2 for a noise estimate), leading periods T ≥ 0, realisations M ≥ 1.
    grid, group : str, int
        Multisine harmonic grid (``full``, ``odd``, ``odd-random``) and the odd-random group size (≥ 2).
    seed : int
        Seed of the phases, the detection lines and the shifts.
    crest_iterations : int
        Clipping iterations of the multisine (0: plain random phases).
    """

    kind: str
    levels: tuple
    band: tuple
    rate: float
    period: float | None = None
    periods: int = 2
    transient_periods: int = 1
    realisations: int = 4
    grid: str = "odd-random"
    group: int = 4
    seed: int = 0
    crest_iterations: int = DEFAULT_CREST_ITERATIONS

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        figures = (figure("levels", ", ".join(f"{x:.4g}" for x in self.levels), "N"),
                   figure("band", f"{self.band[0]:.4g}–{self.band[1]:.4g}", "Hz"), figure("rate", self.rate, "Hz"),
                   figure("period", self.samples / self.rate, "s"), figure("periods", self.periods),
                   figure("transient periods", self.transient_periods), figure("realisations", self.realisations))
        head = f"{self.kind}, {len(self.levels)} level{'s' * (len(self.levels) != 1)} (RMS force)"
        return Shown(type(self).__name__, head, figures, figures + options_shown(self).figures[4:])

    def __post_init__(self):
        if self.kind not in KINDS:
            raise UserError(f"excitation: must be one of {', '.join(KINDS)}, not {self.kind!r}")
        levels = tuple(_positive("--levels", v) for v in (self.levels or ()))
        if not levels:
            raise UserError("--levels: give at least one RMS level (N)")
        rate = _positive("--rate", self.rate)
        if len(self.band) != 2:
            raise UserError(f"--band: give f_min,f_max in Hz, not {len(self.band)} numbers")
        f_min, f_max = (_positive("--band", v) for v in self.band)
        if f_min >= f_max:
            raise UserError(f"--band: f_min {f_min:g} Hz must be below f_max {f_max:g} Hz")
        if f_max >= rate / 2:
            raise UserError(f"--band: f_max {f_max:g} Hz is not below the Nyquist frequency {rate / 2:g} Hz of "
                            f"--rate {rate:g}")
        if self.grid not in GRIDS:
            raise UserError(f"--grid: must be one of {', '.join(GRIDS)}, not {self.grid!r}")
        check_int("--periods", self.periods, 1)
        check_int("--transient-periods", self.transient_periods, 0)
        check_int("--realisations", self.realisations, 1)
        check_int("--group", self.group, 2)
        check_int("--seed", self.seed, 0)
        check_int("--crest-iterations", self.crest_iterations, 0, 10_000)
        for name, value in (("levels", levels), ("band", (f_min, f_max)), ("rate", rate)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "period", self._checked_period())
        if not self.lines.size:
            raise UserError(f"--band: no line of the {self.grid if self.kind == 'multisine' else 'full'} grid "
                            f"(resolution {1 / self.period:g} Hz) lies in [{f_min:g}, {f_max:g}] Hz")
        total = len(levels) * self.realisations * (self.periods + self.transient_periods) * self.samples
        if total > MAX_SAMPLES:
            raise UserError(f"--periods: the plan has {total:.3g} samples, more than {MAX_SAMPLES:.3g} (fewer "
                            "levels, realisations, periods or a lower --rate)")

    def _checked_period(self) -> float:
        if self.kind == "prbs":
            n = self._prbs_bits()
            period = (2 ** n - 1) * self._prbs_hold() / self.rate
            if self.period is not None and not math.isclose(self.period, period, rel_tol=1e-9):
                raise UserError(f"--period: a PRBS's period follows from --band and --rate ({period:.9g} s here); "
                                "leave --period out")
            return period
        period = 1.0 / self.band[0] if self.period is None else _positive("--period", self.period)
        n = period * self.rate
        if self.period is None:
            return round(n) / self.rate
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 4:
            raise UserError(f"--period: {period:g} s is not a whole number (>= 4) of samples at --rate "
                            f"{self.rate:g} Hz ({n:.6g})")
        return round(n) / self.rate

    def _prbs_hold(self) -> int:
        return max(1, int(self.rate // (PRBS_CLOCK_FACTOR * self.band[1])))

    def _prbs_bits(self) -> int:
        clock = self.rate / self._prbs_hold()
        return max(2, math.ceil(math.log2(clock / self.band[0] + 1)))

    # -- the grid ----------------------------------------------------------------------------------------------
    @property
    def samples(self) -> int:
        """Samples per period."""
        return int(round(self.period * self.rate))

    @property
    def resolution(self) -> float:
        """Frequency resolution 1/period (Hz)."""
        return 1.0 / self.period

    def _band_lines(self) -> np.ndarray:
        lo = max(1, math.ceil(self.band[0] * self.period - 1e-9))
        hi = min(math.floor(self.band[1] * self.period + 1e-9), (self.samples - 1) // 2)
        return np.arange(lo, hi + 1)

    @property
    def lines(self) -> np.ndarray:
        """The excited lines k (DFT bins of one period; at k/period Hz)."""
        k = self._band_lines()
        if self.kind != "multisine" or self.grid == "full":
            return k
        odd = k[k % 2 == 1]
        if self.grid == "odd":
            return odd
        return np.setdiff1d(odd, self.detection_lines)

    @property
    def detection_lines(self) -> np.ndarray:
        """The odd lines of the band left out (odd-random grid; empty otherwise): one per group of ``group``
        consecutive odd lines, chosen with the seed."""
        k = self._band_lines()
        odd = k[k % 2 == 1]
        if self.kind != "multisine" or self.grid != "odd-random" or odd.size < self.group:
            return np.zeros(0, dtype=int)
        rng = np.random.default_rng([self.seed, 0xDE7EC7])
        groups = odd.size // self.group
        picks = rng.integers(0, self.group, size=groups) + self.group * np.arange(groups)
        return odd[picks]

    @property
    def free_lines(self) -> np.ndarray:
        """The lines of the band left without excitation (even lines and detection lines of an odd grid): where
        the output shows nonlinear distortions and noise only."""
        return np.setdiff1d(self._band_lines(), self.lines)

    @property
    def frequencies(self) -> np.ndarray:
        """The excited frequencies (Hz)."""
        return self.lines / self.period

    # -- the signals -------------------------------------------------------------------------------------------
    def realisation(self, r: int) -> np.ndarray:
        """One period of realisation ``r`` with RMS 1 (``samples`` values, sample i at time i/rate)."""
        check_int("realisation", r, 0, self.realisations - 1)
        rng = np.random.default_rng([self.seed, r])
        if self.kind == "multisine":
            x = _multisine(self.samples, self.lines, rng, self.crest_iterations)
        elif self.kind == "chirp":
            x = np.roll(_chirp(self.samples, self._band_lines()), int(rng.integers(self.samples)) if r else 0)
        else:
            x = np.roll(_prbs(self._prbs_bits(), self._prbs_hold()), int(rng.integers(self.samples)) if r else 0)
        return x / np.sqrt(np.mean(x ** 2))

    def signal(self, level: int, r: int) -> np.ndarray:
        """The whole input of level index ``level`` and realisation ``r`` (N): transient and analysed periods."""
        return self.levels[level] * np.tile(self.realisation(r), self.transient_periods + self.periods)

    def signals(self) -> np.ndarray:
        """Every input, shape (levels, realisations, (T + P)·samples), in N."""
        base = np.stack([np.tile(self.realisation(r), self.transient_periods + self.periods)
                         for r in range(self.realisations)])
        return np.asarray(self.levels)[:, None, None] * base[None]

    def describe(self) -> dict:
        """The plan as JSON-ready values (what a signal file and a data file store; :meth:`from_description`)."""
        out = asdict(self)
        out.update(levels=list(self.levels), band=list(self.band), samples=self.samples,
                   lines=self.lines.tolist(), detection_lines=self.detection_lines.tolist())
        return out

    @classmethod
    def from_description(cls, doc: dict) -> "BroadbandPlan":
        """The plan a description was made of; refuses one whose lines do not come out the same."""
        names = ("kind", "levels", "band", "rate", "period", "periods", "transient_periods", "realisations",
                 "grid", "group", "seed", "crest_iterations")
        try:
            plan = cls(**{n: doc[n] for n in names if n in doc})
        except TypeError as exc:
            raise UserError(f"excitation description: {exc}") from None
        if "lines" in doc and list(doc["lines"]) != plan.lines.tolist():
            raise UserError("excitation description: its lines are not those of its plan (edited or foreign)")
        return plan

    def to_json(self) -> str:
        """:meth:`describe` as one line of JSON."""
        return json.dumps(self.describe(), separators=(",", ":"))


def _multisine(n: int, lines: np.ndarray, rng: np.random.Generator, iterations: int) -> np.ndarray:
    """Equal amplitudes at ``lines``, random phases, then clipping iterations (module docstring)."""
    spectrum = np.zeros(n // 2 + 1, complex)
    spectrum[lines] = np.exp(2j * np.pi * rng.random(lines.size))
    x = np.fft.irfft(spectrum, n)
    best, best_crest = x, crest_factor(x)
    for _ in range(iterations):
        peak = CLIP_FRACTION * np.max(np.abs(x))
        phases = np.angle(np.fft.rfft(np.clip(x, -peak, peak))[lines])
        spectrum[lines] = np.exp(1j * phases)
        x = np.fft.irfft(spectrum, n)
        crest = crest_factor(x)
        if crest < best_crest:  # clipping is not monotone: keep the best
            best, best_crest = x, crest
    return best


def _chirp(n: int, band_lines: np.ndarray) -> np.ndarray:
    """A linear sweep from line k0 to k1 over one period, k0 + k1 even so that the phase closes."""
    k0, k1 = int(band_lines[0]), int(band_lines[-1])
    if (k0 + k1) % 2:
        k1 = k1 - 1 if k1 - 1 > k0 else k1 + 1
    s = np.arange(n) / n  # time in periods
    return np.sin(2 * np.pi * (k0 * s + 0.5 * (k1 - k0) * s ** 2))


def _prbs(bits: int, hold: int) -> np.ndarray:
    """One period of a maximum-length sequence of ``bits`` bits (±1), each value held ``hold`` samples."""
    from scipy.signal import max_len_seq

    seq = max_len_seq(bits)[0].astype(float) * 2 - 1
    return np.repeat(seq, hold)
