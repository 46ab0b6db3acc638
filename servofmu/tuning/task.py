"""The motion a drive is tuned for: a reference position at every controller sample, from rest at 0.

A task is either a reference file (CSV with columns time and position, as `servofmu system` reads) or a reversing
stroke: x(t) = (M/2)·(1 − cos ωt) with peak speed V = M·ω/2, two periods long.  Before any tuning the task is
checked against the drive: one sample per controller sample, and the force the model needs to follow it
(mass·acceleration + the friction and viscous forces at the reference velocity) within the output limit — a
reference that jumps asks for a force far above any limit, and a tuning that hid that would tune for saturation.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError
from ..model.controller import ControllerSpec
from ..model.laws.viscous import viscous_levels
from ..model.plant import Plant

__all__ = ["Task", "stroke_task", "task_from_csv", "load_task", "check_task", "reference_velocity", "step_task",
           "MIN_SAMPLES_PER_PERIOD", "DEFAULT_STROKE", "DEFAULT_SPEED"]

DEFAULT_STROKE, DEFAULT_SPEED = 0.1, 0.15  # m, m/s: the reversing stroke tuned for when no task is given

# A stroke's period spans at least this many controller samples: a discrete loop follows nothing faster than a few
# samples per period, and the tuning's loop and page need a sampled motion to measure errors on
MIN_SAMPLES_PER_PERIOD = 20


@dataclass(frozen=True)
class Task:
    """A reference trajectory: ``time`` (s, one value per controller sample, from 0) and ``position`` (m), named
    by ``label`` in messages and reports."""

    time: np.ndarray
    position: np.ndarray
    label: str

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        duration = float(self.time[-1] - self.time[0]) if self.time.size else 0.0
        return Shown(type(self).__name__, f"{self.label!r}: {self.time.size} samples", (
            figure("duration", duration, "s"), figure("span", self.span if self.time.size else 0.0, "m")))

    @property
    def span(self) -> float:
        """The range of the reference (m)."""
        return float(np.max(self.position) - np.min(self.position))


def reference_velocity(task: Task) -> np.ndarray:
    """The reference velocity as the drive computes it, (r_k − r_k−1)/Ts, 0 at the first sample (m/s)."""
    return np.r_[0.0, np.diff(task.position) / np.diff(task.time)]


def stroke_task(stroke: float, speed: float, sample_time: float) -> Task:
    """The reversing stroke of ``stroke`` m at a peak speed of ``speed`` m/s: (M/2)(1 − cos ωt), ω = 2V/M, over
    two periods (four reversals of the velocity counting the ends), sampled every ``sample_time`` s."""
    if not (np.isfinite(stroke) and stroke > 0):
        raise UserError(f"--stroke must be a positive length in m, not {stroke!r}")
    if not (np.isfinite(speed) and speed > 0):
        raise UserError(f"--speed must be a positive speed in m/s, not {speed!r}")
    omega = 2.0 * speed / stroke
    duration = 2 * 2 * np.pi / omega
    fastest = stroke * np.pi / (MIN_SAMPLES_PER_PERIOD * sample_time)
    if speed > fastest:
        raise UserError(f"--speed {speed:g} m/s: a stroke of {stroke:g} m at that speed reverses every "
                        f"{duration / 4:.3g} s, faster than a loop sampled every {sample_time:g} s can follow (at "
                        f"most {fastest:.4g} m/s over this --stroke, {MIN_SAMPLES_PER_PERIOD} samples a period)")
    if duration / sample_time > 2_000_000:
        raise UserError(f"a stroke of {stroke:g} m at {speed:g} m/s lasts {duration:.3g} s, more than 2e6 controller "
                        "samples; give a higher speed or a shorter stroke")
    t = np.arange(0.0, duration + sample_time / 2, sample_time)
    return Task(t, 0.5 * stroke * (1 - np.cos(omega * t)), f"stroke of {stroke:g} m at {speed:g} m/s")


def step_task(height: float, duration: float, sample_time: float) -> Task:
    """A step of the reference to ``height`` m one sample after the start, held for ``duration`` s."""
    t = np.arange(0.0, duration + sample_time / 2, sample_time)
    return Task(t, np.where(t > 0, height, 0.0), f"step of {height:g} m")


def task_from_csv(path: str | Path, sample_time: float) -> Task:
    """A task from a reference file (columns ``time`` and ``position``), which must hold one row per controller
    sample from time 0 and start at rest at position 0 (as an axis archive needs)."""
    from ..control.fmus import read_reference_csv

    t, r = read_reference_csv(path)
    if t.size < 3:
        raise UserError(f"{path}: a task needs at least three samples")
    steps = np.diff(t)
    if abs(t[0]) > 1e-9 * sample_time or np.max(np.abs(steps - sample_time)) > 1e-6 * sample_time:
        raise UserError(f"{path}: the reference must have one row per controller sample ({sample_time:g} s) from "
                        f"time 0; its rows are {np.median(steps):g} s apart from {t[0]:g} s")
    if r[0] != 0.0:
        raise UserError(f"{path}: the reference must start at rest at position 0 (an axis starts there), not at "
                        f"{r[0]:g} m")
    if not np.any(r):
        raise UserError(f"{path}: column 'position' stays at 0 m throughout: a task that never moves has no tracking "
                        "error to tune for; give --task a motion (or --stroke and --speed)")
    return Task(t, r, str(path))


def load_task(task: str | Path | None, stroke: float | None, speed: float | None, sample_time: float) -> Task:
    """The task from a reference file or a stroke (default: DEFAULT_STROKE at DEFAULT_SPEED); not both."""
    if task is not None and (stroke is not None or speed is not None):
        raise UserError("give a task as --task REF.csv or as --stroke/--speed, not both")
    if task is not None:
        return task_from_csv(task, sample_time)
    return stroke_task(DEFAULT_STROKE if stroke is None else stroke, DEFAULT_SPEED if speed is None else speed,
                       sample_time)


def check_task(task: Task, plant: Plant, controller: ControllerSpec, mass: float) -> float:
    """The largest force (N) the model needs to follow the task (mass·a_ref + friction + viscous force at v_ref,
    with the drive's own difference quotients, + the load's forces at their largest); a task that needs more
    than the output limit is refused, naming the time and force."""
    from ..model.friction import viscous_damping

    v = reference_velocity(task)
    a = np.r_[0.0, np.diff(v) / np.diff(task.time)]
    fr = plant.friction
    breakaway = max(fr.fc_pos, fr.fc_neg, fr.fs_pos or 0.0, fr.fs_neg or 0.0)
    load = plant.load
    fv = max(viscous_levels(fr.values()))
    force = mass * np.abs(a) + (viscous_damping(plant) + fv) * np.abs(v) + breakaway + abs(load.offset or 0.0) \
        + abs(load.stiffness or 0.0) * np.abs(task.position - (load.x0 or 0.0)) + abs(load.ripple_amplitude or 0.0)
    k = int(np.argmax(force))
    limit = controller["force_limit"]
    if force[k] > limit:
        jump = " (the reference jumps there)" if abs(v[k]) * controller.sample_time > 0.01 * max(task.span, 1e-12) \
            else ""
        raise UserError(f"{task.label}: infeasible for the drive: following it needs {force[k]:.4g} N at "
                        f"t = {task.time[k]:g} s{jump}, above the output limit of {limit:g} N")
    return float(force[k])
