"""`servofmu tune`'s work: the drive's gains for an identified axis, beside its given gains and the reference rule,
each judged on the model (linearised loop, simulated task and step) and, given the axis, on its co-simulation.

The result of identification must be of the axis the controller drives: the controller's gains and mass
feed-forward are read against the identified mass, and a model whose velocity loop they would put beyond the
Nyquist frequency or far below any drive's (or whose mass is 20 times off the feed-forward's) is refused —
tuning a drive on another plant's model writes gains that fit neither.
"""
from __future__ import annotations

import time as clock
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..display import Shown, figure, gain_db, hz, shown_html, shown_repr
from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode
from ..identification.results import Result, read_result
from ..model.controller import ControllerSpec, controller_toml, friction_feedforward, load_controller
from ..runtime import Progress, utc_now
from ..simulation.closed_loop import LoopSimulator
from ..text_digest import with_digest
from .check import AxisRun, Figures, check_on_axis, step_drive, tracking_figures
from .loop import LoopAnalysis, analyse_loop, axis_mass, sensitivity_peak
from .rule import tune_rule
from .search import (TuneOptions, TuneSearch, Uncertainty, determined_intervals, search_gains, tracking_errors,
                     uncertainty_sets)
from .task import Task, check_task, load_task, step_task

__all__ = ["METHODS", "Tuning", "ModelRun", "check_pairing", "tune_axis", "step_for", "tune_files"]

METHODS = ("pso", "rule")
MASS_MISMATCH = 20.0  # a mass feed-forward this many times off the identified mass: another axis


def check_pairing(result: Result, controller: ControllerSpec, source: str) -> float:
    """The identified mass (kg), after checking that the result is of the axis ``controller`` drives (the
    module's docstring): its closed-loop identification, if any, ran with a drive of the same sample time and
    delay; the controller's velocity loop on the identified mass lies between 10⁻⁴ of and the Nyquist
    frequency; its mass feed-forward, if any, within a factor of 20 of the identified mass."""
    mass = axis_mass(result.plant)
    ctrl_file = result.provenance.get("controller_file")
    if ctrl_file:
        try:
            logged = load_controller(ctrl_file)
        except UserError:
            logged = None  # the file has moved: nothing to compare with
        if logged is not None and any(abs(logged[n] - controller[n]) > 1e-12 * abs(controller[n])
                                      for n in ("sample_time", "delay")):
            raise UserError(f"{source}: identified in the loop of {ctrl_file} (sample time {logged.sample_time:g} s, "
                            f"delay {logged['delay']:g}), not of {controller.source}'s drive: a result of another "
                            "axis")
    omega_ts = controller["kp_velocity"] / mass * controller.sample_time
    ff = controller["mass_feedforward"]
    if not 1e-4 <= omega_ts <= np.pi or (ff > 0 and not 1 / MASS_MISMATCH <= ff / mass <= MASS_MISMATCH):
        raise UserError(f"{source}: the identified plant {result.plant.name} (a mass of {mass:.4g} kg) is not the "
                        f"axis of {controller.source} (its velocity gain puts the loop at "
                        f"{omega_ts / controller.sample_time / (2 * np.pi):.3g} Hz on it, its mass feed-forward is "
                        f"{ff:g} kg): a result of another plant")
    return mass


def step_for(task: Task, controllers: list[ControllerSpec]) -> Task:
    """The step the controllers are compared on: 1 % of the task's span, lowered so that no controller's first
    command (kp_velocity·kp_position·height, feed-forward off) exceeds half the output limit; long enough for
    the slowest position loop to settle (10/kp_position, 0.3 to 5 s)."""
    c0 = controllers[0]
    stiffest = max(c["kp_velocity"] * max(c["kp_position"], 1e-12) for c in controllers)
    height = min(0.01 * task.span, 0.5 * c0["force_limit"] / stiffest)
    slowest = min(max(c["kp_position"], 1e-12) for c in controllers)
    return step_task(height, float(np.clip(10.0 / slowest, 0.3, 5.0)), c0.sample_time)


@dataclass(frozen=True)
class ModelRun:
    """A controller on the identified model: its settings, the linearised loop, the largest sensitivity peak over
    the corners of G's 95 % box, the worst RMS tracking error over the uncertainty set (m), the figures on the
    nominal model and its simulated task and step (position, velocity at the samples)."""

    controller: ControllerSpec
    loop: LoopAnalysis
    worst_peak: float
    worst_rms: float
    figures: Figures
    position: np.ndarray
    v: np.ndarray
    step_position: np.ndarray

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        loop = self.loop._shown()
        return Shown(type(self).__name__, f"{self.controller.name!r} on the model", loop.figures + (
            figure("RMS error", self.figures.rms_error, "m", ".3g"),
            figure("worst RMS error", self.worst_rms, "m", ".3g"), figure("worst Ms", self.worst_peak, "", ".3g")))


@dataclass(frozen=True)
class Tuning:
    """What `servofmu tune` found: the model, task and step, the method, every controller's :class:`ModelRun`
    (labels "given", "rule" and, for the swarm, "tuned"), the rule's a, the swarm's search, the axis's runs
    (or None) and the run time (s)."""

    result: Result
    task: Task
    step: Task
    method: str
    options: TuneOptions
    compensate: bool
    runs: dict[str, ModelRun]
    rule_a: float
    search: TuneSearch | None
    axis_runs: list[AxisRun] | None
    seconds: float
    uncertainty: Uncertainty = field(repr=False, default=None)

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        run = self.runs[self.chosen]
        c, loop = run.controller, run.loop
        figures = (figure("kp_position", c["kp_position"], "1/s"), figure("kp_velocity", c["kp_velocity"], "N.s/m"),
                   figure("ki_velocity", c["ki_velocity"], "N/m"), figure("Ms", loop.ms, "", ".3g"),
                   figure("gain margin", gain_db(loop.gain_margin), "dB", ".3g"),
                   figure("phase margin", loop.phase_margin, "deg", ".3g"),
                   figure("crossover", hz(loop.crossover), "Hz", ".3g"),
                   figure("RMS error", run.figures.rms_error, "m", ".3g"))
        table = figures + (figure("Ms, worst corner of the 95 % box", run.worst_peak, "", ".3g"),
                           figure("RMS error, worst of the uncertainty set", run.worst_rms, "m", ".3g"),
                           figure("time", self.seconds, "s", ".3g"))
        notes = tuple(f"{label}: Ms {r.loop.ms:.3g}, gain margin {gain_db(r.loop.gain_margin):.3g} dB, RMS error "
                      f"{r.figures.rms_error:.3g} m" for label, r in self.runs.items() if label != self.chosen)
        head = (f"{self.method} of {self.result.structure.name!r}: {self.chosen} controller of {len(self.runs)}, task "
                f"{self.task.label!r}" + (", checked on the axis" if self.axis_runs else ""))
        return Shown(type(self).__name__, head, figures, table, notes)

    @property
    def chosen(self) -> str:
        """The label of the controller the tuning writes: "tuned" (swarm) or "rule"."""
        return "tuned" if self.method == "pso" else "rule"

    @property
    def controller(self) -> ControllerSpec:
        """The controller the tuning writes."""
        return self.runs[self.chosen].controller


def _model_run(uncertainty: Uncertainty, simulator: LoopSimulator, task: Task, step: Task,
               controller: ControllerSpec, rtol: float) -> ModelRun:
    nominal = uncertainty.nominal
    loop = analyse_loop(nominal, controller)
    worst_peak = max(sensitivity_peak(p, controller, points=3000) for p in uncertainty.linear_corners)
    worst = float(np.max(tracking_errors(simulator, uncertainty.sets, task, controller, rtol)))
    on_task = simulator.simulate_loop(nominal.parameter_vector()[None], task.time, task.position, controller,
                                      rtol=rtol)
    on_step = simulator.simulate_loop(nominal.parameter_vector()[None], step.time, step.position,
                                      step_drive(controller), rtol=rtol)
    figures = tracking_figures(task, on_task.position[0], on_task.v[0], on_task.command[0],
                               controller["force_limit"], step, on_step.position[0])
    return ModelRun(controller, loop, worst_peak, worst, figures, on_task.position[0], on_task.v[0],
                    on_step.position[0])


def tune_axis(result: Result, controller: ControllerSpec, task: Task, options: TuneOptions = TuneOptions(),
              method: str = "pso", compensate: bool = False, axis: str | Path | None = None,
              engine: str = "libcosim", progress: Progress | None = None, source: str = "the result") -> Tuning:
    """Tune the drive's gains for an identified axis.

    Parameters
    ----------
    result : Result
        The axis identified (servofmu.read_result), with the 95 % intervals its uncertainty set is drawn from.
    controller : ControllerSpec
        The drive (servofmu.model.controller.load_controller): its sample time, delay, output limit and encoder
        stay; its gains are the "given" ones compared with.
    task : Task
        The motion tuned for (servofmu.tuning.task: a stroke or a reference file).
    options : TuneOptions
        The bound on the sensitivity peak, the swarm's settings and the uncertainty set's.
    method : str
        "pso" (the particle swarm, servofmu.tuning.search) or "rule" (the reference rule alone,
        servofmu.tuning.rule).
    compensate : bool
        Feed forward the identified friction in every controller compared.
    axis : str or Path, optional
        An axis archive (SSP) to co-simulate the given, the rule's and the tuned gains on (servofmu.tuning.check).
    engine : str
        Its co-simulation engine, "libcosim" or "fmpy".
    progress : callable, optional
        ``progress(done, total)`` after each of the swarm's iterations.
    source : str
        How messages name the result.

    Returns
    -------
    Tuning
        Every controller's loop figures and figures on the model (and on the axis); ``.controller`` is the one
        chosen (the swarm's, or the rule's with ``method="rule"``).  Nothing is written.

    Raises
    ------
    UserError
        For a result of another axis, a task infeasible at the output limit, or a bound nothing meets.
    """
    from ..api_checks import check_arguments

    check_arguments(tune_axis, locals())  # a wrong type: UserError naming it
    if method not in METHODS:
        raise UserError(f"--method must be one of {', '.join(METHODS)}, not {method!r}")
    started = clock.perf_counter()
    plant = result.plant
    mass = check_pairing(result, controller, source)
    check_task(task, plant, controller, mass)
    base = friction_feedforward(controller, plant) if compensate else controller
    intervals = determined_intervals(plant, result.intervals, options.keep, source)
    uncertainty = uncertainty_sets(plant, result.theta, intervals, options.draws, options.seed)
    rule, rule_a = tune_rule(plant, base, options.max_sensitivity, uncertainty.linear_corners)
    controllers = {"given": base, "rule": rule}
    search = None
    if method == "pso":
        search = search_gains(uncertainty, base, task, options, starts=[rule], progress=progress)
        controllers["tuned"] = search.controller
    step = step_for(task, list(controllers.values()))
    simulator = LoopSimulator(plant, threads=options.threads)
    runs = {label: _model_run(uncertainty, simulator, task, step, c, options.rtol)
            for label, c in controllers.items()}
    axis_runs = None
    if axis is not None:
        axis_runs = check_on_axis(axis, controllers, task, step, engine)
    return Tuning(result, task, step, method, options, compensate, runs, rule_a, search, axis_runs,
                  clock.perf_counter() - started, uncertainty)


def tune_files(result: str | Path, controller: str | Path, output: str | Path | None, task: str | Path | None = None,
               stroke: float | None = None, speed: float | None = None, options: TuneOptions | None = None,
               compensate: bool = False, method: str = "pso", axis: str | Path | None = None,
               engine: str = "libcosim", overwrite: bool = False, progress: Progress | None = None) -> Tuning:
    """`servofmu tune` from files: tune the controller file ``controller`` for the result file ``result``
    (:func:`tune_axis`) and write the tuned controller file ``output`` (None: nothing written; an existing one only
    with ``overwrite``).  ``task``: a reference file, or ``stroke`` and ``speed`` (servofmu.tuning.task.load_task);
    ``options``: the one TuneOptions of the run, checked before any work.  Nothing is written when the tuning
    fails; the page is servofmu.output.tune_report's."""
    options = options or TuneOptions()
    if output is not None:
        output = claim_output(output, output_mode(overwrite), inputs=(result, controller, task, axis))
    spec = load_controller(controller)
    tuning = tune_axis(read_result(result), spec, load_task(task, stroke, speed, spec.sample_time), options,
                       method=method, compensate=compensate, axis=axis, engine=engine, progress=progress,
                       source=str(result))
    if output is not None:
        atomic_write(output, with_digest(controller_toml(tuning.controller, _tuned_note(tuning, controller, result))))
    return tuning


def _tuned_note(tuning: Tuning, controller: str | Path, result: str | Path) -> str:
    """The tuned controller file's comment: where it came from and the chosen loop's figures."""
    run = tuning.runs[tuning.chosen]
    return (f"Tuned by servofmu tune ({tuning.method}) from {Path(controller).name} for {Path(result).name} on "
            f"{tuning.task.label}, {utc_now()}:\nsensitivity peak {run.loop.ms:.3f} (bound "
            f"{tuning.options.max_sensitivity:g}), gain margin {run.loop.summary()['gain_margin_db']:.2f} dB, phase "
            f"margin {run.loop.phase_margin:.1f} deg; RMS tracking error on the model {run.figures.rms_error:.4g} m "
            f"(given gains {tuning.runs['given'].figures.rms_error:.4g} m).")
