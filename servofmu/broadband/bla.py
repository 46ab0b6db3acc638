"""The best linear approximation (BLA) of periodic records, its noise and nonlinear-distortion variances (the robust
method of Pintelon & Schoukens, System Identification, 2nd ed., ch. 3-4), and the H1 estimate of any record.

Periodic data: M realisations × P periods × N samples per period of the input u and output y, in steady state.
With U_mp(k), Y_mp(k) the DFT of period p of realisation m at line k (scaled as amplitudes, 2/N):

* per realisation: Ū_m, Ȳ_m the means over the periods, G_m = Ȳ_m / Ū_m;
* noise (period to period): σ²_Y,m = Σ_p |Y_mp − Ȳ_m|² / (P − 1), likewise σ²_U,m and the covariance σ²_YU,m;
  the noise variance of G_m is (σ²_Y,m − 2 Re(G_m* σ²_YU,m) + |G_m|² σ²_U,m) / (P |Ū_m|²);
* G_BLA = Σ_m G_m / M; its total variance σ²_BLA = Σ_m |G_m − G_BLA|² / (M (M − 1)) (noise and stochastic
  nonlinear distortions, realisation to realisation); its noise variance σ²_BLA,n = Σ_m σ²_G,m,n / M²; its
  distortion variance σ²_BLA,s = σ²_BLA − σ²_BLA,n (that of one realisation's G_m is M times larger);
* coherence over all M·P blocks: |Σ Y U*|² / (Σ |U|² Σ |Y|²) per line;
* at the lines of the band that are not excited (even and odd detection lines): the output's level
  sqrt(mean_m |Ȳ_m|²) and its noise level sqrt(mean_m σ²_Y,m / P) — even and odd nonlinear distortions.

P = 1 leaves the noise unknown (NaN) and M = 1 the total variance; the estimate itself is still exact.

The framework holds for a response periodic in the excitation's period.  A plant that oscillates on its own (a
friction limit cycle), a transient not yet decayed or a disturbance puts output power between the period's lines
of the whole record's DFT, where a periodic response has only noise; the strongest such component is reported
(nonsynchronous_components): there the period-to-period "noise" variance holds it, not the sensor's noise.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError

__all__ = ["BLA", "H1Estimate", "estimate_bla", "split_periods", "h1_estimate", "ClosedLoopEstimate",
           "closed_loop_estimate", "nonsynchronous_components"]


@dataclass(frozen=True)
class BLA:
    """The BLA at the excited lines and the levels at the detection lines (module docstring: the formulas).

    Arrays over the excited lines: ``frequencies`` (Hz), ``G`` (complex, output unit per input unit),
    ``var_noise``, ``var_distortion``, ``var_total`` (variances of G, not of one realisation; the distortion's
    may come out slightly negative where it is below the noise: an estimate), ``coherence``, ``U`` (the input's
    mean amplitude, |Ū| averaged over the realisations).  Over the detection lines: ``detection_frequencies``,
    ``detection_level`` and ``detection_noise`` (output amplitude and its noise level, output unit).  The strongest
    output component between the period's lines where one stands out (nonsynchronous_components; NaN where none
    does or P = 1): ``nonsynchronous_frequency`` (Hz), its power ``nonsynchronous_re_response_db`` relative to the
    output's at the excited lines and ``nonsynchronous_over_floor_db`` over the noise floor around it.
    """

    frequencies: np.ndarray
    G: np.ndarray
    var_noise: np.ndarray
    var_distortion: np.ndarray
    var_total: np.ndarray
    coherence: np.ndarray
    U: np.ndarray
    detection_frequencies: np.ndarray
    detection_level: np.ndarray
    detection_noise: np.ndarray
    detection_lines: np.ndarray
    periods: int
    realisations: int
    nonsynchronous_frequency: float = math.nan
    nonsynchronous_re_response_db: float = math.nan
    nonsynchronous_over_floor_db: float = math.nan

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        figures = _band_figures(self.frequencies, self.G, self.coherence) + (
            figure("distortion/noise", self.distortion_to_noise_db, "dB", ".3g"),
            figure("relative distortion", self.relative_distortion_db, "dB", ".3g"),
            figure("even detection/noise", self.detection_to_noise_db("even"), "dB", ".3g"),
            figure("odd detection/noise", self.detection_to_noise_db("odd"), "dB", ".3g"))
        return Shown(type(self).__name__, f"at {self.frequencies.size} lines, {self.realisations} realisations × "
                     f"{self.periods} periods", figures)

    @property
    def periodic(self) -> bool:
        """False where a component between the period's lines stands out: the response is not periodic in the
        excitation's period (a limit cycle, an unfinished transient, a disturbance), and the noise level holds it."""
        return not math.isfinite(self.nonsynchronous_frequency)

    @property
    def std_noise(self) -> np.ndarray:
        """Standard deviation of G_BLA from the noise."""
        return np.sqrt(self.var_noise)

    @property
    def std_distortion(self) -> np.ndarray:
        """Standard deviation of G_BLA from the stochastic nonlinear distortions (negative estimates as 0)."""
        return np.sqrt(np.clip(self.var_distortion, 0.0, None))

    @property
    def std_total(self) -> np.ndarray:
        """Standard deviation of G_BLA, noise and distortions together."""
        return np.sqrt(self.var_total)

    def band_factor(self, level: float = 0.95) -> float:
        """k of the band G_BLA ± k·σ_total that holds the true BLA with probability ``level``.

        σ_total is estimated from the M realisations, so the error over it is not normal: |Ĝ − G|²/σ̂² follows
        F(2, 2(M − 1)) (a complex error, two real degrees of freedom, over a variance of 2(M − 1)), and
        k = √F⁻¹(level; 2, 2(M − 1)): 2.27 at M = 4 for 95 %, where ±2σ holds 92.1 %.  One realisation has only
        the noise variance, from its P periods: k from F(2, 2(P − 1))."""
        from scipy.stats import f

        dof = 2 * (self.realisations - 1) if self.realisations > 1 else 2 * (self.periods - 1)
        return float(np.sqrt(f.ppf(level, 2, dof))) if dof > 0 else math.nan

    @property
    def std_band(self) -> np.ndarray:
        """σ of the band: the total standard deviation, or the noise's where one realisation gives no total."""
        return self.std_total if self.realisations > 1 else self.std_noise

    @property
    def distortion_to_noise_db(self) -> float:
        """10·log10 of the mean distortion variance over the mean noise variance (all lines): ≫ 0 dB when the
        plant is nonlinear at this level; −inf when the distortions are below what M realisations resolve."""
        ratio = float(np.mean(self.var_distortion) / np.mean(self.var_noise))
        return 10 * math.log10(ratio) if ratio > 0 else -math.inf

    @property
    def relative_distortion_db(self) -> float:
        """10·log10 of one realisation's distortion variance (M·σ²_BLA,s) over |G_BLA|², averaged over the lines:
        the stochastic distortions' power relative to the linear part's in the output (−inf when not resolved)."""
        ratio = float(np.mean(self.realisations * self.var_distortion) / np.mean(np.abs(self.G) ** 2))
        return 10 * math.log10(ratio) if ratio > 0 else -math.inf

    @property
    def total_to_noise_db(self) -> float:
        """10·log10 of the mean total variance over the mean noise variance: ≈ 0 dB for a linear plant."""
        return 10 * math.log10(float(np.mean(self.var_total) / np.mean(self.var_noise)))

    def detection_to_noise_db(self, parity: str) -> float:
        """10·log10 of the output power at the ``even`` or ``odd`` detection lines over its noise power there
        (NaN without such lines): ≈ 0 dB when the plant makes no distortion of that parity."""
        pick = self.detection_lines % 2 == (0 if parity == "even" else 1)
        if not pick.any():
            return math.nan
        return 10 * math.log10(float(np.mean(self.detection_level[pick] ** 2)
                                     / np.mean(self.detection_noise[pick] ** 2)))


def split_periods(x: np.ndarray, samples: int, periods: int, transient_periods: int, what: str = "record"):
    """Records of shape (..., (T + P)·N) as (..., P, N), the T leading periods dropped; a record of another length
    is a UserError naming ``what``."""
    x = np.asarray(x, float)
    expected = (periods + transient_periods) * samples
    if x.shape[-1] != expected:
        raise UserError(f"{what}: {x.shape[-1]} samples is not {transient_periods} + {periods} periods of "
                        f"{samples} samples ({expected})")
    return x[..., transient_periods * samples:].reshape(*x.shape[:-1], periods, samples)


def estimate_bla(u: np.ndarray, y: np.ndarray, lines: Sequence[int] | np.ndarray, rate: float,
                 detection: Sequence[int] | np.ndarray = ()) -> BLA:
    """The robust BLA of periodic data (module docstring).

    Parameters
    ----------
    u, y : ndarray, shape (M, P, N)
        Input and output: M realisations, P periods of N samples each, in steady state.
    lines : array of int
        The excited lines (DFT bins of one period).
    rate : float
        Sample rate (Hz): line k lies at k·rate/N Hz.
    detection : array of int
        Lines of the band left without excitation (their output levels are reported).

    Returns
    -------
    BLA
        G_BLA, its noise, distortion and total variances and the coherence at ``lines``; the levels at
        ``detection``.
    """
    from ..api_checks import check_arguments

    check_arguments(estimate_bla, locals())  # a wrong type: UserError naming it
    u, y = np.asarray(u, float), np.asarray(y, float)
    if u.ndim != 3 or u.shape != y.shape:
        raise UserError(f"u and y must both have the shape (realisations, periods, samples), not {u.shape} and "
                        f"{y.shape}")
    m, p, n = u.shape
    lines, detection = np.asarray(lines, int), np.asarray(detection, int)
    scale = 2.0 / n
    U = np.fft.rfft(u, axis=-1)[..., lines] * scale
    Yall = np.fft.rfft(y, axis=-1) * scale
    Y = Yall[..., lines]
    Um, Ym = U.mean(axis=1), Y.mean(axis=1)  # (M, K)
    if np.any(np.abs(Um) == 0):
        raise UserError("the input has no power at some excited line: not the excitation these lines belong to")
    Gm = Ym / Um
    G = Gm.mean(axis=0)
    nan = np.full(G.shape, np.nan)
    if p > 1:
        dU, dY = U - Um[:, None], Y - Ym[:, None]
        vU = np.sum(np.abs(dU) ** 2, axis=1) / (p - 1)
        vY = np.sum(np.abs(dY) ** 2, axis=1) / (p - 1)
        cYU = np.sum(dY * np.conj(dU), axis=1) / (p - 1)
        var_gm = (vY - 2 * np.real(np.conj(Gm) * cYU) + np.abs(Gm) ** 2 * vU) / (p * np.abs(Um) ** 2)
        var_noise = var_gm.sum(axis=0) / m ** 2
    else:
        var_noise = nan
    var_total = np.sum(np.abs(Gm - G) ** 2, axis=0) / (m * (m - 1)) if m > 1 else nan
    Suu = np.sum(np.abs(U) ** 2, axis=(0, 1))
    Syy = np.sum(np.abs(Y) ** 2, axis=(0, 1))
    Syu = np.sum(Y * np.conj(U), axis=(0, 1))
    coherence = np.abs(Syu) ** 2 / (Suu * Syy)
    D = Yall[..., detection]
    Dm = D.mean(axis=1)
    det_noise = np.sqrt(np.mean(np.sum(np.abs(D - Dm[:, None]) ** 2, axis=1) / (p - 1), axis=0) / p) \
        if p > 1 else np.full(detection.shape, np.nan)
    frequency, re_response, over_floor = nonsynchronous_components(y, rate, float(np.sum(np.abs(Ym) ** 2) / m))
    return BLA(frequencies=lines * rate / n, G=G, var_noise=var_noise, var_distortion=var_total - var_noise,
               var_total=var_total, coherence=coherence, U=np.mean(np.abs(Um), axis=0),
               detection_frequencies=detection * rate / n, detection_level=np.sqrt(np.mean(np.abs(Dm) ** 2, axis=0)),
               detection_noise=det_noise, detection_lines=detection, periods=p, realisations=m,
               nonsynchronous_frequency=frequency, nonsynchronous_re_response_db=re_response,
               nonsynchronous_over_floor_db=over_floor)


# Between the lines, a periodic response's whole-record DFT holds noise alone: each bin's power over the local
# floor (the median of FLOOR_LINES lines' bins, over ln 2: the mean of an exponential) follows about Exp(1), and
# the largest of L bins about ln L.  A component is reported where it stands FALSE_ALARM_MARGIN above that (one
# false report in e^9 ≈ 8 000 periodic records) and carries at least MIN_NONSYNCHRONOUS of the response's power
# (noise-free records: a transient's last 1e-9 is no finding).
FLOOR_LINES = 32
FALSE_ALARM_MARGIN = 9.0
MIN_NONSYNCHRONOUS = 1e-6


def nonsynchronous_components(y: np.ndarray, rate: float, response_power: float) -> tuple[float, float, float]:
    """(frequency in Hz, power re ``response_power`` in dB, power over the local floor in dB) of the strongest
    output component between the period's lines of ``y`` (M, P, N) — all NaN where none stands out (see above) or
    P = 1 (no bins between the lines)."""
    m, p, n = y.shape
    nan = (math.nan, math.nan, math.nan)
    if p < 2:
        return nan
    power = np.abs(np.fft.rfft(y.reshape(m, p * n), axis=-1) * (2.0 / (p * n))) ** 2
    between = np.flatnonzero(np.arange(power.shape[-1]) % p)
    block = FLOOR_LINES * (p - 1)
    usable = between.size // block * block
    if usable == 0:
        return nan
    blocks = power[:, between[:usable]].reshape(m, -1, block)  # (M, blocks, bins)
    floor = np.median(blocks, axis=-1, keepdims=True) / math.log(2)
    ratio = blocks / np.maximum(floor, 1e-300)
    realisation, k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    strongest = float(ratio[realisation, k, j])
    share = float(blocks[realisation, k, j]) / max(response_power, 1e-300)
    if strongest < math.log(ratio.size) + FALSE_ALARM_MARGIN or share < MIN_NONSYNCHRONOUS:
        return nan
    return float(between[k * block + j] * rate / (p * n)), 10 * math.log10(share), 10 * math.log10(strongest)


@dataclass(frozen=True)
class H1Estimate:
    """The H1 estimate S_yu/S_uu of a record (Welch averages, Hann window, half overlap): ``frequencies`` (Hz),
    ``G`` (complex), ``coherence`` and ``var`` (variance of G: |G|²(1 − γ²)/(n_d γ²), Bendat & Piersol, with n_d
    the number of segments averaged)."""

    frequencies: np.ndarray
    G: np.ndarray
    coherence: np.ndarray
    var: np.ndarray
    segments: int

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return Shown(type(self).__name__, f"at {self.frequencies.size} lines, {self.segments} segments averaged",
                     _band_figures(self.frequencies, self.G, self.coherence))


def _band_figures(frequencies: np.ndarray, G: np.ndarray, coherence: np.ndarray) -> tuple:
    """The band (Hz), |G|'s range in dB (of the output unit per input unit) and the lowest coherence."""
    if frequencies.size == 0:
        return ()
    mag = 20 * np.log10(np.maximum(np.abs(G), 1e-300))
    return (figure("band", f"{frequencies.min():.4g}–{frequencies.max():.4g}", "Hz"),
            figure("|G|", f"{mag.min():.3g} to {mag.max():.3g}", "dB"),
            figure("lowest coherence", float(np.min(coherence)), "", ".3g"))


def h1_estimate(u: np.ndarray, y: np.ndarray, rate: float, segment: int | None = None,
                band: tuple[float, float] | None = None) -> H1Estimate:
    """The H1 estimate of a record of any kind (chirp, PRBS, a drive's log; periodic or not).

    Leakage and transients bias it (not removed here); on periodic data the BLA (:func:`estimate_bla`) is exact
    where H1 is not.

    Parameters
    ----------
    u, y : ndarray
        Input and output, one record each, of one length, sampled at ``rate``.
    rate : float
        Sample rate (Hz).
    segment : int, optional
        Samples per Welch segment (default: the record / 8, at least 256).
    band : (float, float), optional
        Keep the frequencies in [f_min, f_max] (Hz).

    Returns
    -------
    H1Estimate
        Frequencies, G, coherence and the variance of G.
    """
    from ..api_checks import check_arguments

    check_arguments(h1_estimate, locals())  # a wrong type: UserError naming it
    from scipy.signal import csd, welch

    u, y = np.asarray(u, float).ravel(), np.asarray(y, float).ravel()
    if u.shape != y.shape or u.size < 16:
        raise UserError(f"u and y must be records of one length (≥ 16 samples), not {u.size} and {y.size}")
    nperseg, segments = _welch_segments(u.size, segment)
    f, Suu = welch(u, fs=rate, nperseg=nperseg)
    _, Syy = welch(y, fs=rate, nperseg=nperseg)
    _, Suy = csd(u, y, fs=rate, nperseg=nperseg)  # E[conj(U) Y]
    keep = Suu > 0
    if band is not None:
        keep &= (f >= band[0]) & (f <= band[1])
    f, Suu, Syy, Suy = f[keep], Suu[keep], Syy[keep], Suy[keep]
    G = Suy / Suu
    coherence = np.clip(np.abs(Suy) ** 2 / (Suu * Syy), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.abs(G) ** 2 * (1 - coherence) / (segments * coherence)
    return H1Estimate(frequencies=f, G=G, coherence=coherence, var=var, segments=segments)


def _welch_segments(samples: int, segment: int | None) -> tuple[int, int]:
    """Samples per Welch segment (``segment``, default the record / 8 and at least 256, at most the record) and
    the number of half-overlapping segments the spectra average."""
    nperseg = min(int(segment or max(256, samples // 8)), samples)
    return nperseg, max(1, 2 * samples // nperseg - 1)


@dataclass(frozen=True)
class ClosedLoopEstimate:
    """The plant's response from a closed-loop record with the reference r as the external signal:
    G = S_ry/S_ur (Welch cross-spectra, Hann window, half overlap), ``frequencies`` (Hz), ``G``, ``var`` (its
    variance S_ee/(n_d·S_uu·γ²_ru), e = y − G·u the noise left in the output, n_d the segments), ``coherence_ru``
    and ``coherence_ry`` (of the reference with the input and the output), ``segments``."""

    frequencies: np.ndarray
    G: np.ndarray
    var: np.ndarray
    coherence_ru: np.ndarray
    coherence_ry: np.ndarray
    segments: int


def closed_loop_estimate(r: np.ndarray, u: np.ndarray, y: np.ndarray, rate: float, segment: int | None = None,
                         band: tuple[float, float] | None = None) -> ClosedLoopEstimate:
    """The plant's response u → y in a loop, from the reference ``r`` (independent of the loop's noise).

    In a loop the noise at the output returns through the controller into u, so u is correlated with the noise
    and the direct estimate S_uy/S_uu (:func:`h1_estimate`) is biased towards −1/C where the noise dominates.
    Cross-spectra with r are not (Pintelon & Schoukens, ch. 9; Ljung, the indirect and joint input–output
    methods): S_ry = G·S_ru + S_re with S_re → 0 as segments are averaged.

    Parameters
    ----------
    r, u, y : ndarray
        Reference (any unit), plant input (N) and output (m/s), one record each, sampled at ``rate``.
    rate, segment, band
        As for :func:`h1_estimate`: the sample rate (Hz), the Welch segment and the band kept.

    Returns
    -------
    ClosedLoopEstimate
        Frequencies, G, its variance and the coherences.
    """
    from scipy.signal import csd, welch

    r, u, y = (np.asarray(x, float).ravel() for x in (r, u, y))
    if not (r.shape == u.shape == y.shape) or u.size < 16:
        raise UserError(f"r, u and y must be records of one length (≥ 16 samples), not {r.size}, {u.size} and "
                        f"{y.size}")
    nperseg, segments = _welch_segments(u.size, segment)
    f, Srr = welch(r, fs=rate, nperseg=nperseg)
    _, Suu = welch(u, fs=rate, nperseg=nperseg)
    _, Syy = welch(y, fs=rate, nperseg=nperseg)
    _, Sru = csd(r, u, fs=rate, nperseg=nperseg)
    _, Sry = csd(r, y, fs=rate, nperseg=nperseg)
    _, Suy = csd(u, y, fs=rate, nperseg=nperseg)
    keep = (np.abs(Sru) > 0) & (Srr > 0)
    if band is not None:
        keep &= (f >= band[0]) & (f <= band[1])
    f, Srr, Suu, Syy, Sru, Sry, Suy = (x[keep] for x in (f, Srr, Suu, Syy, Sru, Sry, Suy))
    G = Sry / Sru
    coh_ru = np.clip(np.abs(Sru) ** 2 / (Srr * Suu), 0.0, 1.0)
    coh_ry = np.clip(np.abs(Sry) ** 2 / (Srr * Syy), 0.0, 1.0)
    See = np.clip(Syy - 2 * np.real(np.conj(G) * Suy) + np.abs(G) ** 2 * Suu, 0.0, None)
    with np.errstate(divide="ignore", invalid="ignore"):
        var = See / (segments * Suu * coh_ru)
    return ClosedLoopEstimate(frequencies=f, G=G, var=var, coherence_ru=coh_ru, coherence_ry=coh_ry,
                              segments=segments)
