"""The local polynomial method (LPM) for arbitrary records: chirp, PRBS, a drive's log, any imported record, periodic
or not (Pintelon, Schoukens, Vandersteen & Barbé, MSSP 2010; Pintelon & Schoukens, System Identification, 2nd ed.,
ch. 7).

On the DFT of the whole record (no window; X(k) = Σ_t x(t) e^(−j2πkt/N), unscaled) a linear system with any initial
and final state gives exactly Y(k) = G(k)·U(k) + T(k) + V(k): T, the transient (leakage) term, is a smooth —
rational — function of frequency, like G; V the noise.  Around each line k, over the 2n + 1 lines k + r,
r = −n..n, both are polynomials of degree R:

    Y(k+r) = (G(k) + Σ_s g_s r^s)·U(k+r) + T(k) + Σ_s t_s r^s + V(k+r),   s = 1..R,

2(R + 1) complex parameters fitted by least squares; G(k) is the constant coefficient.  The residuals leave
dof = 2n + 1 − 2(R + 1) complex degrees of freedom: the noise variance σ²_V(k) = ‖residual‖²/dof (of Y(k), per
line, unscaled: N·σ² for white noise of variance σ²) and var G(k) = σ²_V(k)·[(KᴴK)⁻¹]₀₀, K the window's regressor.
Removing T is what H1 (Welch, windowed) cannot do: its leakage and transient bias does not fall with averaging.

Closed loop (a reference r, independent of the noise): the same fit of Z = [Y; U] on R(k+r), G_zr = [G_yr; G_ur]
and T_z, a 2×2 residual covariance C_z; G = G_yr/G_ur, its variance to first order
[(KᴴK)⁻¹]₀₀·(C_yy − 2 Re(G*·C_yu) + |G|²·C_uu)/|G_ur|².  That first order fails where the reference barely moves
u on a line (G_ur about its own noise): the ratio is then biased and the band ±k·σ too narrow (86 % coverage
below 5 Hz in scripts/bench_lpm.py's loop).  The band of a closed-loop estimate is Fieller's instead, exact for
the ratio of two Gaussian estimates: the G for which the residual G_yr − G·G_ur is within k of its own standard
deviation, |G_yr − G·G_ur|² ≤ k²·[(KᴴK)⁻¹]₀₀·(C_yy − 2 Re(G*·C_yu) + |G|²·C_uu) — a quadratic inequality in G,
a disc where |G_ur|² > k²·[(KᴴK)⁻¹]₀₀·C_uu (G_ur stands out of its noise) and unbounded where not: there the data
do not bound G at all (:meth:`LpmEstimate.band`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError

__all__ = ["LpmEstimate", "lpm_estimate", "default_half_width"]

_CHUNK = 4096  # lines solved at once: bounds the (lines, 2n+1, 2(R+1)) regressor stack in memory


def default_half_width(order: int) -> int:
    """n of the window for polynomials of degree ``order``: n = R + 2, 2n + 1 = 2R + 5 lines for 2(R + 1)
    parameters, dof = 3 complex degrees of freedom whatever R.

    Three is the usual compromise (Pintelon et al. 2010 take dof of a few): each extra line widens the window over
    which G and T must be polynomials (bias where G changes fast, e.g. at a resonance) and smooths σ²_V over more
    lines, while dof = 1 or 2 leaves σ²_V so scattered (relative spread 1/√dof) that the band must be very wide:
    k = √F⁻¹(0.95; 2, 2·dof) is 4.4 at dof = 1, 2.3 at dof = 3, 2.0 at dof = 5 against 1.73 with σ known."""
    return int(order) + 2


@dataclass(frozen=True)
class LpmEstimate:
    """The LPM's estimate (module docstring): ``frequencies`` (Hz), ``G`` (complex), ``var`` (variance of G),
    ``noise_var`` (σ²_V, the output's noise variance per DFT line, unscaled DFT: N·σ² for white noise of variance
    σ²), ``dof`` (complex degrees of freedom of σ²_V), ``order`` (R), ``half_width`` (n), ``closed_loop`` (fitted
    on the reference) and ``samples`` (N).

    Parameters
    ----------
    frequencies, G, var, noise_var : ndarray
        One value per DFT line of the band.
    dof, order, half_width, samples : int
        As above.
    closed_loop : bool
        True when G = G_yr/G_ur from a reference.
    ratio : ndarray, optional
        Closed loop: per line G_ur, [(KᴴK)⁻¹]₀₀, C_yy, C_uu and C_yu (columns; complex) — Fieller's band.
    """

    frequencies: np.ndarray
    G: np.ndarray
    var: np.ndarray
    noise_var: np.ndarray
    dof: int
    order: int
    half_width: int
    closed_loop: bool
    samples: int
    ratio: np.ndarray | None = None

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        f = self.frequencies
        figures = (figure("band", f"{f.min():.4g}–{f.max():.4g}" if f.size else "empty", "Hz"),
                   figure("median σ/|G|", float(np.median(self.std / np.abs(self.G))) if f.size else math.nan),
                   figure("dof", self.dof), figure("95 % factor", self.band_factor(), "", ".3g"))
        how = "from the reference" if self.closed_loop else "open loop"
        return Shown(type(self).__name__, f"{how}, R = {self.order}, n = {self.half_width}, {f.size} lines",
                     figures)

    @property
    def std(self) -> np.ndarray:
        """Standard deviation of G."""
        return np.sqrt(self.var)

    def band_factor(self, level: float = 0.95) -> float:
        """k of the band G ± k·σ that holds the true G with probability ``level``.

        σ² is estimated from the residuals with dof complex (2·dof real) degrees of freedom, independent of G's
        error (least squares, Gaussian noise), so |Ĝ − G|²/σ̂² follows F(2, 2·dof) and k = √F⁻¹(level; 2, 2·dof):
        2.27 at dof = 3 (±2σ holds only 92 %), → 1.73 as dof grows (σ known)."""
        from scipy.stats import f

        return float(np.sqrt(f.ppf(level, 2, 2 * self.dof)))

    def band(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """(centre, radius) per line of the disc that holds the true G with probability ``level``: open loop
        G ± k·σ (:meth:`band_factor`); closed loop Fieller's (module docstring), radius inf where the data do not
        bound G (the reference's effect on u within its noise on that line)."""
        k2 = self.band_factor(level) ** 2
        if self.ratio is None:
            return self.G, np.sqrt(k2 * self.var)
        gur, p00, c_yy, c_uu, c_yu = self.ratio.T
        q = k2 * p00.real
        gyr = self.G * gur
        a = np.abs(gur) ** 2 - q * c_uu.real
        b = gyr * np.conj(gur) - q * c_yu
        c = np.abs(gyr) ** 2 - q * c_yy.real
        with np.errstate(divide="ignore", invalid="ignore"):
            centre = np.where(a > 0, b / a, self.G)
            radius = np.where(a > 0, np.sqrt(np.clip(np.abs(b) ** 2 - a * c, 0.0, None)) / a, np.inf)
        return centre, radius


def _lines(n: int, rate: float, band, width: int) -> np.ndarray:
    """The DFT lines of the band (default: all but DC and Nyquist); a band narrower than the window is refused."""
    top = (n - 1) // 2
    k = np.arange(1, top + 1)
    if band is not None:
        f = k * rate / n
        k = k[(f >= band[0]) & (f <= band[1])]
    if k.size < width:
        raise UserError(f"the band holds {k.size} DFT lines of the record, fewer than the LPM's window of {width} "
                        "lines: widen the band, lengthen the record or lower the order")
    return k


def _windows(lines: np.ndarray, half: int) -> np.ndarray:
    """Per line the offsets r of its window: −n..n, shifted at the band's edges to stay inside the band."""
    r = np.arange(-half, half + 1)
    centre = np.clip(np.arange(lines.size), half, lines.size - 1 - half)
    return (centre - np.arange(lines.size))[:, None] + r  # index offsets within the band's lines


def _fit(X: np.ndarray, Z: np.ndarray, lines: np.ndarray, order: int, half: int):
    """Per line: the local fit of Z (…, m outputs) on X with polynomial coefficients and a polynomial transient.

    Returns the constant coefficients of X (lines, m), [(KᴴK)⁻¹]₀₀ (lines,) and the residual sums of products
    (lines, m, m)."""
    offsets = _windows(lines, half)
    r = (lines[np.arange(lines.size)[:, None] + offsets] - lines[:, None]) / half  # scaled: conditioning only
    powers = r[..., None] ** np.arange(order + 1)  # (L, 2n+1, R+1)
    idx = np.arange(lines.size)[:, None] + offsets
    x = X[idx]
    K = np.concatenate([powers * x[..., None], powers], axis=-1)  # (L, 2n+1, 2(R+1)); column 0: X itself
    z = Z[idx]  # (L, 2n+1, m)
    Q, Rm = np.linalg.qr(K)
    theta = np.linalg.solve(Rm, np.conj(np.swapaxes(Q, -1, -2)) @ z)
    resid = z - K @ theta
    Rinv = np.linalg.inv(Rm)
    p00 = np.sum(np.abs(Rinv[:, 0, :]) ** 2, axis=-1)  # (KᴴK)⁻¹ = R⁻¹R⁻ᴴ: its [0, 0] is row 0 of R⁻¹ squared
    S = np.conj(np.swapaxes(resid, -1, -2)) @ resid  # (L, m, m): [i, j] = Σ conj(e_i)·e_j
    return theta[:, 0, :], p00, S


def lpm_estimate(u: np.ndarray, y: np.ndarray, rate: float, order: int = 2, half_width: int | None = None,
                 band: tuple[float, float] | None = None, reference: np.ndarray | None = None) -> LpmEstimate:
    """The LPM estimate of the response u → y from one record of any kind (module docstring).

    Parameters
    ----------
    u, y : ndarray
        Input and output, one record each, of one length N, sampled at ``rate``.
    rate : float
        Sample rate (Hz): line k lies at k·rate/N Hz.
    order : int
        R, the degree of the local polynomials of G and of the transient (2 by default; without noise the
        relative error on a smooth G is ~3e-8 at the median line and ~3e-5 at the 95th percentile, measured).
    half_width : int, optional
        n, the window's half width in lines (default :func:`default_half_width`, dof = 3); at least R + 2
        (dof ≥ 1 for the noise).
    band : (float, float), optional
        Keep the lines in [f_min, f_max] (Hz); the windows stay inside it.
    reference : ndarray, optional
        The loop's reference r (independent of the noise): the closed-loop form, G = G_yr/G_ur.

    Returns
    -------
    LpmEstimate
        Frequencies, G, its variance, the output's noise variance per line and the fit's dof.
    """
    u, y = np.asarray(u, float).ravel(), np.asarray(y, float).ravel()
    r = None if reference is None else np.asarray(reference, float).ravel()
    if u.shape != y.shape or (r is not None and r.shape != u.shape):
        raise UserError(f"u, y (and the reference) must be records of one length, not {u.size} and {y.size}"
                        + ("" if r is None else f" and {r.size}"))
    order = int(order)
    half = default_half_width(order) if half_width is None else int(half_width)
    if order < 0 or half < order + 2:
        raise UserError(f"LPM order {order} and half width {half}: give order ≥ 0 and half width ≥ order + 2 "
                        "(the noise needs a degree of freedom)")
    n = u.size
    lines = _lines(n, rate, band, 2 * half + 1)
    dof = 2 * half + 1 - 2 * (order + 1)
    U, Y = np.fft.fft(u)[lines], np.fft.fft(y)[lines]
    X, Z = (U, Y[:, None]) if r is None else (np.fft.fft(r)[lines], np.column_stack([Y, U]))
    G, var, noise = (np.empty(lines.size, complex), np.empty(lines.size), np.empty(lines.size))
    ratio = None if r is None else np.empty((lines.size, 5), complex)
    for start in range(0, lines.size, _CHUNK):
        # each chunk is fitted with the band's lines around it so the windows see their true neighbours
        lo, hi = max(0, start - 2 * half), min(lines.size, start + _CHUNK + 2 * half)
        g, p00, S = _fit(X[lo:hi], Z[lo:hi], lines[lo:hi], order, half)
        keep = slice(start - lo, start - lo + min(_CHUNK, lines.size - start))
        g, p00, C = g[keep], p00[keep], S[keep] / dof
        if r is None:
            G[start:start + g.shape[0]], v = g[:, 0], C[:, 0, 0].real
            var[start:start + g.shape[0]] = p00 * v
        else:
            gyr, gur = g[:, 0], g[:, 1]
            Gk = gyr / gur
            G[start:start + g.shape[0]], v = Gk, C[:, 0, 0].real
            ee = C[:, 0, 0].real - 2 * np.real(np.conj(Gk) * C[:, 1, 0]) + np.abs(Gk) ** 2 * C[:, 1, 1].real
            var[start:start + g.shape[0]] = p00 * np.clip(ee, 0.0, None) / np.abs(gur) ** 2
            ratio[start:start + g.shape[0]] = np.column_stack([gur, p00, C[:, 0, 0], C[:, 1, 1], C[:, 1, 0]])
        noise[start:start + g.shape[0]] = v
    return LpmEstimate(frequencies=lines * rate / n, G=G, var=var, noise_var=noise, dof=dof, order=order,
                       half_width=half, closed_loop=r is not None, samples=n, ratio=ratio)
