"""The report's figures: measured against identified responses (Bode, records), the friction curve and the swarm's
convergence, each as (caption, image bytes) for servofmu.output.report's page; the results of a comparison are
overlaid on the same axes (one figure per view, not one per method)."""
from __future__ import annotations

import io
from dataclasses import replace
from typing import Sequence

import numpy as np

from ..identification.criterion import SineData
from ..measurement.datafile import DataFile
from ..model.plant import Plant
from .figures import bode, friction_curve
from .html import DPI, png_bytes
from .plots import MAX_PANELS, SAVE_RC, figure_axes, plot_bode_points
from .report_entries import CURVE_POINTS, Entry, model_sine
from .validation_report import validation_figure

__all__ = ["bode_figures", "records_figure", "friction_figure", "convergence_figure", "bla_report_figure",
           "plot_convergence"]


# ---------------------------------------------------------------------------
# Figures (PNG or SVG bytes); several entries are overlaid on the same axes
# ---------------------------------------------------------------------------
def _svg(fig) -> bytes:
    """A figure as SVG: vector lines, and the measured points as marker elements a reader (or a test) can find
    in the markup."""
    import matplotlib

    if fig.get_layout_engine() is None:
        fig.tight_layout()
    buffer = io.BytesIO()
    with matplotlib.rc_context(SAVE_RC):
        fig.savefig(buffer, format="svg", dpi=DPI)
    return buffer.getvalue()


def _fitted_data_file(data_file: DataFile, noisy: bool) -> DataFile:
    """The data as fitted: the noisy first harmonics when the file has noise."""
    if not noisy:
        return data_file
    return replace(data_file, experiments=tuple(replace(e, H=e.H_noisy) for e in data_file.experiments
                                              if e.H_noisy is not None))


def _segments(label: str, f: np.ndarray, H: np.ndarray, ok: np.ndarray) -> dict:
    """The runs of consecutive frequencies where ``ok`` as separate curves, so that where the model reaches no
    steady state the line has a gap (one NaN would spoil the unwrapped phase of the whole curve).  Only the
    first carries the label: matplotlib leaves labels that start with "_" out of the legend."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
    runs = [(a, b) for a, b in zip(edges[::2], edges[1::2])]
    return {(label if i == 0 else f"_{label} {i}"): (f[a:b], H[a:b]) for i, (a, b) in enumerate(runs)}


def _who(entries: Sequence[Entry]) -> str:
    return entries[0].label if len(entries) == 1 else ", ".join(e.label for e in entries)


def bode_figures(entries: Sequence[Entry], data_file: DataFile, data: SineData) -> list[tuple[str, bytes]]:
    """(caption, SVG): measured against identified response at each magnitude (every entry's model overlaid),
    then all magnitudes against every identified linear G(jω) with its 95 % band."""
    fitted = _fitted_data_file(data_file, data.noisy)
    f_lo, f_hi = data.frequencies.min(), data.frequencies.max()
    grid = np.unique(np.concatenate([np.geomspace(f_lo, f_hi, CURVE_POINTS), data.frequencies]))
    several = len(entries) > 1
    out = []
    for m in sorted(set(data.amplitudes.tolist()), reverse=True):
        references, gaps = {}, []
        for e in entries:
            H, _, ok = model_sine(e.result.plant, np.full(grid.size, m), grid)
            references.update(_segments(f"{e.label if several else 'identified model'} at {m:g} N", grid, H, ok))
            if not ok.all():
                gaps.append(f"{e.label}: {np.sum(~ok)}" if several else str(np.sum(~ok)))
        one = replace(fitted, experiments=tuple(e for e in fitted.experiments if e.amplitude == m), records=())
        title = f"{_who(entries)}: measured and identified response at {m:g} N"
        note = "" if not gaps else f" The identified model reaches no steady state at {'; '.join(gaps)} of the " \
                                   f"{grid.size} frequencies (gaps)."
        lines = "the lines the identified plants" if several else "the dashed line the identified plant"
        out.append((f"{title}: markers are the measured first harmonics H = V1/U1 (one per experiment, not "
                    f"joined), {lines} simulated to steady state at {grid.size} frequencies.{note}",
                    _svg(plot_bode_points(one, references, title))))
    wide = np.geomspace(f_lo / 2, f_hi * 2, 200)
    title = f"{_who(entries)}: every magnitude against the identified G(jω)"
    fig = bode({e.label: e.result for e in entries}, data=fitted, frequencies=wide)
    fig.axes[0].set_title(title)
    out.append((f"{title}: markers are the measured first harmonics at each magnitude (grey, one shape per "
                "magnitude), the lines the identified G(jω) without friction with its 95 % band from the "
                "parameters' covariance (shaded); the spread between magnitudes is the friction's effect.", _svg(fig)))
    return out


def records_figure(entries: Sequence[Entry]) -> tuple[str, bytes]:
    """Measured against simulated output of every record the entries were fitted to (overlaid), with the residual
    correlations."""
    n = len(entries[0].records.records)
    more = f" (the first {MAX_PANELS} of {n} records)" if n > MAX_PANELS else ""
    models = "the identified models" if len(entries) > 1 else "the identified model"
    return (f"{_who(entries)}: measured output and {models} driven by the measured input{more}, with the "
            "residuals' correlations and their joint 99 % bounds.",
            validation_figure([(e.label, e.records) for e in entries], "records"))


def bla_report_figure(entries: Sequence[Entry], data_file: DataFile) -> tuple[str, bytes]:
    """Broadband data: the BLA of every level with its ±2σ band, each identified plant's linear part (friction left
    out) and the frequency-domain fit's G over it."""
    from ..broadband.frf import frf_of_file
    from ..identification.frequency_fit import linear_response
    from .bla_plots import plot_bla

    data, levels = frf_of_file(data_file.path)
    f = np.unique(np.concatenate([b.frequencies for _, b in levels]))
    models = []
    for e in entries:
        result, who = e.result, f" ({e.label})" if len(entries) > 1 else ""
        models.append((f"identified plant without friction{who}", f,
                       linear_response(result.structure, result.plant.parameter_vector(), f, data.plan.rate)))
        fd = result.provenance.get("frequency_fit")
        if fd:
            vector, names = result.structure.parameter_vector(), result.structure.parameter_names()
            for n, v in zip(fd["names"], fd["theta"]):
                vector[names.index(n)] = v
            models.append((f"G fitted to the BLA (frequency domain){who}", f,
                           linear_response(result.structure, vector, f, data.plan.rate)))
    png = png_bytes(plot_bla(levels, f"{_who(entries)}: BLA, ±2σ", models=tuple(models)))
    return (f"{_who(entries)}: the best linear approximation at each level (excited lines, ±2σ shaded; σ of the "
            "noise dotted, of the nonlinear distortions dashed), the identified plant's linear part and the G fitted "
            "to the BLA; with friction the BLA lies off G, more so at the lower level.", png)


def friction_figure(entries: Sequence[Entry], truth: Plant | None, v_max: float) -> tuple[str, bytes]:
    """Friction force against velocity at constant velocity: each identified plant, and the true one if known.
    Left: every velocity the data reached; right: near v = 0, where the Stribeck effect and the smoothing live."""
    plants = [e.result.plant for e in entries] + ([truth] if truth is not None else [])
    stribeck = [p.friction.vs for p in plants if p.friction.vs]
    v_zoom = min(v_max, 5 * max(stribeck) if stribeck else v_max / 20)
    fig, axes = figure_axes(None, 2, (10, 4.5), nrows=1, ncols=2)
    friction_curve([e.result for e in entries], ax=axes, labels=[f"identified ({e.label})" for e in entries],
                   v_max=v_max, truth=truth)
    axes[1].set_xlim(-v_zoom, v_zoom)
    for ax, title in zip(axes, ("every velocity the data reached", f"near zero: |v| ≤ {v_zoom:.3g} m/s")):
        ax.set_title(title, fontsize=10)
    fig.suptitle("friction against velocity (steady sliding)")
    png = png_bytes(fig)
    return ("Friction force against velocity at constant velocity, over the velocities the data reached "
            f"(|v| ≤ {v_max:.3g} m/s)" + (", identified against true" if truth is not None else "") + ".", png)


def plot_convergence(entries: Sequence[Entry], ax=None):
    """The swarm's best fitness per iteration of every entry, with each stage's final fitness as a level.
    ``ax``: a matplotlib Axes to draw into, else a new Figure.  Returns the Figure."""
    fig, (ax,) = figure_axes(ax, 1, (8, 4.5))
    for i, e in enumerate(entries):
        h = e.result.history
        if h.size:
            ax.semilogy(np.arange(h.size), h, "-o", ms=3, color=f"C{i}", label=f"PSO best ({e.label})")
        for j, stage in enumerate(e.result.stages):
            if stage.name != "pso" and np.isfinite(stage.fitness) and stage.fitness > 0:
                ax.axhline(stage.fitness, color=f"C{i}", ls=(":", "-.", "--")[j % 3], lw=1,
                           label=f"after {stage.name} ({e.label}): {stage.fitness:.3g}")
    ax.set_xlabel("PSO iteration (0: the initial swarm)")
    ax.set_ylabel("fitness (RMS relative output error)")
    ax.set_title("PSO convergence")
    ax.grid(True, which="both", alpha=0.4)
    ax.legend(fontsize=8)
    return fig


def convergence_figure(entries: Sequence[Entry]) -> tuple[str, bytes] | None:
    """PNG of :func:`plot_convergence`; None when no entry has a search history."""
    if not any(e.result.history.size for e in entries):
        return None
    return "Best fitness of the swarm at each iteration; lines mark the fitness after the other stages.", \
        png_bytes(plot_convergence(entries))
