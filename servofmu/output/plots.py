"""Figures of a data file: Bode plot of the first harmonics, time series of records and windows."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode
from ..measurement.datafile import DataFile

__all__ = ["bode_figure", "time_series_figure", "bode_points", "pyplot", "finish_figure", "MAX_PANELS"]

MAX_PANELS = 8


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no screen)."""
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["svg.fonttype"] = "none"  # SVG text as text: smaller, and searchable
    matplotlib.rcParams["svg.hashsalt"] = "servofmu"  # the same figure gives the same SVG
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path, overwrite: bool) -> None:
    path = claim_output(path, output_mode(overwrite))
    buffer = io.BytesIO()
    try:
        fig.savefig(buffer, dpi=110, format=path.suffix.lstrip(".") or "png")
    except ValueError as exc:  # a format matplotlib does not know
        raise UserError(f"{path}: cannot write the figure ({exc})") from exc
    atomic_write(path, buffer.getvalue())


def bode_points(data_file: DataFile) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """label -> (frequencies, H, converged), frequency-sorted: one entry per amplitude, and one for the
    sinusoidal records."""
    curves: dict[str, list] = {}
    for e in data_file.experiments:
        curves.setdefault(f"amplitude {e.amplitude:g} N", []).append((e.frequency, e.H, e.converged))
    for r in data_file.records:
        if r.analysis is not None:
            a = r.analysis
            curves.setdefault(f"records (|U1| ≈ {a.amplitude:.3g} N)", []).append((a.frequency, a.H, a.converged))
    out = {}
    for label, pts in curves.items():
        pts.sort(key=lambda p: p[0])
        out[label] = (np.array([p[0] for p in pts]), np.array([p[1] for p in pts]), np.array([p[2] for p in pts]))
    return out


def bode_figure(data_file: DataFile, path: str | Path, references: dict | None = None, title: str | None = None,
                overwrite: bool = False) -> Path:
    """Bode magnitude and phase of H = V1/U1, one curve per excitation amplitude on one figure, written to
    ``path`` (an existing file only with ``overwrite``).

    ``references``: label -> (frequencies in Hz, complex response), drawn as lines (e.g. the linear G(jω)).
    Experiments that reached no steady state are drawn as open markers.
    """
    curves = bode_points(data_file)
    if not curves:
        raise UserError(f"{data_file.path}: has no first harmonics to plot (no experiments, no sinusoidal records)")
    plt = pyplot()
    fig, (ax_mag, ax_ph) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    for label, (f, h) in (references or {}).items():
        f, h = np.asarray(f, float), np.asarray(h, complex)
        ax_mag.semilogx(f, 20 * np.log10(np.abs(h)), "k--", lw=1, label=label)
        ax_ph.semilogx(f, np.degrees(np.unwrap(np.angle(h))), "k--", lw=1)
    markers = "osD^vP*X"
    for k, (label, (f, h, ok)) in enumerate(curves.items()):
        mag, phase = 20 * np.log10(np.abs(h)), np.degrees(np.unwrap(np.angle(h)))
        color, marker = f"C{k}", markers[k % len(markers)]
        # measured points are markers only: a line between two frequencies would claim values nobody measured
        for part, ax, y in (("magnitude", ax_mag, mag), ("phase", ax_ph, phase)):
            ax.semilogx(f[ok], y[ok], marker, ls="none", color=color, label=label if part == "magnitude" else None,
                        gid=f"measured-{k}-{part}")
            if (~ok).any():
                ax.semilogx(f[~ok], y[~ok], marker, ls="none", mfc="none", color=color,
                            gid=f"measured-{k}-{part}-unsettled")
    if any((~ok).any() for _, _, ok in curves.values()):
        ax_mag.plot([], [], "o", mfc="none", color="gray", label="no steady state (flagged)")
    ax_mag.set_ylabel("|H| = |V1/U1| [dB re 1 m/(N·s)]")
    ax_ph.set_ylabel("phase of H [deg]")
    ax_ph.set_xlabel("frequency [Hz]")
    for ax in (ax_mag, ax_ph):
        ax.grid(True, which="both", alpha=0.4)
    ax_mag.legend(fontsize=8)
    ax_mag.set_title(title or f"{Path(data_file.path).name}: first-harmonic response")
    return finish_figure(plt, fig, path, overwrite)


def time_series_figure(data_file: DataFile, path: str | Path, title: str | None = None,
                       overwrite: bool = False) -> Path:
    """Records: u and v over time, one panel pair per record.  Measurements: the analysed windows of v,
    over the excitation phase, one panel per amplitude.  Written to ``path`` (an existing file only with
    ``overwrite``)."""
    plt = pyplot()
    if data_file.records:
        recs = data_file.records[:MAX_PANELS]
        fig, axes = plt.subplots(2 * len(recs), 1, figsize=(9, 2.6 * 2 * len(recs)), squeeze=False)
        for i, r in enumerate(recs):
            s = r.series
            ax_u, ax_v = axes[2 * i, 0], axes[2 * i + 1, 0]
            ax_u.plot(s.time, s.u, lw=0.8)
            ax_u.set_ylabel("u [N]")
            ax_u.set_title(f"{r.name} ({r.source}, {r.kind} record"
                           + (f", {r.analysis.frequency:.4g} Hz sine)" if r.analysis else ")"))
            ax_v.plot(s.time, s.v, lw=0.8, label="v" if r.kind == "velocity" else "v (estimate from position)")
            if r.analysis is not None:
                a = r.analysis
                ax_v.axvspan(a.window_start, a.window_start + a.window_periods / a.frequency, color="C2", alpha=0.1,
                             label="analysed window")
            ax_v.set_ylabel("v [m/s]")
            ax_v.set_xlabel("time [s]")
            ax_v.legend(fontsize=8, loc="upper right")
    elif data_file.experiments:
        amplitudes = sorted({e.amplitude for e in data_file.experiments}, reverse=True)[:MAX_PANELS]
        fig, axes = plt.subplots(len(amplitudes), 1, figsize=(9, 3.2 * len(amplitudes)), squeeze=False)
        for ax, m in zip(axes[:, 0], amplitudes):
            for e in sorted((e for e in data_file.experiments if e.amplitude == m), key=lambda e: e.frequency):
                phase = (e.window.time - e.window_start) * e.frequency
                ax.plot(phase, e.window.v, lw=1, label=f"{e.frequency:g} Hz" + ("" if e.converged else " (no steady state)"))
            ax.set_title(f"amplitude {m:g} N: v over the analysed window")
            ax.set_ylabel("v [m/s]")
            ax.set_xlabel("time × frequency [periods]")
            ax.grid(True, alpha=0.4)
            ax.legend(fontsize=7, ncol=3)
    else:
        raise UserError(f"{data_file.path}: has no experiments or records to plot")
    if title:
        fig.suptitle(title)
    return finish_figure(plt, fig, path, overwrite)


def finish_figure(plt, fig, path, overwrite: bool) -> Path:
    """Lay out, save (atomically; an existing ``path`` only with ``overwrite``) and close a figure."""
    fig.tight_layout()
    try:
        _save(fig, Path(path), overwrite)
    finally:
        plt.close(fig)
    return Path(path)
