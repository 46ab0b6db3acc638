"""`servofmu tune`'s page: the drive's gains for an identified axis (the tuning and the controller file it writes:
servofmu.tuning.run.tune_files).

The page shows what the tuning weighed: every controller's gains, the linearised loop's sensitivity peak and
margins (nominal and the worst over the corners of the model's 95 % box), the figures on the model (RMS and peak
tracking error, the worst RMS across the uncertainty set, the step's settling, the velocity error at the
reversals) and on the axis when one was co-simulated, the loop's Bode and Nyquist plots with the margins, and
the responses and tracking errors over time.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..model.controller import FILTERS
from ..runtime import utc_now
from .html import escape, figure, number, page, png_bytes, table
from .plots import figure_axes

if TYPE_CHECKING:  # the type only: the page runs no tuning
    from ..tuning.run import Tuning

__all__ = ["tune_text", "tune_json", "tune_html", "plot_loop_bode", "plot_nyquist", "plot_responses"]

LABELS = {"given": "given gains", "rule": "reference rule", "tuned": "tuned (swarm)"}


def _gains(c) -> list[str]:
    kind = FILTERS[int(c["velocity_filter"])]
    detail = {"none": "", "moving-average": f" ({int(c['filter_window'])})",
              "first-order": f" ({1e3 * c['filter_time_constant']:.3g} ms)"}[kind]
    return [number(c["kp_position"], ".4g"), number(c["kp_velocity"], ".5g"), number(c["ki_velocity"], ".5g"),
            kind + detail, number(c["velocity_feedforward"], ".4g"), number(c["mass_feedforward"], ".5g"),
            number(c["friction_feedforward"], ".3g")]


def tune_json(tuning: Tuning) -> dict:
    """One object for scripts: per controller its gains, loop figures and figures on the model (and the axis)."""
    out = {"method": tuning.method, "chosen": tuning.chosen, "max_sensitivity": tuning.options.max_sensitivity,
           "task": tuning.task.label, "compensate": tuning.compensate, "rule_a": tuning.rule_a,
           "seconds": tuning.seconds, "controllers": {}}
    axis = {r.label: r.figures.as_dict() for r in tuning.axis_runs or ()}
    for label, run in tuning.runs.items():
        c = run.controller
        out["controllers"][label] = {
            "gains": {n: c[n] for n in ("kp_position", "kp_velocity", "ki_velocity", "velocity_filter",
                                        "filter_window", "filter_time_constant", "velocity_feedforward",
                                        "mass_feedforward", "friction_feedforward")},
            "loop": {**run.loop.summary(), "worst_sensitivity_peak": run.worst_peak},
            "model": {**run.figures.as_dict(), "worst_rms_error": run.worst_rms},
            **({"axis": axis[label]} if label in axis else {})}
    return out


def tune_text(tuning: Tuning) -> str:
    """A plain-text table of the controllers (loop figures; RMS tracking error on the model and the axis) and a
    line with the chosen controller's improvement."""
    axis = {r.label: r.figures for r in tuning.axis_runs or ()}
    head = f"{'controller':<16}{'Ms':>7}{'Ms box':>8}{'GM dB':>7}{'PM deg':>8}{'RMS model [m]':>15}" \
           f"{'worst RMS [m]':>15}" + (f"{'RMS axis [m]':>14}{'peak axis [m]':>15}" if axis else "")
    lines = [head]
    for label, run in tuning.runs.items():
        s = run.loop.summary()
        line = (f"{label:<16}{s['sensitivity_peak']:>7.3f}{run.worst_peak:>8.3f}{s['gain_margin_db']:>7.2f}"
                f"{s['phase_margin_deg']:>8.1f}{run.figures.rms_error:>15.4e}{run.worst_rms:>15.4e}")
        if label in axis:
            line += f"{axis[label].rms_error:>14.4e}{axis[label].peak_error:>15.4e}"
        lines.append(line)
    figures = axis or {label: run.figures for label, run in tuning.runs.items()}
    where = "on the axis" if axis else "on the model"
    chosen = figures[tuning.chosen].rms_error
    def than(label: str, name: str) -> str:
        ratio = figures[label].rms_error / chosen if chosen > 0 else 1.0  # (no error at all: as good)
        return f"{ratio:.2f}x lower than {name}" if ratio >= 1 else f"{1 / ratio:.2f}x higher than {name}"

    lines.append(f"{tuning.chosen}: RMS tracking error {where} {than('given', 'the given gains')}"
                 + (f", {than('rule', 'the reference rule')}" if tuning.chosen != "rule" else "")
                 + f", at a sensitivity peak of {tuning.runs[tuning.chosen].loop.ms:.3f} "
                 f"(bound {tuning.options.max_sensitivity:g}); {tuning.seconds:.1f} s")
    if figures[tuning.chosen].saturated > 0:  # said, not hidden: the task asks for the limit
        lines.insert(-1, f"note: the {tuning.chosen} gains hold the force at the output limit on "
                         f"{100 * figures[tuning.chosen].saturated:.2f} % of the task's samples {where}")
    return "\n".join(lines)


def plot_loop_bode(tuning: Tuning, ax=None):
    """|L|, phase of L and |S| of every tuning's loop with the crossovers, phase margins and the sensitivity
    bound.  ``ax``: three matplotlib Axes to draw into, else a new Figure.  Returns the Figure."""
    fig, axes = figure_axes(ax, 3, (9, 8.5), sharex=True)
    for i, (label, run) in enumerate(tuning.runs.items()):
        keep = run.loop.omega < 0.98 * run.loop.omega[-1]  # L's zero near z = −1 (the hold) is no figure
        f, resp, color = run.loop.omega[keep] / (2 * np.pi), run.loop.response[keep], f"C{i}"
        phase = np.degrees(np.unwrap(np.angle(resp)))
        phase -= 360.0 * np.ceil(phase[0] / 360.0 - 1e-9) if phase[0] > -180 else 0.0  # start in (−360, 0]
        axes[0].semilogx(f, 20 * np.log10(np.abs(resp)), color=color, label=LABELS[label])
        axes[1].semilogx(f, phase, color=color)
        axes[2].semilogx(f, 20 * np.log10(np.abs(1 / (1 + resp))), color=color)
        if np.isfinite(run.loop.crossover):
            axes[0].axvline(run.loop.crossover / (2 * np.pi), color=color, ls=":", lw=1)
            axes[1].annotate(f"PM {run.loop.phase_margin:.0f}°", (run.loop.crossover / (2 * np.pi), -180 +
                                                                   run.loop.phase_margin), color=color, fontsize=8)
    axes[0].axhline(0, color="k", lw=0.8)
    axes[1].axhline(-180, color="k", lw=0.8)
    axes[2].axhline(20 * np.log10(tuning.options.max_sensitivity), color="k", ls="--", lw=1,
                    label=f"bound Ms = {tuning.options.max_sensitivity:g}")
    axes[0].set_ylabel("|L| [dB]")
    axes[1].set_ylabel("phase of L [deg]")
    axes[2].set_ylabel("|S| [dB]")
    axes[2].set_xlabel("frequency [Hz] (to the Nyquist frequency)")
    axes[0].legend(fontsize=8)
    axes[2].legend(fontsize=8)
    axes[0].set_ylim(-60, 100)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    return fig


def plot_nyquist(tuning: Tuning, ax=None):
    """The loops' Nyquist curves near −1 with the circle of the sensitivity bound.  ``ax``: a matplotlib Axes to
    draw into, else a new Figure.  Returns the Figure."""
    fig, (ax,) = figure_axes(ax, 1, (6.5, 6))
    for i, (label, run) in enumerate(tuning.runs.items()):
        resp = np.where(np.abs(run.loop.response) < 5, run.loop.response, np.nan)  # the part near −1
        ax.plot(resp.real, resp.imag, "-", lw=1.2, color=f"C{i}",
                label=f"{LABELS[label]} (Ms {run.loop.ms:.2f}, GM {run.loop.summary()['gain_margin_db']:.1f} dB)")
    angle = np.linspace(0, 2 * np.pi, 400)
    radius = 1 / tuning.options.max_sensitivity
    ax.plot(-1 + radius * np.cos(angle), radius * np.sin(angle), "k--", lw=1,
            label=f"|1 + L| = 1/{tuning.options.max_sensitivity:g}")
    ax.plot([-1], [0], "k+", ms=12)
    ax.set_xlim(-3, 1.5)
    ax.set_ylim(-3, 1.5)
    ax.set_aspect("equal")
    ax.set_xlabel("Re L")
    ax.set_ylabel("Im L")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    return fig


def plot_responses(tuning: Tuning, ax=None):
    """Tracking and velocity errors on the task and the step response of every tuning (and of the axis when
    co-simulated).  ``ax``: three matplotlib Axes to draw into, else a new Figure.  Returns the Figure."""
    fig, axes = figure_axes(ax, 3, (9, 9))
    axis = {r.label: r for r in tuning.axis_runs or ()}
    for i, (label, run) in enumerate(tuning.runs.items()):
        color = f"C{i}"
        axes[0].plot(tuning.task.time, tuning.task.position - run.position, color=color, lw=1,
                     label=f"{LABELS[label]}, model (RMS {run.figures.rms_error:.2e} m)")
        if label in axis:
            result = axis[label].task_run
            axes[0].plot(result.time, result["reference"] - result["position"], color=color, lw=0.8, ls="--",
                         label=f"{LABELS[label]}, axis (RMS {axis[label].figures.rms_error:.2e} m)")
        axes[1].plot(tuning.task.time, run.v - np.gradient(tuning.task.position, tuning.task.time), color=color,
                     lw=1, label=LABELS[label])
        axes[2].plot(tuning.step.time, run.step_position / tuning.step.position[-1], color=color, lw=1,
                     label=f"{LABELS[label]} (settles in {run.figures.settling_time * 1e3:.0f} ms)")
    axes[0].set_ylabel("tracking error r − x [m]")
    axes[1].set_ylabel("velocity error v − dr/dt [m/s]")
    axes[2].set_ylabel("step response x/h (model)")
    axes[2].axhspan(0.98, 1.02, color="0.9")
    axes[0].set_xlabel("time [s]")
    axes[1].set_xlabel("time [s]")
    axes[2].set_xlabel("time after the step [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    return fig


def _tables(tuning: Tuning) -> list[str]:
    rows = [[LABELS[k], *_gains(r.controller)] for k, r in tuning.runs.items()]
    parts = ["<h2>Gains</h2>", table("gains", ["controller", "kp position [1/s]", "kp velocity [N·s/m]",
                                               "ki velocity [N/m]", "velocity filter", "velocity feed-forward",
                                               "mass feed-forward [kg]", "friction feed-forward"], rows)]
    rows = []
    for label, run in tuning.runs.items():
        s = run.loop.summary()
        rows.append([LABELS[label], number(s["sensitivity_peak"], ".4f"), number(run.worst_peak, ".4f"),
                     number(s["gain_margin_db"], ".2f"), number(s["phase_margin_deg"], ".1f"),
                     number(s["crossover_hz"], ".1f"), number(s["sensitivity_peak_hz"], ".1f")])
    parts += ["<h2>The loop, linearised about motion</h2>",
              table("loop", ["controller", "Ms", "Ms, worst corner of the 95 % box", "gain margin [dB]",
                             "phase margin [deg]", "crossover [Hz]", "Ms at [Hz]"], rows)]
    head = ["controller", "RMS error [m]", "peak error [m]", "settling [ms]", "overshoot [%]",
            "velocity error at reversals [m/s]", "at the output limit [% of samples]"]

    def figures_row(label, f, extra=()):
        return [LABELS[label], number(f.rms_error, ".4e"), number(f.peak_error, ".4e"),
                number(1e3 * f.settling_time, ".0f"), number(100 * f.overshoot, ".2f"),
                number(f.reversal_velocity_error, ".3e"), number(100 * f.saturated, ".2f"), *extra]

    rows = [figures_row(k, r.figures, [number(r.worst_rms, ".4e")]) for k, r in tuning.runs.items()]
    parts += ["<h2>On the identified model</h2>", table("model", [*head, "worst RMS over the box [m]"], rows)]
    if tuning.axis_runs:
        rows = [figures_row(r.label, r.figures) for r in tuning.axis_runs]
        parts += ["<h2>On the axis (co-simulation)</h2>", table("axis", head, rows)]
    return parts


def tune_html(tuning: Tuning, result_source: str, controller_source: str) -> str:
    """The tuning's page (the module's docstring)."""
    o = tuning.options
    what = ("the project's particle swarm, each candidate scored by its worst RMS tracking error over the nominal "
            f"model and {o.draws} random corners of its 95 % box" if tuning.method == "pso" else "the reference rule")
    parts = [f"<h1>Tuning {escape(controller_source)} for {escape(result_source)}</h1>",
             f"<p>Task: {escape(tuning.task.label)} ({tuning.task.time[-1]:g} s). Gains by {escape(what)}, under a "
             f"sensitivity peak of at most {o.max_sensitivity:g} at every corner of the box of G's parameters. "
             f"Reference rule: symmetric optimum for the velocity PI, magnitude optimum for the position P, at "
             f"a = {tuning.rule_a:.3f}. Friction feed-forward: {'on' if tuning.compensate else 'off'}. "
             f"{tuning.seconds:.1f} s.</p>",
             f'<p class="note">{escape(tune_text(tuning).splitlines()[-1])}.</p>',
             *_tables(tuning),
             "<h2>Figures</h2>",
             figure("The loop L broken at the force (discrete, at the controller's sample time): magnitude with the "
                    "crossovers dotted, phase with the phase margins, and the sensitivity |S| against its bound.",
                    png_bytes(plot_loop_bode(tuning)), "Bode plots"),
             figure("Nyquist curves of L near −1 and the circle |1 + L| = 1/Ms of the bound: a curve outside it "
                    "meets the bound.", png_bytes(plot_nyquist(tuning)), "Nyquist plot"),
             figure(f"The tracking error on the task (model solid, axis dashed), the velocity error, and the step "
                    f"of {tuning.step.position[-1]:.3g} m with the feed-forward off (model; the band: ±2 %).",
                    png_bytes(plot_responses(tuning)), "responses"),
             f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>']
    return page(f"Tuning {controller_source}", parts)
