"""The drive's gains searched with the project's particle swarm, each candidate scored by its simulated tracking
error on the task, under a bound on the sensitivity peak, across the identified model's uncertainty.

A candidate is six numbers, scaled so that one box fits every axis (m the identified mass, Ts the sample time,
ω_v = kp_velocity/m the velocity loop's crossover):

    log10(ω_v·(delay + 1)·Ts)        the velocity loop's speed against the loop's dead time
    log10(ki_velocity/kp_velocity/ω_v)   the integral corner against ω_v
    log10(kp_position/ω_v)           the position loop against the velocity loop (the bandwidth ratio)
    τ/Ts of the velocity estimate's first-order filter (below 1/2: no filter, the plain position difference)
    velocity_feedforward             the share of the reference velocity fed forward
    mass_feedforward/m               the share of the identified mass fed forward

Score of a candidate: the largest RMS tracking error r − x over the plants of the uncertainty set (the nominal
model and random corners of its 95 % box), the loop simulated by the batch simulator with the drive's C law
(sampling, delay, output limit, the encoder's quantiser).  Constraint: the linearised loop's sensitivity peak
(servofmu.tuning.loop) at most Ms for every corner of the box of G's parameters; a candidate above it is not
simulated and scores 10³ + its peak, so that the swarm is drawn back to the bound.
"""
from __future__ import annotations

import itertools
import time
import warnings
from dataclasses import dataclass

import numpy as np

from ..display import Shown, figure, options_html, options_repr, shown_html, shown_repr
from ..errors import ServofmuWarning, UserError, check_int, is_real
from ..identification.pso import PsoOptions, minimize_pso
from ..identification.prior import full_vectors, identified_names
from ..model.controller import ControllerSpec
from ..model.plant import Plant
from ..runtime import WORK_LIMIT_HOURS, check_work, check_work_limit
from ..simulation.closed_loop import LoopSimulator
from .loop import axis_mass, sensitivity_peak
from .task import Task

__all__ = ["Uncertainty", "uncertainty_sets", "GainSpace", "TuneOptions", "TuneSearch", "tracking_errors",
           "search_gains", "compass_search", "to_bound", "determined_intervals", "INFEASIBLE"]

INFEASIBLE = 1e3  # the score of a candidate above the sensitivity bound (plus its peak)
MAX_RELATIVE_WIDTH = 0.5  # an interval wider than ±50 % (or unbounded) is clipped to it, with a warning
LINEAR_PREFIXES = ("pole", "zero", "gain", "dc_gain")


@dataclass(frozen=True)
class Uncertainty:
    """The plants a tuning is judged on: ``sets`` (rows of full parameter vectors: the nominal model first, then
    random corners of the identified 95 % box) for the tracking error, ``linear_corners`` (every corner of the box
    of G's parameters, nominal first) for the sensitivity bound."""

    nominal: Plant
    sets: np.ndarray
    linear_corners: tuple[Plant, ...]


def _box(plant: Plant, theta: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    names = identified_names(plant)
    lo, hi = np.array(intervals[:, 0], float), np.array(intervals[:, 1], float)
    width = MAX_RELATIVE_WIDTH * np.abs(theta)
    wide = ~np.isfinite(lo) | ~np.isfinite(hi) | (theta - lo > width) | (hi - theta > width)
    if np.any(wide):
        warnings.warn(f"the 95 % intervals of {', '.join(n for n, w in zip(names, wide) if w)} are wider than "
                      f"±{100 * MAX_RELATIVE_WIDTH:g} %: the tuning judges them at ±{100 * MAX_RELATIVE_WIDTH:g} %",
                      ServofmuWarning, stacklevel=3)
    lo = np.where(wide, theta - width, lo)
    hi = np.where(wide, theta + width, hi)
    return np.stack([np.minimum(lo, theta), np.maximum(hi, theta)], axis=1)


def uncertainty_sets(plant: Plant, theta: np.ndarray, intervals: np.ndarray, draws: int = 6,
                     seed: int = 0) -> Uncertainty:
    """The uncertainty of an identified model (``theta`` and its 95 % ``intervals``, both over
    identified_names(plant)): the nominal plant and ``draws`` corners of the box drawn with ``seed``, and all
    corners of the box of G's parameters."""
    theta, intervals = np.asarray(theta, float), np.array(intervals, float)
    kept = np.isnan(intervals)  # parameters taken at their identified value (determined_intervals)
    intervals[kept] = np.broadcast_to(theta[:, None], intervals.shape)[kept]
    box = _box(plant, theta, intervals)
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, 2, size=(draws, box.shape[0]))
    corners = np.take_along_axis(np.broadcast_to(box, (draws, *box.shape)), picks[:, :, None], axis=2)[:, :, 0]
    sets = full_vectors(plant, np.vstack([theta, corners]))
    names = identified_names(plant)
    linear = [i for i, n in enumerate(names) if n.startswith(LINEAR_PREFIXES)]
    plants = [plant]
    for choice in itertools.product((0, 1), repeat=len(linear)):
        vector = np.array(theta, float)
        vector[linear] = box[linear, list(choice)]
        plants.append(plant.with_parameters(full_vectors(plant, vector)[0]))
    return Uncertainty(plant, sets, tuple(plants))


@dataclass(frozen=True)
class GainSpace:
    """The search box of the gains for a plant of mass ``mass`` (kg) and a drive sampled every ``sample_time``
    with ``delay`` (see the module's docstring for the six coordinates)."""

    mass: float
    sample_time: float
    delay: int
    lower: tuple = (np.log10(0.01), np.log10(0.005), np.log10(0.005), 0.0, 0.0, 0.0)
    upper: tuple = (np.log10(1.5), np.log10(1.0), np.log10(1.0), 8.0, 1.5, 2.0)

    def controller(self, base: ControllerSpec, x: np.ndarray) -> ControllerSpec:
        """The controller of the point ``x`` (the other settings of ``base`` kept)."""
        omega_v = 10 ** x[0] / ((self.delay + 1) * self.sample_time)
        kp = self.mass * omega_v
        filtered = x[3] >= 0.5
        return base.with_values(kp_velocity=kp, ki_velocity=kp * omega_v * 10 ** x[1],
                                kp_position=omega_v * 10 ** x[2], velocity_filter=2.0 if filtered else 0.0,
                                filter_time_constant=x[3] * self.sample_time if filtered else
                                base["filter_time_constant"],
                                velocity_feedforward=x[4], mass_feedforward=x[5] * self.mass)

    def point(self, controller: ControllerSpec) -> np.ndarray:
        """The point of a controller's gains (a moving average counts as a first-order filter of its lag),
        clipped into the box."""
        omega_v = controller["kp_velocity"] / self.mass
        kind = int(controller["velocity_filter"])
        lag = {0: 0.0, 1: (controller["filter_window"] - 1) / 2,
               2: controller["filter_time_constant"] / self.sample_time}[kind]
        x = [np.log10(omega_v * (self.delay + 1) * self.sample_time),
             np.log10(max(controller["ki_velocity"], 1e-300) / controller["kp_velocity"] / omega_v),
             np.log10(max(controller["kp_position"], 1e-300) / omega_v), lag,
             controller["velocity_feedforward"], controller["mass_feedforward"] / self.mass]
        return np.clip(np.array(x), self.lower, self.upper)


@dataclass(frozen=True)
class TuneOptions:
    """Settings of a tuning.

    Parameters
    ----------
    max_sensitivity : float
        Bound on the sensitivity peak of the loop linearised about motion, above 1 (default 1.7).
    particles, iterations : int
        The particle swarm's size and length (default 16 and 30).
    draws : int
        Random corners of the identified 95 % box in the uncertainty set, beside the nominal model (default 6).
    seed : int
        Seed of the swarm and of the draws.
    rtol : float
        Relative tolerance of the loop simulations.
    threads : int or None
        Threads of the batch simulator (None: the cores this process may use).
    polish_steps : tuple of float
        Steps of the compass search after the swarm, as shares of the box's widths.
    work_limit : float
        Hours the swarm may be estimated at (servofmu.runtime.check_work).
    keep : tuple of str
        Parameters the data left undetermined (infinite intervals) that the tuning takes at their identified
        values; any other undetermined parameter is refused (:func:`determined_intervals`).
    """

    max_sensitivity: float = 1.7
    particles: int = 16
    iterations: int = 30
    draws: int = 6
    seed: int = 0
    rtol: float = 1e-6
    threads: int | None = None
    polish_steps: tuple[float, ...] = (0.02, 0.005)
    keep: tuple[str, ...] = ()
    work_limit: float = WORK_LIMIT_HOURS
    _units = {"work_limit": "h"}
    __repr__, _repr_html_ = options_repr, options_html

    def __post_init__(self):
        check_int("--particles", self.particles, 1, 10_000)
        check_int("--iterations", self.iterations, 0, 100_000)
        check_int("the number of uncertainty draws", self.draws, 0, 10_000)
        check_int("--seed", self.seed, 0)
        check_work_limit(self.work_limit)
        if not (is_real(self.max_sensitivity) and self.max_sensitivity > 1.0):
            raise UserError(f"the sensitivity peak bound must be above 1 (|S| ≥ 1 somewhere for every loop "
                            f"with a delay), not {self.max_sensitivity!r}")


def determined_intervals(plant: Plant, intervals: np.ndarray, keep: tuple[str, ...], source: str) -> np.ndarray:
    """The 95 % intervals a tuning is judged on: a parameter the data left undetermined (an infinite interval) is
    refused in one line — the plant's value along a direction the data do not fix is arbitrary, and so would the
    gains be — unless ``keep`` names it, in which case it is taken at its identified value (interval of width 0)."""
    names = identified_names(plant)
    unknown = [k for k in keep if k not in names]
    if unknown:
        raise UserError(f"--keep {', '.join(unknown)}: not an identified parameter of {plant.name} (those are "
                        f"{', '.join(names)})")
    intervals = np.array(intervals, float)
    open_ = [n for n, row in zip(names, intervals) if not np.all(np.isfinite(row))]
    missing = [n for n in open_ if n not in keep]
    if missing:
        raise UserError(f"{source}: the data did not determine {', '.join(missing)} (infinite 95 % intervals): fix "
                        "them in the structure file (fixed = [...]) and identify again, or give --keep "
                        f"{','.join(missing)} to tune with their identified values")
    theta_rows = [i for i, n in enumerate(names) if n in keep]
    intervals[theta_rows] = np.nan  # filled with the identified value by uncertainty_sets
    return intervals


def tracking_errors(simulator: LoopSimulator, sets: np.ndarray, task: Task, controller: ControllerSpec,
                    rtol: float = 1e-6) -> np.ndarray:
    """RMS tracking error r − x (m) of ``controller`` on the task for every plant (rows of ``sets``)."""
    response = simulator.simulate_loop(sets, task.time, task.position, controller, rtol=rtol)
    return np.sqrt(np.mean((task.position[None, :] - response.position) ** 2, axis=1))


@dataclass(frozen=True)
class TuneSearch:
    """A finished search: the best controller, its worst-case RMS error over the uncertainty set (m), the
    swarm's best score per iteration, and the number of candidates simulated."""

    controller: ControllerSpec
    worst_rms: float
    history: np.ndarray
    simulated: int
    evaluations: int

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        c = self.controller
        return Shown(type(self).__name__, f"{self.history.size} iterations, {self.simulated} candidates simulated", (
            figure("worst RMS error", self.worst_rms, "m", ".3g"), figure("kp_position", c["kp_position"], "1/s"),
            figure("kp_velocity", c["kp_velocity"], "N.s/m"), figure("ki_velocity", c["ki_velocity"], "N/m")))


def search_gains(uncertainty: Uncertainty, controller: ControllerSpec, task: Task, options: TuneOptions,
                 starts: list[ControllerSpec] = (), progress=None) -> TuneSearch:
    """The swarm's search (the module's docstring) from ``controller`` (its sample time, delay, limit, encoder
    and friction feed-forward kept); ``starts``: controllers placed among the first particles."""
    space = GainSpace(axis_mass(uncertainty.nominal), controller.sample_time, int(controller["delay"]))
    simulator = LoopSimulator(uncertainty.nominal, threads=options.threads)
    simulated = [0]

    def peak(x: np.ndarray, corners: bool = True) -> float:
        candidate = space.controller(controller, x)
        worst = 0.0
        for plant in uncertainty.linear_corners[:None if corners else 1]:  # nominal first: most fail there
            worst = max(worst, sensitivity_peak(plant, candidate))
            if worst > options.max_sensitivity:
                break
        return worst

    def score(x: np.ndarray) -> float:
        bounded = to_bound(peak, x, options.max_sensitivity, space.lower[0])
        if bounded is None:
            return INFEASIBLE + min(peak(np.r_[space.lower[0], x[1:]]), 1e6)
        simulated[0] += 1
        return float(np.max(tracking_errors(simulator, uncertainty.sets, task,
                                            space.controller(controller, bounded), options.rtol)))

    def cost(population: np.ndarray) -> np.ndarray:
        return np.array([score(x) for x in population])

    x0 = np.array([space.point(c) for c in [controller, *starts]])[:options.particles]
    t0 = time.perf_counter()
    cost(x0[:1])
    check_work(f"the tuning's swarm ({options.particles} particles × {options.iterations} iterations on "
               f"{len(uncertainty.sets)} plants)", (time.perf_counter() - t0) * options.particles *
               (options.iterations + 1), options.work_limit, "give fewer --particles or --iterations")
    found = minimize_pso(cost, space.lower, space.upper, PsoOptions(particles=options.particles,
                                                                    iterations=options.iterations),
                         x0=x0, seed=options.seed, progress=progress)
    if found.cost >= INFEASIBLE:
        raise UserError(f"no gains the search tried meet a sensitivity peak of {options.max_sensitivity:g} (the "
                        f"lowest found: {found.cost - INFEASIBLE:.3g}); allow a larger --max-sensitivity")
    x, best, polished = compass_search(cost, found.position, found.cost, space.lower, space.upper,
                                       options.polish_steps)
    x = to_bound(peak, x, options.max_sensitivity, space.lower[0])
    return TuneSearch(space.controller(controller, x), best, np.r_[found.cost_history, best],
                      simulated[0], found.evaluations + polished)


def to_bound(peak, x: np.ndarray, bound: float, lowest: float, tolerance: float = 0.002) -> np.ndarray | None:
    """``x`` itself when its sensitivity peak ``peak(x)`` is within ``bound``, else ``x`` with its first
    coordinate (the velocity loop's speed; the peak rises with it) lowered onto the bound — by bisection on the
    nominal plant (``peak(x, corners=False)``), then in steps of ``tolerance`` until every corner meets it: every
    candidate shape is scored at the fastest loop it allows.  None when even ``lowest`` exceeds the bound."""
    if peak(x) <= bound:
        return x
    if peak(np.r_[lowest, x[1:]]) > bound:
        return None
    lo, hi = lowest, x[0]
    while hi - lo > tolerance:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if peak(np.r_[mid, x[1:]], corners=False) <= bound else (lo, mid)
    while lo > lowest and peak(np.r_[lo, x[1:]]) > bound:
        lo = max(lo - tolerance, lowest)
    return np.r_[lo, x[1:]]


def compass_search(cost, x: np.ndarray, fx: float, lower, upper, steps: tuple[float, ...]):
    """(x, cost, evaluations): a compass search from the swarm's best point — each coordinate tried one step
    up and down, the step halved through ``steps`` once no move helps.  The swarm finds the basin, this its floor
    (the score is flat to rounding only between the encoder's quanta, not across them)."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    evaluations = 0
    for step in steps:
        moved = True
        while moved:
            moved = False
            trials = []
            for i in range(x.size):
                for sign in (1.0, -1.0):
                    y = x.copy()
                    y[i] = np.clip(y[i] + sign * step * (upper[i] - lower[i]), lower[i], upper[i])
                    if not np.array_equal(y, x):
                        trials.append(y)
            costs = cost(np.array(trials))
            evaluations += len(trials)
            j = int(np.argmin(costs))
            if costs[j] < fx * (1 - 1e-6):
                x, fx, moved = trials[j], float(costs[j]), True
    return x, fx, evaluations
