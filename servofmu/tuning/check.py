"""Tuned gains checked on the axis: the axis archive rebuilt with each controller and co-simulated on the task and
on a step, and the figures a drive's commissioning looks at.

The axis (an SSP archive of `servofmu system`) brings its plant FMU — the true plant when the user has it — and
its drive's runtime: the encoder and any actuator noise.  Each controller's settings (gains, filter,
feed-forward, output limit) replace the archive's controller parameters; the task and the step are new
reference sources in archives rebuilt from the axis's own FMUs.  The same figures are computed on simulations
of the model (servofmu.tuning.run), so that what the model promised and what the axis does stand side by side:

- RMS and peak tracking error r − x on the task;
- the step's settling time (the last time |r − x| leaves ±2 % of the step) and overshoot;
- the velocity error at the reversals: the largest |v − dr/dt| within ±50 ms of each reversal of the reference
  velocity — the stick-slip ripple friction leaves there;
- the share of the task's samples whose force command is at the output limit (a tuning that saturates on its task
  says so).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING
from pathlib import Path

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError
from ..model.controller import ControllerSpec, missing_parameter
from ..runtime import temporary_folder
from .task import Task

if TYPE_CHECKING:  # the co-simulation (FMPy, CasADi) is imported by the check itself, not by the names
    from ..control.cosim import CosimResult

__all__ = ["Figures", "AxisRun", "tracking_figures", "settling", "reversal_velocity_error", "axis_drive",
           "step_drive", "check_on_axis", "STEP_BAND", "REVERSAL_WINDOW"]

STEP_BAND = 0.02  # settled: within ±2 % of the step
REVERSAL_WINDOW = 0.05  # s either side of a reversal of the reference velocity
RUNTIME = ("encoder_resolution", "force_noise", "noise_seed")  # the axis's own, kept in every run


@dataclass(frozen=True)
class Figures:
    """The figures of one controller on one plant (m, s, m/s): RMS and peak tracking error on the task, the
    step's settling time and overshoot (a share of the step), the largest velocity error at the reversals, the
    share of the task's samples at the output limit."""

    rms_error: float
    peak_error: float
    settling_time: float
    overshoot: float
    reversal_velocity_error: float
    saturated: float

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return Shown(type(self).__name__, "of a controller on a task", (
            figure("RMS error", self.rms_error, "m", ".3g"), figure("peak error", self.peak_error, "m", ".3g"),
            figure("settling time", self.settling_time, "s", ".3g"),
            figure("overshoot", 100 * self.overshoot, "%", ".3g"),
            figure("reversal velocity error", self.reversal_velocity_error, "m/s", ".3g"),
            figure("saturated", 100 * self.saturated, "%", ".3g")))

    def as_dict(self) -> dict:
        """The figures by name."""
        return dict(self.__dict__)


def settling(time: np.ndarray, reference: np.ndarray, position: np.ndarray, band: float = STEP_BAND):
    """(settling time, overshoot) of a step of the reference from 0 at its first non-zero sample: the time after
    the step of the last sample outside ±band·height (inf when the run ends outside it), and the largest
    excursion past the height as a share of it."""
    start = int(np.argmax(reference != 0))
    height = reference[-1]
    outside = np.flatnonzero(np.abs(reference[start:] - position[start:]) > band * abs(height))
    if outside.size == 0:
        settle = 0.0
    elif outside[-1] == reference.size - start - 1:
        settle = float("inf")
    else:
        settle = float(time[start + outside[-1] + 1] - time[start])
    overshoot = max(0.0, float(np.max((position[start:] - height) * np.sign(height)) / abs(height)))
    return settle, overshoot


def reversal_velocity_error(time: np.ndarray, reference: np.ndarray, v: np.ndarray,
                            window: float = REVERSAL_WINDOW) -> float:
    """The largest |v − dr/dt| within ±``window`` s of each reversal of the reference velocity (dr/dt by central
    differences); NaN for a reference that does not reverse."""
    v_ref = np.gradient(reference, time)
    moving = np.flatnonzero(np.abs(v_ref) > 1e-3 * np.max(np.abs(v_ref)))
    signs = np.sign(v_ref[moving])
    flips = moving[np.flatnonzero(signs[1:] != signs[:-1]) + 1]
    if flips.size == 0:
        return float("nan")
    near = np.min(np.abs(time[:, None] - time[flips][None, :]), axis=1) <= window
    return float(np.max(np.abs(v - v_ref)[near]))


def tracking_figures(task: Task, position: np.ndarray, v: np.ndarray, command: np.ndarray, limit: float,
                     step: Task, step_position: np.ndarray) -> Figures:
    """The figures of a run on the task (``position``, ``v`` and the force ``command`` at its samples, the output
    ``limit``) and one on the step."""
    error = task.position - position
    settle, overshoot = settling(step.time, step.position, step_position)
    return Figures(float(np.sqrt(np.mean(error ** 2))), float(np.max(np.abs(error))), settle, overshoot,
                   reversal_velocity_error(task.time, task.position, v),
                   float(np.mean(np.abs(command) >= limit * (1 - 1e-12))))


def step_drive(controller: ControllerSpec) -> ControllerSpec:
    """The controller as it runs the step: feed-forward of velocity and mass off, so that the step shows the
    settling of the feedback loops themselves (a step's reference velocity and acceleration are one sample's
    spikes that the feed-forward would turn into a saturated kick)."""
    return controller.with_values(velocity_feedforward=0.0, mass_feedforward=0.0)


def axis_drive(axis: dict, settings: ControllerSpec, source: str) -> ControllerSpec:
    """The controller run on the axis: ``settings``' values with the axis's runtime (encoder, actuator noise and
    its seed) from its parameter set ``axis``; an axis sampled otherwise than the controller is refused."""
    missing = missing_parameter(axis)
    if missing:
        raise UserError(f"{source}: the controller's parameter set has no {missing!r}")
    for name in ("sample_time", "delay"):
        if abs(axis[name] - settings[name]) > 1e-12 * abs(settings[name]):
            raise UserError(f"{source}: its drive has {name} = {axis[name]:g}, the controller {settings.source} "
                            f"{settings[name]:g}: not the axis of this controller")
    return settings.with_values(**{name: axis[name] for name in RUNTIME})


@dataclass(frozen=True)
class AxisRun:
    """One controller co-simulated on the axis: its label, the run on the task, the run on the step, and the
    figures of both."""

    label: str
    task_run: CosimResult
    step_run: CosimResult
    figures: Figures


def check_on_axis(ssp: str | Path, controllers: dict[str, ControllerSpec], task: Task, step: Task,
                  engine: str = "libcosim") -> list[AxisRun]:
    """Co-simulate every controller (label → settings) on the axis archive ``ssp``, on the task and on the step,
    in archives rebuilt from the axis's FMUs with those references."""
    from ..control.compensation import run_variant
    from ..control.system import read_system, write_system

    runs = []
    with temporary_folder("tune") as tmp:
        system = read_system(ssp, Path(tmp) / "axis")
        drives = {label: axis_drive(system.controller, c, str(ssp)) for label, c in controllers.items()}
        first = next(iter(drives.values()))
        archives = {}
        for name, reference in (("task", task), ("step", step)):
            archives[name] = write_system(system.fmu("plant"), system.fmu("controller"),
                                          (reference.time, reference.position), Path(tmp) / f"{name}.ssp",
                                          controller=first, overwrite=True)
        for label, drive in drives.items():
            on_task = run_variant(archives["task"], drive, label, engine).result
            on_step = run_variant(archives["step"], step_drive(drive), label, engine).result
            figures = tracking_figures(Task(on_task.time, on_task["reference"], task.label), on_task["position"],
                                       on_task["v"], on_task["force_command"], drive["force_limit"],
                                       Task(on_step.time, on_step["reference"], step.label), on_step["position"])
            runs.append(AxisRun(label, on_task, on_step, figures))
    return runs
