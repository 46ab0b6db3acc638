"""A first estimate of G(s) and the Coulomb friction for a candidate order, by linear least squares: where each
candidate's swarm starts (the swarm searches a box around it), since a user choosing a structure has no values.

The plant v = G·(u − F), G = N/D (D monic of degree n, N of degree m < n), with the friction F = fc+·s⁺ − fc−·s⁻
(s⁺ = [v > 0], s⁻ = [v < 0]; viscous friction is part of G), obeys D(p)·v = N(p)·u − fc+·N(p)·s⁺ + fc−·N(p)·s⁻.
Taking fc±·N as polynomials C, E of their own makes the equation linear in the coefficients of D, N, C and E;
the friction levels are then the least-squares ratios fc+ = −⟨C, N⟩/⟨N, N⟩ and fc− = ⟨E, N⟩/⟨N, N⟩.

- Records (time series from rest, uniformly sampled): the derivatives p^k are taken through the state-variable
  filter λⁿ/(p + λ)ⁿ (the equation holds for the filtered signals too: every term passes the same filter), the
  filters discretised by the bilinear transform.
- Stepped-sine windows (whole periods of the periodic steady state): the equation holds at every harmonic kω of
  the window's Fourier series, p = jkω, exactly.

Rows are weighted by 1/|D(p)| of the previous solution (Sanathanan–Koerner iterations), which removes the
high-frequency bias of the plain equation-error fit.  The estimate is biased by the noise and by the friction
model's approximation; the swarm and the polish that follow correct it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LinearEstimate", "Series", "estimate_linear", "start_estimates", "data_bandwidth", "series_of_records",
           "series_of_experiments", "input_power_sign"]

ITERATIONS = 4  # Sanathanan–Koerner reweightings
HARMONICS = 15  # harmonics of a stepped-sine window used


@dataclass(frozen=True)
class LinearEstimate:
    """G(s) = N(s)/D(s) as roots and a numerator constant, and the Coulomb levels fc_pos, fc_neg (N)."""

    poles: tuple[complex, ...]
    zeros: tuple[complex, ...]
    gain: float
    fc_pos: float
    fc_neg: float
    v_rms: float  # RMS velocity of the data (m/s): the scale of the Stribeck velocity's first guess


@dataclass(frozen=True)
class Series:
    """One stretch of data: uniformly sampled ``u`` (N) and ``v`` (m/s) at step ``dt`` (s); ``periodic``: whole
    periods of a periodic steady state (a stepped-sine window)."""

    u: np.ndarray
    v: np.ndarray
    dt: float
    periodic: bool


def series_of_records(records) -> list[Series]:
    """The fitted samples of records (identification.criterion.RecordSeries with velocity output, or records
    whose velocity is derived from the position) as Series."""
    out = []
    for r in records:
        f = r.fitted
        v = r.y[f] if r.output == "v" else np.gradient(r.y[f], r.time[f])
        dt = float(np.median(np.diff(r.time)))
        out.append(Series(u=np.asarray(r.u[f], float), v=np.asarray(v, float), dt=dt, periodic=False))
    return out


def series_of_experiments(experiments) -> list[Series]:
    """The analysed windows of stepped-sine experiments (the noisy velocity where the file has one)."""
    out = []
    for e in experiments:
        if not e.converged:
            continue
        w = e.window
        v = w.v_noisy if w.v_noisy is not None else w.v
        n = e.window_periods * e.samples_per_period  # whole periods only
        out.append(Series(u=np.asarray(w.u[:n], float), v=np.asarray(v[:n], float),
                          dt=float(w.time[1] - w.time[0]), periodic=True))
    return out


def _filtered(x: np.ndarray, dt: float, lam: float, n: int) -> np.ndarray:
    """Rows p^k·λⁿ/(p + λ)ⁿ·x for k = 0..n, in time units of 1/λ (so p^k is O(1))."""
    from scipy.signal import bilinear, lfilter

    rows = []
    den = np.poly(np.full(n, -1.0))  # (s + 1)^n in the scaled time
    for k in range(n + 1):
        num = np.zeros(n + 1)
        num[n - k] = 1.0  # s^k
        b, a = bilinear(num, den, fs=1.0 / (dt * lam))
        rows.append(lfilter(b, a, x))
    return np.array(rows)


def _time_rows(s: Series, n: int, lam: float):
    """Per signal (v, u, s⁺, s⁻) its filtered derivatives 0..n: complex-free regressors of one record."""
    sp, sn = (s.v > 0).astype(float), (s.v < 0).astype(float)
    return [_filtered(x, s.dt, lam, n) for x in (s.v, s.u, sp, sn)], None


def _harmonic_rows(s: Series, n: int, lam: float):
    """Per signal its Fourier coefficients at the window's harmonics times (jω/λ)^k, k = 0..n, and p = jω/λ."""
    m = s.v.size
    periods = _periods(s)
    bins = periods * np.arange(0, HARMONICS + 1)
    bins = bins[bins < m // 2]
    omega = 2 * np.pi * bins / (m * s.dt) / lam
    p = 1j * omega
    sp, sn = (s.v > 0).astype(float), (s.v < 0).astype(float)
    out = []
    for x in (s.v, s.u, sp, sn):
        spectrum = np.fft.rfft(x)[bins] / m
        out.append(np.array([p**k * spectrum for k in range(n + 1)]))
    return out, p


def _periods(s: Series) -> int:
    """The number of periods of a window: the bin of the input's strongest non-zero harmonic."""
    spectrum = np.abs(np.fft.rfft(s.u))
    spectrum[0] = 0
    return int(np.argmax(spectrum))


def estimate_linear(series: list[Series], order: int, zeros: int, bandwidth: float | None = None
                    ) -> LinearEstimate:
    """The least-squares estimate of G (``order`` poles, ``zeros`` zeros) and the Coulomb levels from ``series``.

    ``bandwidth`` λ (rad/s) of the state-variable filter: by default a fifth of the Nyquist frequency of records,
    ten times the highest excitation frequency of stepped-sine windows.  Raises ValueError when the data leaves
    the equation undetermined (no excitation)."""
    n, m = order, zeros
    lam = bandwidth or _default_bandwidth(series)
    blocks = [(_harmonic_rows(s, n, lam) if s.periodic else _time_rows(s, n, lam)) for s in series]
    a = None  # the first pass unweighted
    for _ in range(ITERATIONS):
        rows, rhs = [], []
        for (v, u, sp, sn), p in blocks:
            # unknowns: a_0..a_{n-1} (D monic), b_0..b_m (N), c_0..c_m (C = −fc+·N), e_0..e_m (E = fc−·N)
            x = np.vstack([-v[:n], u[:m + 1], sp[:m + 1], sn[:m + 1]]).T
            y = v[n]
            if p is not None:
                w = 1.0 if a is None else 1.0 / np.maximum(np.abs(np.polyval(np.r_[1.0, a[::-1]], p)), 1e-12)
                x, y = x * np.reshape(w, (-1, 1)), y * w
                x, y = np.vstack([x.real, x.imag]), np.concatenate([y.real, y.imag])
            rows.append(x)
            rhs.append(y)
        x, y = np.vstack(rows), np.concatenate(rhs)
        scale = np.linalg.norm(x, axis=0)
        scale[scale == 0] = 1.0
        coef = np.linalg.lstsq(x / scale, y, rcond=None)[0] / scale
        if not np.all(np.isfinite(coef)):
            raise ValueError("the data does not determine the linear estimate")
        a_new = coef[:n]
        if a is not None and np.allclose(a_new, a, rtol=1e-6):
            break
        a = a_new
        if series and not series[0].periodic:
            break  # records: the filtered equation has no frequency weight to update
    a, b, c, e = coef[:n], coef[n:n + m + 1], coef[n + m + 1:n + 2 * m + 2], coef[n + 2 * m + 2:]
    return _as_estimate(a, b, c, e, lam, series)


def _default_bandwidth(series: list[Series]) -> float:
    if series[0].periodic:
        top = max(2 * np.pi * _periods(s) / (s.u.size * s.dt) for s in series)
        return 10.0 * top
    return 0.2 * np.pi / series[0].dt


def _as_estimate(a, b, c, e, lam, series) -> LinearEstimate:
    """Roots in rad/s (the scaled coefficients undone), the numerator constant and the friction levels."""
    n, m = a.size, b.size - 1
    den = np.r_[1.0, a[::-1]]  # highest power first, in s/λ
    num = b[::-1]
    poles = np.roots(den) * lam
    zeros = np.roots(num) * lam if m > 0 else np.array([])
    # K: N(s) = Σ b_k (s/λ)^k, its leading coefficient b_m/λ^m; D monic in s/λ is (1/λ^n)·(monic in s)
    gain = float(num[0] * lam ** (n - m)) if num.size else 1.0
    nn = float(b @ b) or 1.0
    fc_pos, fc_neg = float(-(c @ b) / nn), float((e @ b) / nn)
    v_rms = float(np.sqrt(np.mean(np.concatenate([s.v for s in series]) ** 2)))
    return LinearEstimate(poles=tuple(poles), zeros=tuple(zeros), gain=gain, fc_pos=fc_pos, fc_neg=fc_neg,
                          v_rms=v_rms)


def data_bandwidth(series: list[Series]) -> float:
    """The fastest dynamics the data can show (rad/s): the Nyquist frequency of records, the highest harmonic
    the estimate uses of stepped-sine windows."""
    if series[0].periodic:
        return HARMONICS * max(2 * np.pi * _periods(s) / (s.u.size * s.dt) for s in series)
    return float(np.pi / min(s.dt for s in series))


def input_power_sign(series: list[Series]) -> float:
    """The sign of G's DC gain as the power the input delivers says it: a force into a mass with damping and
    friction does positive work on average (G is positive real), so Σ u·v > 0 unless input or output is measured
    with the opposite sign.  A least-squares first-order fit's sign is no guide: it flips when the data's
    resonance dominates."""
    return float(np.sign(sum(float(np.dot(s.u, s.v)) for s in series)) or 1.0)


def _dc_gain(e: LinearEstimate) -> float:
    num0 = np.prod([-z for z in e.zeros]).real if e.zeros else 1.0
    return float(e.gain * num0 / np.prod([-p for p in e.poles]).real)


def _plausible(e: LinearEstimate, sign: float) -> bool:
    """Stable poles none of which nearly at 0 (relative to the fastest), and a DC gain of the first-order
    estimate's sign: what the swarm's box around it can improve on."""
    mags = np.abs(e.poles)
    return bool(np.all(np.real(e.poles) < 0) and np.all(mags >= 1e-3 * mags.max()) and np.isfinite(e.gain)
                and np.sign(_dc_gain(e)) == sign)


def _augmented(base: LinearEstimate, zeros: int) -> LinearEstimate:
    """``base`` with a real pole five times faster than its fastest (and with ``zeros`` a zero six times faster),
    the DC gain kept: a higher-order start that responds as the lower-order estimate does."""
    fast = 5.0 * float(np.max(np.abs(base.poles)))
    poles, gain = (*base.poles, complex(-fast)), base.gain * fast
    new_zeros = base.zeros
    if zeros > len(base.zeros):
        new_zeros, gain = (*base.zeros, complex(-1.2 * fast)), gain / (1.2 * fast)
    return LinearEstimate(poles=poles, zeros=new_zeros, gain=gain, fc_pos=base.fc_pos, fc_neg=base.fc_neg,
                          v_rms=base.v_rms)


def start_estimates(series: list[Series], keys) -> dict[tuple[int, int], LinearEstimate]:
    """The linear estimate for every (order, zeros) of ``keys``: the least-squares one where it is plausible (stable,
    no pole nearly at 0, a DC gain of the sign of the input's power: :func:`input_power_sign`), else the estimate of
    one order less (with the zero where it has one) augmented by a fast pole (and zero).  Raises ValueError when
    the data determines not even the first-order estimate."""
    first = estimate_linear(series, 1, 0)
    sign = input_power_sign(series)
    out = {(1, 0): first}
    for order, zeros in sorted(set(keys)):
        if (order, zeros) in out:
            continue
        try:
            direct = estimate_linear(series, order, zeros)
            if _plausible(direct, sign):
                out[(order, zeros)] = direct
                continue
        except (ValueError, np.linalg.LinAlgError):
            pass
        lower = (order - 1, min(zeros, order - 2))
        if lower not in out:
            out.update(start_estimates(series, [lower]))
        out[(order, zeros)] = _augmented(out[lower], zeros)
    return out
