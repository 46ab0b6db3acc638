"""Identification of G(s) and the friction: the PSO-ANN hybrid, scored by output error.

A candidate is scored by how well its simulated responses match the measured ones (the paper's fitness needs
the true parameters, which no user has).  Stages (docs/identification.md):

1. ``ann``: the trained network maps the measured features to a first estimate;
2. ``pso``: a particle swarm searches a box around it (in the network's output coordinates: logs of
   magnitudes, so the box is relative and positivity is kept); without a network (``method="pso"``) the box is
   the prior's;
3. ``polish``: Levenberg–Marquardt on the residuals from the search's best point, with a forward-difference
   Jacobian computed in one batch call; its last Jacobian gives the 95 % intervals (Gauss–Newton covariance
   s²(JᵀJ)⁻¹, Student t quantile).
The GA comparators (``ga-ann``, ``aga-ann``) replace stage 2 with the same budget of model evaluations.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .batch import BatchSimulator, SteadyStateOptions
from .dataset import SineData, ann_features, feature_names, from_targets, sine_residuals, to_targets
from .errors import UserError
from .plant import Plant
from .ga import AdaptiveGaOptions, GaOptions, minimize_ga
from .prior import canonical_order, full_vectors, identified_names
from .pso import PsoOptions, minimize_pso

# The paper's hybrid, the swarm alone, and its comparators GA-ANN [31] and adaptive GA-ANN [35]: the same ANN
# estimate, box, criterion, polish and number of model evaluations, only the search differs.
METHODS = ("pso-ann", "pso", "ga-ann", "aga-ann")
SEARCH_NAMES = {"pso-ann": "pso", "pso": "pso", "ga-ann": "ga", "aga-ann": "aga"}
# Integrator tolerances (relative): the swarm only needs to rank candidates; the polish's residuals must be far
# more exact than the 1e-6 the parameters are to reach.  Its forward-difference Jacobian (relative step 1e-5) is
# evaluated at the same tight tolerance: looser ones (1e-8) made g2's steady-state test fail for single
# perturbed candidates, which spoils a whole Jacobian.
SEARCH_RTOL = 1e-5
POLISH_RTOL = 1e-10
JACOBIAN_RTOL = POLISH_RTOL
JACOBIAN_STEP = 1e-5
MAX_POLISH_ITERATIONS = 20


@dataclass(frozen=True)
class RecordData:
    """Time-domain records to identify from: per record time (s), input u (N) and measured velocity v (m/s)."""

    records: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]
    source: str


# ---------------------------------------------------------------------------
# Output-error criteria: residuals of many candidates at once
# ---------------------------------------------------------------------------
def steady_state_options(rtol: float) -> SteadyStateOptions:
    """Batch-simulator settings for an integrator tolerance: periods compared to a tenth of it (within limits).

    Giving up early on an experiment that seems not to settle saves the search much time, and a wrong verdict
    there only costs a candidate its rank; the polish's few candidates run to max_time instead, since a wrong
    verdict there stalls the fit (seen on g2-like plants whose 4 Hz response settles slowly)."""
    return SteadyStateOptions(rtol=rtol, tol=min(max(rtol / 10, 1e-10), 1e-6), give_up_early=rtol >= SEARCH_RTOL)


class SineCriterion:
    """Residuals of candidates against stepped-sine data (servofmu.dataset.sine_residuals)."""

    def __init__(self, structure: Plant, data: SineData, simulator: BatchSimulator):
        self.structure, self.data, self.simulator = structure, data, simulator
        self.evaluations = 0

    def residuals(self, theta: np.ndarray, rtol: float) -> np.ndarray:
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        feats = self.simulator.steady_state(full_vectors(self.structure, theta), self.data.amplitudes,
                                            self.data.frequencies, steady_state_options(rtol))
        r = sine_residuals(self.data, feats.H, feats.dc)
        r[~np.all(feats.converged, axis=1)] = np.nan  # a candidate without steady state cannot be compared
        return r


class RecordCriterion:
    """Residuals of candidates against time-domain records: (v_model − v)/rms(v) at every sample."""

    def __init__(self, structure: Plant, data: RecordData, simulator: BatchSimulator):
        self.structure, self.data, self.simulator = structure, data, simulator
        self.evaluations = 0

    def residuals(self, theta: np.ndarray, rtol: float) -> np.ndarray:
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        full = full_vectors(self.structure, theta)
        parts = []
        for t, u, v in self.data.records:
            sim = self.simulator.simulate_record(full, t, u, rtol=rtol)
            parts.append((sim - v) / np.sqrt(np.mean(v**2)))
        return np.concatenate(parts, axis=1)


def rms(r: np.ndarray) -> np.ndarray:
    """The fitness: root mean square of the residuals per candidate (inf where a simulation failed)."""
    out = np.sqrt(np.mean(np.square(r), axis=-1))
    return np.where(np.isfinite(out), out, np.inf)


# ---------------------------------------------------------------------------
# The estimator
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Stage:
    """One stage's outcome: identified parameters, fitness, wall time and candidates evaluated."""

    name: str
    theta: np.ndarray
    fitness: float
    seconds: float
    evaluations: int


@dataclass(frozen=True)
class AnnModel:
    """A trained network with the plan it belongs to (see servofmu.ann)."""

    network: object
    layout: object
    source: str


def prior_box(structure: Plant, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """The prior's box in target coordinates (see servofmu.prior and servofmu.dataset.to_targets)."""
    centre = to_targets(structure, structure.parameter_vector()[None, _mask(structure)])[0]
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    half = np.array([np.log1p(spread) if (nominal[n] != 0 or n.endswith(("_re", "_im")) or n.startswith("fs_"))
                     else spread for n in identified_names(structure)])
    return centre - half, centre + half


def _mask(structure: Plant) -> np.ndarray:
    from .prior import identified_mask
    return identified_mask(structure)


class PSOANNIdentifier:
    """PSO-ANN identification (estimator-style: ``__init__`` stores settings, ``fit`` returns self).

    After ``fit``: ``theta_`` (identified parameters, in ``names_`` order), ``plant_`` (the identified plant),
    ``fitness_`` (RMS relative output error), ``intervals_`` (p × 2, 95 %), ``stages_`` (list of Stage),
    ``history_`` (PSO best cost per iteration), ``seconds_``, ``evaluations_``.
    """

    def __init__(self, structure: Plant, ann: AnnModel | None = None, method: str = "pso-ann",
                 pso: PsoOptions = PsoOptions(), polish: bool = True, box: float = 4.0, spread: float = 0.5,
                 seed: int = 0, threads: int | None = None,
                 progress: Callable[[str, int, int], None] | None = None):
        self.structure, self.ann, self.method, self.pso = structure, ann, method, pso
        self.polish, self.box, self.spread, self.seed = polish, box, spread, seed
        self.threads, self.progress = threads, progress

    # ---- stages ------------------------------------------------------------------------------------------
    def _ann_estimate(self, data: SineData) -> tuple[np.ndarray, np.ndarray]:
        """The network's estimate and its search half-width, both in target coordinates."""
        from .ann import FeatureLayout

        names = identified_names(self.structure)
        layout = FeatureLayout(feature_names=feature_names(data.amplitudes.size), parameter_names=names,
                               plan=data.plan)
        self.ann.layout.check_compatible(layout, self.ann.source)
        x = ann_features(data.H[None], data.dc[None], data.amplitudes)
        y = self.ann.network.predict(x)[0]
        half = self.box * self.ann.network.validation_rmse * np.asarray(self.ann.network.y_scale)
        return y, half

    def ann_theta(self, data: SineData) -> np.ndarray:
        """The network's estimate of the identified parameters (the first stage alone)."""
        y, _ = self._ann_estimate(data)
        return canonical_order(self.structure, from_targets(self.structure, y[None]))[0]

    def fit(self, data: SineData | RecordData) -> "PSOANNIdentifier":
        if self.method not in METHODS:
            raise UserError(f"unknown method {self.method!r} (choose {', '.join(METHODS)})")
        uses_ann = self.method != "pso"
        if uses_ann and self.ann is None:
            raise UserError(f"method {self.method} needs a trained network (--ann ANN.h5; see `servofmu train`)")
        if uses_ann and isinstance(data, RecordData):
            raise UserError("the ANN works on stepped-sine data; identify records with --method pso")
        start = time.perf_counter()
        simulator = BatchSimulator(self.structure, threads=self.threads)
        crit = SineCriterion(self.structure, data, simulator) if isinstance(data, SineData) else \
            RecordCriterion(self.structure, data, simulator)
        self.names_ = identified_names(self.structure)
        stages = []

        def to_theta(y):
            return canonical_order(self.structure, from_targets(self.structure, y))

        def cost(y, rtol=SEARCH_RTOL):
            return rms(crit.residuals(to_theta(y), rtol))

        if uses_ann:
            t0 = time.perf_counter()
            y0, half = self._ann_estimate(data)
            theta0 = to_theta(y0)[0]
            stages.append(Stage("ann", theta0, float(cost(y0[None])[0]), time.perf_counter() - t0, 1))
            lower, upper = y0 - half, y0 + half
        else:
            lower, upper = prior_box(self.structure, self.spread)
            y0 = None

        t0, before = time.perf_counter(), crit.evaluations
        search = SEARCH_NAMES[self.method]
        progress = (lambda done, total, best: self.progress(search, done, total)) if self.progress else None
        if search == "pso":
            result = minimize_pso(cost, lower, upper, self.pso, x0=y0, seed=self.seed, progress=progress)
        else:  # the GAs get the swarm's budget: particles × (iterations + 1) evaluations
            budget = self.pso.particles * (self.pso.iterations + 1)
            options = GaOptions(max_evaluations=budget) if search == "ga" else AdaptiveGaOptions(max_evaluations=budget)
            result = minimize_ga(cost, lower, upper, options, x0=y0, seed=self.seed, progress=progress)
        y_best = result.position
        stages.append(Stage(search, to_theta(y_best)[0], float(result.cost), time.perf_counter() - t0,
                            crit.evaluations - before))
        self.history_ = result.cost_history

        if self.polish:
            t0, before = time.perf_counter(), crit.evaluations
            y_best, jac_y = self._polish(crit, to_theta, y_best)
            theta = to_theta(y_best)[0]
            r = crit.residuals(theta, POLISH_RTOL)[0]
            stages.append(Stage("polish", theta, float(rms(r)), time.perf_counter() - t0, crit.evaluations - before))
            # the polish's last Jacobian, taken from target to parameter coordinates, gives the intervals
            jac = jac_y @ _target_jacobian(self.structure, y_best)
            self.intervals_ = intervals_from_jacobian(theta, r, jac)
        else:
            theta = stages[-1].theta
            r = crit.residuals(theta, POLISH_RTOL)[0]
            self.intervals_ = intervals_from_jacobian(theta, r, _central_jacobian(crit, theta))
        self.theta_ = stages[-1].theta
        self.fitness_ = stages[-1].fitness
        self.plant_ = self.structure.with_parameters(full_vectors(self.structure, self.theta_)[0])
        self.stages_ = stages
        self.seconds_ = time.perf_counter() - start
        self.evaluations_ = crit.evaluations
        return self

    def _polish(self, crit, to_theta, y0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Levenberg–Marquardt from ``y0`` (target coordinates); returns the optimum and the Jacobian there.

        Stops when a step changes no coordinate by more than 1e-10 (relative), or when the best step
        lowers the residual norm by less than 1 % (the features' own noise floor is reached)."""

        def residual(y):
            r = crit.residuals(to_theta(y[None]), POLISH_RTOL)[0]
            return np.where(np.isfinite(r), r, 1e3)  # a candidate without steady state: far from the data

        def jacobian(y, r):  # forward differences, all columns in one batch call
            h = JACOBIAN_STEP * np.maximum(np.abs(y), 1.0)
            cols = crit.residuals(to_theta(y + np.diag(h)), JACOBIAN_RTOL)
            failed = ~np.all(np.isfinite(cols), axis=1)
            if failed.any():  # a perturbed candidate without steady state: step the other way
                h[failed] = -h[failed]
                cols[failed] = crit.residuals(to_theta(y + np.diag(h)[failed]), JACOBIAN_RTOL)
            return ((cols - r) / h[:, None]).T  # NaN columns (both ways failed) end the polish

        y, r = y0.copy(), residual(y0)
        jac, damping = jacobian(y, r), 1e-6
        for _ in range(MAX_POLISH_ITERATIONS):
            if not np.all(np.isfinite(jac)):
                break
            a, g = jac.T @ jac, jac.T @ r
            while damping < 1e8:
                step = np.linalg.solve(a + damping * np.diag(np.diag(a) + 1e-30), -g)
                r_new = residual(y + step)
                if r_new @ r_new < r @ r:
                    break
                damping *= 10
            else:
                break  # no step lowers the residuals: converged
            improvement = 1 - np.sqrt((r_new @ r_new) / (r @ r))
            y, r, damping = y + step, r_new, max(damping / 10, 1e-9)
            small = np.max(np.abs(step) / np.maximum(np.abs(y), 1e-3)) < 1e-10
            jac = jacobian(y, r)
            if small or improvement < 0.01:
                break
        return y, jac


def _central_jacobian(crit, theta: np.ndarray) -> np.ndarray:
    """d residuals / d theta by central differences (one batch call)."""
    p = theta.size
    h = JACOBIAN_STEP * np.maximum(np.abs(theta), 1e-3)
    r = crit.residuals(np.concatenate([theta + np.diag(h), theta - np.diag(h)]), JACOBIAN_RTOL)
    return ((r[:p] - r[p:]) / (2 * h[:, None])).T


def _target_jacobian(structure: Plant, y: np.ndarray) -> np.ndarray:
    """d y / d theta at the parameters of ``y`` (the coordinate change only; no simulation)."""
    theta = from_targets(structure, y[None])[0]
    h = 1e-7 * np.maximum(np.abs(theta), 1e-6)
    up = to_targets(structure, theta + np.diag(h))
    down = to_targets(structure, theta - np.diag(h))
    return ((up - down) / (2 * h[:, None])).T


def intervals_from_jacobian(theta: np.ndarray, r: np.ndarray, jac: np.ndarray, level: float = 0.95) -> np.ndarray:
    """(p, 2) intervals from the Gauss–Newton covariance s²(JᵀJ)⁻¹ with a Student t quantile."""
    from scipy.stats import t as student

    p = theta.size
    dof = max(r.size - p, 1)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        return np.full((p, 2), np.nan)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    half = student.ppf(0.5 + level / 2, dof) * np.sqrt(np.clip(np.diag(cov), 0, None))
    return np.stack([theta - half, theta + half], axis=1)


# ---------------------------------------------------------------------------
# Reading what `servofmu identify` is given
# ---------------------------------------------------------------------------
def load_inputs(data_path, structure_path, ann_path, method: str, command: str = ""):
    """(structure, SineData | RecordData, AnnModel | None, provenance) for the identify command.

    Refuses a structure that does not match the plant the data was measured on (when the data file says which),
    and a network trained for another plan or structure.
    """
    import hashlib

    from .ann import load_network
    from .dataset import sine_data
    from .plant import load_plant
    from .store import load_dataset

    if method not in METHODS:
        raise UserError(f"unknown method {method!r} (choose {', '.join(METHODS)})")
    structure = load_plant(structure_path)
    ds = load_dataset(data_path)
    measured = [n for n in ds.parameters if n.startswith(("pole", "zero", "fc_", "fs_", "sigma", "gain", "dc_gain"))]
    if measured and set(measured) - set(structure.parameter_names()):
        raise UserError(f"{structure_path}: the structure ({', '.join(identified_names(structure))}) does not match "
                        f"the plant {data_path} was measured on ({', '.join(measured)})")
    if ds.kind == "records":
        records = tuple((r.series.time, r.series.u, r.series.v) for r in ds.records)
        if not records:
            raise UserError(f"{data_path}: the file holds no records")
        data = RecordData(records=records, source=str(data_path))
    else:
        if not ds.experiments:
            raise UserError(f"{data_path}: the file holds no experiments")
        data = sine_data(ds)
    ann = None
    if method != "pso":
        if ann_path is None:
            raise UserError(f"method {method} needs a trained network: give --ann ANN.h5 (made by `servofmu dataset` "
                            "and `servofmu train`), or use --method pso")
        net, layout = load_network(ann_path)
        ann = AnnModel(net, layout, str(ann_path))
        if list(layout.parameter_names) != identified_names(structure):
            raise UserError(f"{ann_path} estimates {', '.join(layout.parameter_names)}; the structure "
                            f"{structure_path} has {', '.join(identified_names(structure))}")
    sha = hashlib.sha256(Path(data_path).read_bytes()).hexdigest()
    provenance = {"data_file": str(data_path), "data_sha256": sha, "structure_file": str(structure_path),
                  "ann_file": str(ann_path) if ann_path else "", "command": command}
    return structure, data, ann, provenance
