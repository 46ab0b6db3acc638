"""`servofmu compensate`'s page: what feeding forward the identified friction buys on an axis (docs/control.md; the
runs: servofmu.control.compensation.compensate_files).

The axis (an SSP archive) runs without friction feed-forward, with the identified friction, and with the true
friction when a plant file of the truth is given; the table gives the tracking error (RMS, peak) and the
velocity's harmonic distortion of each run, the page adds the friction force against velocity (identified curve,
truth, points reconstructed from the uncompensated run) and the tracking error over time.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..model.friction import steady_friction, viscous_damping
from ..model.plant import Plant
from ..runtime import utc_now
from .html import escape, figure, number, page, png_bytes, table
from .plots import figure_axes

if TYPE_CHECKING:  # the types only: the page runs nothing
    from ..control.compensation import Compensation, TrackingRun

__all__ = ["compensation_json", "compensation_text", "compensation_html", "compensation_page",
           "plot_compensation_friction", "plot_tracking_error", "reconstructed_friction"]


def compensation_json(runs: list[TrackingRun]) -> dict:
    """One object for scripts: per run the tracking error and distortion, and the improvement ratios."""
    out = {"runs": {r.label: {"rms_error": r.rms_error, "peak_error": r.peak_error,
                              "velocity_distortion": r.distortion} for r in runs},
           "rms_reduction": runs[0].rms_error / runs[1].rms_error}
    if len(runs) > 2:
        out["identified_over_true"] = runs[1].rms_error / runs[2].rms_error
    return out


def compensation_text(runs: list[TrackingRun]) -> str:
    """A plain-text table of the runs (RMS and peak tracking error in m, velocity distortion) and a line with the
    RMS error's reduction by the compensation."""
    lines = [f"{'run':<22}{'RMS error [m]':>16}{'peak error [m]':>16}{'v distortion':>14}"]
    lines += [f"{r.label:<22}{r.rms_error:>16.4e}{r.peak_error:>16.4e}{r.distortion:>14.3e}" for r in runs]
    summary = compensation_json(runs)
    lines.append(f"compensation with the identified friction lowers the RMS tracking error "
                 f"{summary['rms_reduction']:.1f}x" + (f"; {summary['identified_over_true']:.3f} times the error "
                                                       "with the true friction" if len(runs) > 2 else ""))
    return "\n".join(lines)


def reconstructed_friction(run: TrackingRun, plant: Plant) -> tuple[np.ndarray, np.ndarray] | None:
    """(velocity, friction force) points reconstructed from a run through the identified linear part, where G is
    first order without zeros: G = K/(s − p) is a mass 1/K, so everything but inertia, u − (dv/dt)/K, is friction
    — the viscous part b·v = −p·v/K included, as in the feed-forward.  The force held on [t_i, t_i+1) is paired
    with the mean velocity and the velocity difference of that interval.  None for other G."""
    if plant.order != 1 or plant.zeros:
        return None
    t, u, v = run.result.time, run.result["force"], run.result["v"]
    return (v[:-1] + v[1:]) / 2, u[:-1] - np.diff(v) / np.diff(t) / plant.numerator_gain()


def plot_compensation_friction(runs: list[TrackingRun], identified: Plant, truth: Plant | None = None, ax=None):
    """Friction force against velocity: the identified (and true) curve with the viscous part, and the points
    reconstructed from the uncompensated run.  ``ax``: a matplotlib Axes to draw into, else a new Figure.
    Returns the Figure."""
    v_max = 1.1 * float(np.max(np.abs(runs[0].result["v"]))) or 1.0
    v = np.linspace(-v_max, v_max, 2000)
    fig, (ax,) = figure_axes(ax, 1, (8, 4.5))
    points = reconstructed_friction(runs[0], identified)
    if points is not None:
        ax.plot(points[0], points[1], ".", ms=1.5, color="0.6", label="reconstructed from the uncompensated run")
    for plant, label, style in ((identified, "identified", "C0-"), (truth, "true", "k--")):
        if plant is not None:
            ax.plot(v, steady_friction(plant, v) + viscous_damping(plant) * v, style, lw=1.5, label=label)
    ax.set_xlabel("velocity v [m/s]")
    ax.set_ylabel("friction force [N]")
    ax.grid(True, alpha=0.4)
    ax.legend(fontsize=8)
    return fig


def plot_tracking_error(runs: list[TrackingRun], ax=None):
    """The tracking error of every run over time, and the reference beneath.  ``ax``: two matplotlib Axes to draw
    into, else a new Figure.  Returns the Figure."""
    fig, axes = figure_axes(ax, 2, (9, 5.5), sharex=True)
    for i, r in enumerate(runs):
        axes[0].plot(r.result.time, r.error, lw=1, color=f"C{i}", label=f"{r.label} (RMS {r.rms_error:.2e} m)")
    axes[0].set_ylabel("tracking error r − x [m]")
    axes[0].legend(fontsize=8)
    axes[1].plot(runs[0].result.time, runs[0].result["reference"], "k", lw=1)
    axes[1].set_ylabel("reference [m]")
    axes[1].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.4)
    return fig


def compensation_html(runs: list[TrackingRun], identified: Plant, truth: Plant | None, source: str) -> str:
    """The compensation page: the runs' table, the tracking errors over time and the identified (and true)
    friction curves, as one self-contained HTML page about ``source``."""
    rows = [[r.label, number(r.rms_error, ".4e"), number(r.peak_error, ".4e"), number(r.distortion, ".3e")]
            for r in runs]
    parts = [f"<h1>Friction compensation on {escape(source)}</h1>",
             "<p>The axis co-simulated without friction feed-forward, with the identified friction and (when known) "
             "the true friction, fed forward at the reference velocity.</p>",
             table("compensation", ["run", "RMS tracking error [m]", "peak tracking error [m]",
                                    "velocity distortion"], rows),
             f'<p class="note">{escape(compensation_text(runs).splitlines()[-1])}.</p>',
             figure("Friction force against velocity: the identified curve, the truth, and points reconstructed from "
                    "the uncompensated run through the identified linear part.",
                    png_bytes(plot_compensation_friction(runs, identified, truth)), "friction"),
             figure("Tracking error over time.", png_bytes(plot_tracking_error(runs)), "tracking error"),
             f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>']
    return page(f"Friction compensation on {source}", parts)


def compensation_page(compensation: Compensation) -> str:
    """:func:`compensation_html` of `servofmu compensate`'s runs (servofmu.control.compensation.compensate_files)."""
    c = compensation
    return compensation_html(c.runs, c.identified, c.truth, c.axis)
