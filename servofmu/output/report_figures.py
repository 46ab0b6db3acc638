"""The report's figures: measured against identified responses (Bode, records), the friction curve and the swarm's
convergence, each as (caption, image bytes) for servofmu.output.report's page."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Sequence

import numpy as np

from ..identification.criterion import SineData
from ..measurement.datafile import DataFile
from ..model.friction import steady_friction
from ..model.plant import Plant
from ..runtime import temporary_folder
from .html import png_bytes
from .plots import MAX_PANELS, bode_figure, pyplot
from .report_entries import CURVE_POINTS, FRICTION_POINTS, Entry, model_sine
from .validation_report import validation_figure

__all__ = ["bode_figures", "records_figure", "friction_figure", "convergence_figure", "bla_report_figure"]


# ---------------------------------------------------------------------------
# Figures (PNG bytes)
# ---------------------------------------------------------------------------
def _bode_svg(data_file: DataFile, references: dict, title: str) -> bytes:
    """A Bode figure (servofmu.output.plots.bode_figure) as SVG: vector lines, and the measured points as
    marker elements a reader (or a test) can find in the markup."""
    with temporary_folder("figure") as tmp:
        path = bode_figure(data_file, Path(tmp) / "bode.svg", references=references, title=title)
        return path.read_bytes()


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


def bode_figures(entry: Entry, data_file: DataFile, data: SineData) -> list[tuple[str, bytes]]:
    """(caption, PNG): measured against identified response at each magnitude, then all magnitudes against the
    identified linear G(jω)."""
    plant = entry.result.plant
    fitted = _fitted_data_file(data_file, data.noisy)
    f_lo, f_hi = data.frequencies.min(), data.frequencies.max()
    grid = np.unique(np.concatenate([np.geomspace(f_lo, f_hi, CURVE_POINTS), data.frequencies]))
    out = []
    for m in sorted(set(data.amplitudes.tolist()), reverse=True):
        H, _, ok = model_sine(plant, np.full(grid.size, m), grid)
        one = replace(fitted, experiments=tuple(e for e in fitted.experiments if e.amplitude == m), records=())
        title = f"{entry.label}: measured and identified response at {m:g} N"
        png = _bode_svg(one, _segments(f"identified model at {m:g} N", grid, H, ok), title)
        note = "" if ok.all() else f" The identified model reaches no steady state at {np.sum(~ok)} of the " \
                                   f"{grid.size} frequencies (gaps)."
        out.append((f"{title}: markers are the measured first harmonics H = V1/U1 (one per experiment, not "
                     f"joined), the dashed line the identified plant simulated to steady state at {grid.size} "
                     f"frequencies.{note}", png))
    wide = np.geomspace(f_lo / 2, f_hi * 2, 200)
    title = f"{entry.label}: every magnitude against the identified G(jω)"
    png = _bode_svg(fitted, {"identified linear G(jω), no friction": (wide, plant.frequency_response(2 * np.pi * wide))},
                    title)
    out.append((f"{title}: markers are the measured first harmonics at each magnitude, the dashed line the "
                "identified G(jω) without friction; the spread between magnitudes is the friction's effect.", png))
    return out


def records_figure(entry: Entry) -> tuple[str, bytes]:
    """Measured against simulated output of every record it was fitted to, with the residual correlations."""
    n = len(entry.records.records)
    more = f" (the first {MAX_PANELS} of {n} records)" if n > MAX_PANELS else ""
    return (f"{entry.label}: measured output and the identified model driven by the measured input{more}, with the "
            "residuals' correlations and their joint 99 % bounds.", validation_figure(entry.records, "records"))


def bla_report_figure(entry: Entry, data_file: DataFile) -> tuple[str, bytes]:
    """Broadband data: the BLA of every level with its ±2σ band, the identified plant's linear part (friction left
    out) and the frequency-domain fit's G over it."""
    from ..broadband.frf import frf_of_file
    from ..identification.frequency_fit import linear_response
    from .bla_plots import bla_figure

    data, levels = frf_of_file(data_file.path)
    f = np.unique(np.concatenate([b.frequencies for _, b in levels]))
    result = entry.result
    models = [("identified plant without friction", f, linear_response(result.structure,
                                                                         result.plant.parameter_vector(), f,
                                                                         data.plan.rate))]
    fd = result.provenance.get("frequency_fit")
    if fd:
        vector, names = result.structure.parameter_vector(), result.structure.parameter_names()
        for n, v in zip(fd["names"], fd["theta"]):
            vector[names.index(n)] = v
        models.append(("G fitted to the BLA (frequency domain)", f,
                       linear_response(result.structure, vector, f, data.plan.rate)))
    with temporary_folder("figure") as tmp:
        png = bla_figure(levels, Path(tmp) / "bla.png", f"{entry.label}: BLA, ±2σ", models=tuple(models)).read_bytes()
    return (f"{entry.label}: the best linear approximation at each level (excited lines, ±2σ shaded; σ of the noise "
            "dotted, of the nonlinear distortions dashed), the identified plant's linear part and the G fitted to "
            "the BLA; with friction the BLA lies off G, more so at the lower level.", png)


def friction_figure(entries: Sequence[Entry], truth: Plant | None, v_max: float) -> tuple[str, bytes]:
    """Friction force against velocity at constant velocity: each identified plant, and the true one if known.
    Left: every velocity the data reached; right: near v = 0, where the Stribeck effect and the smoothing live."""
    half = np.geomspace(v_max * 1e-4, v_max, FRICTION_POINTS // 2)
    v = np.concatenate([-half[::-1], half])
    plants = [e.result.plant for e in entries] + ([truth] if truth is not None else [])
    stribeck = [p.friction.vs for p in plants if p.friction.vs]
    v_zoom = min(v_max, 5 * max(stribeck) if stribeck else v_max / 20)
    curves = [(f"identified ({e.label})", e.result.plant, "--" if truth is not None else "-", f"C{i}", 1.5)
              for i, e in enumerate(entries)]
    if truth is not None:
        curves.insert(0, (f"true ({truth.name})", truth, "-", "0.6", 4))
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for label, plant, style, color, width in curves:
        force = steady_friction(plant, v)
        for ax in axes:
            ax.plot(v, force, style, color=color, lw=width, label=label)
    axes[1].set_xlim(-v_zoom, v_zoom)
    for ax, title in zip(axes, ("every velocity the data reached", f"near zero: |v| ≤ {v_zoom:.3g} m/s")):
        ax.axhline(0, color="k", lw=0.5)
        ax.axvline(0, color="k", lw=0.5)
        ax.set_xlabel("velocity v [m/s]")
        ax.set_title(title, fontsize=10)
        ax.grid(True, alpha=0.4)
    axes[0].set_ylabel("friction force F(v) [N]")
    axes[0].legend(fontsize=8)
    fig.suptitle("friction against velocity (steady sliding)")
    png = png_bytes(fig)
    return ("Friction force against velocity at constant velocity, over the velocities the data reached "
            f"(|v| ≤ {v_max:.3g} m/s)" + (", identified against true" if truth is not None else "") + ".", png)


def convergence_figure(entries: Sequence[Entry]) -> tuple[str, bytes] | None:
    """The swarm's best fitness per iteration, with each stage's final fitness as a level."""
    if not any(e.result.history.size for e in entries):
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
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
    png = png_bytes(fig)
    return "Best fitness of the swarm at each iteration; lines mark the fitness after the other stages.", png
