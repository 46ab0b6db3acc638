"""Figures of a data file: Bode plot of the first harmonics, time series of records and windows; and the figure
plumbing of servofmu.output: figures are matplotlib Figure objects, never pyplot's, so that drawing leaves the
user's backend and open figures alone; files are written through the Figure itself."""
from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode
from ..measurement.datafile import DataFile

__all__ = ["bode_figure", "time_series_figure", "plot_bode_points", "plot_time_series", "bode_points",
           "figure_axes", "finish_figure", "draw_measured", "time_series_panels", "save_figure", "MAX_PANELS",
           "REFERENCE_STYLES", "SAVE_RC"]

MAX_PANELS = 8
# Lines of references (models) drawn over measured points: the first black dashed as before, then colours the
# measured series (C0, C1, ...) rarely reach.
REFERENCE_STYLES = (("k", "--"), ("C3", "-."), ("C4", ":"), ("C5", "--"), ("C6", "-."), ("C8", ":"), ("C9", "--"),
                    ("C7", "-."))
# Applied while a file is written only (the user's rcParams stay as they are): SVG text as text (smaller,
# searchable) and the same figure gives the same SVG.
SAVE_RC = {"svg.fonttype": "none", "svg.hashsalt": "servofmu"}


def figure_axes(ax, panels: int, figsize: tuple[float, float], **subplots):
    """(figure, axes) to draw on: the given ``ax`` (one Axes, or a sequence of ``panels`` Axes) and its figure, or
    a new matplotlib Figure (no pyplot: the user's backend and figure list are not touched) with ``panels`` Axes
    from ``Figure.subplots(**subplots)``.  ``axes`` is a flat list."""
    if ax is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=figsize, layout="constrained")  # laid out when drawn: inline, savefig alike
        subplots.setdefault("nrows", panels)
        axes = fig.subplots(squeeze=False, **subplots)
        return fig, list(np.asarray(axes).ravel())
    axes = list(np.asarray(ax, dtype=object).ravel()) if isinstance(ax, (Sequence, np.ndarray)) else [ax]
    if len(axes) != panels or not all(hasattr(a, "plot") and hasattr(a, "figure") for a in axes):
        raise UserError(f"ax: this view draws {panels} panel(s): give {panels} matplotlib Axes, got {ax!r}")
    return axes[0].figure, axes


def save_figure(fig, path: str | Path, overwrite: bool = False, dpi: int = 110) -> Path:
    """Write a matplotlib Figure to ``path`` (format from the suffix; atomically; an existing file only with
    ``overwrite``) through the figure's own canvas, with :data:`SAVE_RC` in effect for the write only."""
    import matplotlib

    path = claim_output(Path(path), output_mode(overwrite))
    buffer = io.BytesIO()
    try:
        with matplotlib.rc_context(SAVE_RC):
            fig.savefig(buffer, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    except ValueError as exc:  # a format matplotlib does not know
        raise UserError(f"{path}: cannot write the figure ({exc})") from exc
    atomic_write(path, buffer.getvalue())
    return path


def finish_figure(fig, path, overwrite: bool) -> Path:
    """Lay out (unless it has a layout engine) and save a figure (atomically; an existing ``path`` only with
    ``overwrite``)."""
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    save_figure(fig, Path(path), overwrite)
    return Path(path)


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


def draw_measured(ax_mag, ax_ph, data_file: DataFile, colors: bool = True) -> None:
    """The measured first harmonics as markers (one series per amplitude, never joined: a line between two
    frequencies would claim values nobody measured); open markers where no steady state was reached.  Each
    series' markers are in SVG groups "measured-K-magnitude"/"-phase"; ``colors=False`` draws them in grey."""
    curves = bode_points(data_file)
    if not curves:
        raise UserError(f"{data_file.path}: has no first harmonics to plot (no experiments, no sinusoidal records)")
    markers = "osD^vP*X"
    for k, (label, (f, h, ok)) in enumerate(curves.items()):
        mag, phase = 20 * np.log10(np.abs(h)), np.degrees(np.unwrap(np.angle(h)))
        color, marker = (f"C{k}" if colors else "0.35"), markers[k % len(markers)]
        for part, ax, y in (("magnitude", ax_mag, mag), ("phase", ax_ph, phase)):
            if ax is None:
                continue
            ax.semilogx(f[ok], y[ok], marker, ls="none", color=color, label=label if part == "magnitude" else None,
                        gid=f"measured-{k}-{part}")
            if (~ok).any():
                ax.semilogx(f[~ok], y[~ok], marker, ls="none", mfc="none", color=color,
                            gid=f"measured-{k}-{part}-unsettled")
    if any((~ok).any() for _, _, ok in curves.values()):
        ax_mag.plot([], [], "o", mfc="none", color="gray", label="no steady state (flagged)")


def plot_bode_points(data_file: DataFile, references: dict | None = None, title: str | None = None,
                     ax=None):
    """Bode magnitude and phase of H = V1/U1 of a data file, one marker series per excitation amplitude.

    Parameters
    ----------
    data_file : DataFile
        Measured data (experiments, or sinusoidal records).
    references : dict, optional
        label -> (frequencies in Hz, complex response), drawn as lines (e.g. models); a label starting with "_"
        continues the line before it (same style, no legend entry).
    title : str, optional
        The magnitude panel's title (default: the file's name).
    ax : sequence of two matplotlib Axes, optional
        (magnitude, phase) to draw into; a new Figure when not given.

    Returns
    -------
    matplotlib.figure.Figure
        The figure drawn into.
    """
    fig, (ax_mag, ax_ph) = figure_axes(ax, 2, (8, 7), sharex=True)
    style = -1
    for label, (f, h) in (references or {}).items():
        style += not label.startswith("_")
        color, ls = REFERENCE_STYLES[max(style, 0) % len(REFERENCE_STYLES)]
        f, h = np.asarray(f, float), np.asarray(h, complex)
        ax_mag.semilogx(f, 20 * np.log10(np.abs(h)), color=color, ls=ls, lw=1, label=label)
        ax_ph.semilogx(f, np.degrees(np.unwrap(np.angle(h))), color=color, ls=ls, lw=1)
    draw_measured(ax_mag, ax_ph, data_file)
    ax_mag.set_ylabel("|H| = |V1/U1| [dB re 1 m/(N·s)]")
    ax_ph.set_ylabel("phase of H [deg]")
    ax_ph.set_xlabel("frequency [Hz]")
    for a in (ax_mag, ax_ph):
        a.grid(True, which="both", alpha=0.4)
    ax_mag.legend(fontsize=8)
    ax_mag.set_title(title or f"{Path(data_file.path).name}: first-harmonic response")
    return fig


def bode_figure(data_file: DataFile, path: str | Path, references: dict | None = None, title: str | None = None,
                overwrite: bool = False) -> Path:
    """:func:`plot_bode_points` written to ``path`` (an existing file only with ``overwrite``)."""
    if not bode_points(data_file):
        raise UserError(f"{data_file.path}: has no first harmonics to plot (no experiments, no sinusoidal records)")
    return finish_figure(plot_bode_points(data_file, references, title), path, overwrite)


def _record_panels(axes, recs) -> None:
    for i, r in enumerate(recs):
        s = r.series
        ax_u, ax_v = axes[2 * i], axes[2 * i + 1]
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


def _window_panels(axes, experiments, amplitudes) -> None:
    for ax, m in zip(axes, amplitudes):
        for e in sorted((e for e in experiments if e.amplitude == m), key=lambda e: e.frequency):
            phase = (e.window.time - e.window_start) * e.frequency
            ax.plot(phase, e.window.v, lw=1,
                    label=f"{e.frequency:g} Hz" + ("" if e.converged else " (no steady state)"))
        ax.set_title(f"amplitude {m:g} N: v over the analysed window")
        ax.set_ylabel("v [m/s]")
        ax.set_xlabel("time × frequency [periods]")
        ax.grid(True, alpha=0.4)
        ax.legend(fontsize=7, ncol=3)


def time_series_panels(data_file: DataFile) -> int:
    """The number of panels :func:`plot_time_series` draws for ``data_file``: two per record (u, v) or one per
    amplitude, at most MAX_PANELS records or amplitudes; 0 when there is nothing to draw."""
    if data_file.records:
        return 2 * min(len(data_file.records), MAX_PANELS)
    return min(len({e.amplitude for e in data_file.experiments}), MAX_PANELS)


def plot_time_series(data_file: DataFile, title: str | None = None, ax=None):
    """Records: u and v over time, one panel pair per record.  Measurements: the analysed windows of v over the
    excitation phase, one panel per amplitude (at most MAX_PANELS records or amplitudes).

    Parameters
    ----------
    data_file : DataFile
        The data.
    title : str, optional
        The figure's title (a new figure only).
    ax : sequence of matplotlib Axes, optional
        :func:`time_series_panels` Axes to draw into; a new Figure when not given.

    Returns
    -------
    matplotlib.figure.Figure
    """
    panels = time_series_panels(data_file)
    if not panels:
        raise UserError(f"{data_file.path}: has no experiments or records to plot")
    height = 2.6 if data_file.records else 3.2
    fig, axes = figure_axes(ax, panels, (9, height * panels))
    if data_file.records:
        _record_panels(axes, data_file.records[:MAX_PANELS])
    else:
        amplitudes = sorted({e.amplitude for e in data_file.experiments}, reverse=True)[:MAX_PANELS]
        _window_panels(axes, data_file.experiments, amplitudes)
    if title and ax is None:
        fig.suptitle(title)
    return fig


def time_series_figure(data_file: DataFile, path: str | Path, title: str | None = None,
                       overwrite: bool = False) -> Path:
    """:func:`plot_time_series` written to ``path`` (an existing file only with ``overwrite``)."""
    return finish_figure(plot_time_series(data_file, title), path, overwrite)
