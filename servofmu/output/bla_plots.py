"""The Bode plot of a BLA with its uncertainty: per level the BLA at the excited lines (markers), its 95 % band,
and beneath it the standard deviations from noise and from nonlinear distortions (docs/broadband.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..broadband.bla import BLA
from .plots import figure_axes, finish_figure

__all__ = ["bla_figure", "records_frf_figure", "plot_bla", "plot_records_frf"]


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.abs(x))


def bla_figure(levels: list[tuple[float, BLA]], path: str | Path, title: str = "", overwrite: bool = False,
               unit: str = "m/(N·s)", models: tuple = ()) -> Path:
    """:func:`plot_bla` written to ``path`` (an existing file only with ``overwrite``)."""
    return finish_figure(plot_bla(levels, title, unit, models), path, overwrite)


def plot_bla(levels: list[tuple[float, BLA]], title: str = "", unit: str = "m/(N·s)", models: tuple = (), ax=None):
    """Magnitude (with the 95 % band, ±k·σ with k from the realisations (BLA.band_factor), and the noise and
    distortion levels) and phase of each level's BLA, and the
    responses ``models`` ((label, frequencies in Hz, complex response), drawn as lines) over them.

    ``ax``: (magnitude, phase) matplotlib Axes to draw into, else a new Figure.  Returns the Figure.
    """
    fig, (ax_mag, ax_ph) = figure_axes(ax, 2, (8, 7), sharex=True)
    for k, (level, b) in enumerate(levels):
        color, f = f"C{k}", b.frequencies
        mag, std = np.abs(b.G), b.band_factor() * b.std_band  # the half-width of the 95 % band
        ax_mag.semilogx(f, _db(b.G), ".", color=color, ms=4, label=f"BLA at {level:g} N RMS (excited lines)")
        if np.isfinite(std).any():
            ax_mag.fill_between(f, _db(np.maximum(mag - std, mag * 1e-3)), _db(mag + std), color=color,
                                alpha=0.2, lw=0)
            ax_mag.semilogx(f, _db(b.std_noise), ":", color=color, lw=1, label=f"σ noise at {level:g} N")
            ax_mag.semilogx(f, _db(b.std_distortion), "--", color=color, lw=1,
                            label=f"σ distortion at {level:g} N ({b.distortion_to_noise_db:.1f} dB over noise)")
        phase = np.degrees(np.unwrap(np.angle(b.G)))
        ax_ph.semilogx(f, phase, ".", color=color, ms=4)
        if np.isfinite(std).any():
            half = np.degrees(np.arcsin(np.clip(std / mag, 0, 1)))
            ax_ph.fill_between(f, phase - half, phase + half, color=color, alpha=0.2, lw=0)
    for k, (label, f, G) in enumerate(models):
        style = ("-", "-.", "--")[k % 3]
        ax_mag.semilogx(f, _db(G), style, color="k", lw=1.2, label=label)
        ax_ph.semilogx(f, np.degrees(np.unwrap(np.angle(G))), style, color="k", lw=1.2)
    _label(ax_mag, ax_ph, "G_BLA", unit, title or "best linear approximation, 95 % band (shaded)")
    return fig


def _label(ax_mag, ax_ph, name: str, unit: str, title: str) -> None:
    """The Bode axes' labels (the response ``name`` in ``unit``), grid, legend and title."""
    ax_mag.set_ylabel(f"|{name}| [dB re 1 {unit}]")
    ax_ph.set_ylabel(f"phase of {name} [deg]")
    ax_ph.set_xlabel("frequency [Hz]")
    for ax in (ax_mag, ax_ph):
        ax.grid(True, which="both", alpha=0.4)
    ax_mag.legend(fontsize=7)
    ax_mag.set_title(title)


def _with_band(ax_mag, ax_ph, f, G, std, color, label, marker, factor=2.0, lw=1.0, centre=None):
    """G (magnitude and wrapped phase) and its band ±factor·std, shaded: a disc about G, or about ``centre`` where
    given (Fieller's band of a ratio); none on the lines where it is infinite."""
    ax_mag.semilogx(f, _db(G), marker, color=color, ms=3, lw=lw, label=label)
    centre = G if centre is None else centre
    mag, radius = np.abs(centre), factor * std
    ok = np.isfinite(radius)
    if ok.any():
        ax_mag.fill_between(f, np.where(ok, _db(np.maximum(mag - radius, mag * 1e-3)), np.nan),
                            np.where(ok, _db(mag + radius), np.nan), color=color, alpha=0.2, lw=0)
    phase = np.degrees(np.angle(G))  # wrapped: noisy lines would carry an unwrapped phase off by turns
    ax_ph.semilogx(f, phase, marker, color=color, ms=3, lw=lw)
    if ok.any():
        middle = np.degrees(np.angle(centre))
        half = np.degrees(np.arcsin(np.clip(radius / mag, 0, 1)))
        ax_ph.fill_between(f, np.where(ok, middle - half, np.nan), np.where(ok, middle + half, np.nan),
                           color=color, alpha=0.2, lw=0)


def records_frf_figure(estimates, path: str | Path, title: str = "", overwrite: bool = False,
                       unit: str = "m/(N·s)") -> Path:
    """:func:`plot_records_frf` written to ``path`` (an existing file only with ``overwrite``)."""
    return finish_figure(plot_records_frf(estimates, title, unit), path, overwrite)


def plot_records_frf(estimates, title: str = "", unit: str = "m/(N·s)", ax=None):
    """Per record the direct estimate S_uy/S_uu and, for closed-loop records, the estimate S_ry/S_ru from the
    external signal r (the reference, or the injected disturbance; marked where γ²_ru ≥ 0.9), each with its ±2σ
    band, and the local polynomial method's estimate with its 95 % band (LpmEstimate.band: ±k·σ,
    k = √F⁻¹(0.95; 2, 2·dof), open loop; Fieller's from r, left out where the data do not bound G).

    ``ax``: (magnitude, phase) matplotlib Axes to draw into, else a new Figure.  Returns the Figure.
    """
    fig, (ax_mag, ax_ph) = figure_axes(ax, 2, (8, 7), sharex=True)
    for k, e in enumerate(estimates):
        if e.lpm is not None:  # first: every DFT line, beneath the Welch estimates' coarser grid
            m = e.lpm
            how = f"from the {e.external}" if m.closed_loop else "u → v"
            centre, radius = m.band()
            band = "Fieller's 95 % band" if m.closed_loop else f"±{m.band_factor():.2f}σ"
            _with_band(ax_mag, ax_ph, m.frequencies, m.G, radius, "0.45",
                       f"{e.name}: LPM {how} (R = {m.order}, {2 * m.half_width + 1} lines), {band}", "-", 1.0, 0.6,
                       centre)
        d = e.direct
        _with_band(ax_mag, ax_ph, d.frequencies, d.G, np.sqrt(d.var), f"C{2 * k}", f"{e.name}: direct S_uy/S_uu",
                   "-")
        if e.closed_loop is not None:
            c = e.closed_loop
            _with_band(ax_mag, ax_ph, c.frequencies, c.G, np.sqrt(c.var), f"C{2 * k + 1}",
                       f"{e.name}: from the {e.external} S_ry/S_ru", "-")
            good = c.coherence_ru >= 0.9
            ax_mag.semilogx(c.frequencies[good], _db(c.G[good]), ".", color=f"C{2 * k + 1}", ms=4,
                            label=f"{e.name}: γ²_ru ≥ 0.9")
    _label(ax_mag, ax_ph, "G", unit, title or "frequency response of records, bands shaded")
    return fig
