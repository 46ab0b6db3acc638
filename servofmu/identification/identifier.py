"""Identification of G(s) and the friction: the PSO-ANN hybrid, scored by output error.

A candidate is scored by how well its simulated responses match the measured ones (the paper's fitness needs
the true parameters, which no user has; servofmu.identification.criterion).  Stages (docs/identification.md):

1. ``ann``: the trained network maps the measured features to a first estimate;
2. ``pso``: a particle swarm searches a box around it (in the network's output coordinates: logs of
   magnitudes, so the box is relative and positivity is kept); without a network (``method="pso"``) the box is
   the prior's;
3. ``polish`` (servofmu.identification.polish): Levenberg–Marquardt on the residuals from the search's best
   point, with a forward-difference Jacobian computed in one batch call; its last Jacobian gives the 95 % intervals
   (Gauss–Newton covariance s²(JᵀJ)⁻¹, Student t quantile), and for records the fit's roughness is checked
   (servofmu.identification.roughness: whether the cost is as quadratic as the intervals assume).
The GA comparators (``ga-ann``, ``aga-ann``) replace stage 2 with the same budget of model evaluations.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import ServofmuWarning, UserError, check_int
from ..model.plant import Plant
from ..runtime import WORK_LIMIT_HOURS, Progress, check_work, check_work_limit
from ..simulation.batch import BatchSimulator
from .ann import AnnModel, FeatureLayout
from .criterion import (
    POLISH_RTOL,
    SEARCH_RTOL,
    RecordCriterion,
    RecordData,
    SineCriterion,
    SineData,
    central_jacobian,
    covariance_from_jacobian,
    intervals_from_covariance,
    rms,
    with_finite_columns,
)
from .confounding import with_free_directions
from .roughness import curvature, curvature_at, finite_covariance, response_roughness
from .features import ann_features, feature_names, from_targets, prior_box, target_jacobian
from .ga import AdaptiveGaOptions, GaOptions, minimize_ga
from .methods import METHODS, NEEDS_ANN, SEARCH_NAMES
from .prior import canonical_order, full_vectors, identified_names
from .polish import MAX_POLISH_ITERATIONS, polish
from .pso import PsoOptions, minimize_pso
from .restarts import RestartOptions, fits_agree, floor_test, noise_half_widths, restart_box, restart_seed
from .results import EstimatorDisplay, Result, Stage, result_from_estimator
from .shortening import long_open_loop, search_share

__all__ = ["PSOANNIdentifier", "polish", "swarm_options", "check_method"]

@dataclass(frozen=True, eq=False)
class _Fit:
    """One search and its polish: parameters, search coordinates, residuals, fitness, the search's history and the
    95 % intervals with the covariance they come from."""

    theta: np.ndarray
    y: np.ndarray
    r: np.ndarray
    fitness: float
    history: np.ndarray
    intervals: np.ndarray
    covariance: np.ndarray
    jacobian: np.ndarray  # of the weighted residuals by the parameters at theta
    search_jacobian: np.ndarray  # by the search coordinates at y (the polish's own; the parameters' without one)


def check_method(method: str) -> None:
    """A UserError naming the methods when ``method`` is not one of them."""
    if method not in METHODS:
        raise UserError(f"unknown method {method!r} (choose {', '.join(METHODS)})")


# A search of at most this many model evaluations is not estimated (the defaults: 10 particles × 51 × 7 searches);
# beyond, WORK_SAMPLE evaluations are timed to estimate it
UNCHECKED_EVALUATIONS, WORK_SAMPLE = 20_000, 2


class PSOANNIdentifier(EstimatorDisplay):
    """PSO-ANN identification of a plant structure from stepped-sine data or records.

    Estimator-style: ``__init__`` only stores its arguments, :meth:`fit` runs the stages and returns ``self``.

    Parameters
    ----------
    structure : Plant
        The structure to identify (order, which roots are complex, friction model); its values are the
        centre of the prior and the fixed parameters (``fv``, ``v_smooth``).
    ann : AnnModel, optional
        A trained network (:func:`servofmu.load_ann`); needed by ``pso-ann``, ``ga-ann`` and ``aga-ann``.
    method : {"pso-ann", "pso", "ga-ann", "aga-ann"}
        The paper's hybrid, the swarm alone (prior box), or the GA comparators.
    pso : PsoOptions
        Swarm settings (the paper's Table I by default).
    search_rtol : float
        Integrator tolerance of the search's simulations (SEARCH_RTOL; docs/bench-swarm-budget.md measures others).
    polish : bool
        Finish with the least-squares polish (and its intervals).
    box : float
        Half-width of the search box around the ANN estimate, in validation RMS errors of the network.
    spread : float
        Prior width for ``method="pso"`` (as in :func:`servofmu.make_training_set`).
    seed : int
        Seed of the search.
    threads : int, optional
        Threads of the batch simulator (default: all cores).
    progress : Progress, optional
        Called with (iterations done, iterations) during the search.
    restarts : RestartOptions
        When a fit that stopped above the noise floor is searched for again (servofmu.identification.restarts;
        ``RestartOptions(restarts=0)``: never).

    Attributes
    ----------
    theta_ : ndarray
        Identified parameters in ``names_`` order.
    names_ : list of str
        Their names (servofmu.identification.prior.identified_names).
    plant_ : Plant
        The identified plant.
    fitness_ : float
        RMS relative output error at ``theta_``.
    data_ : SineData or RecordData
        The data fitted.
    fit_percent_ : dict or None
        For records: the fit of every record (%), as MATLAB's ``compare`` defines it, by record (and signal).
    intervals_ : ndarray, shape (p, 2)
        95 % intervals.
    covariance_ : ndarray, shape (p, p)
        The estimates' covariance the intervals come from (servofmu.identification.confounding names the
        parameter directions it shows the data does not separate).
    jacobian_ : ndarray, shape (residuals, p)
        The criterion's weighted residuals differentiated by the parameters at ``theta_`` (the polish's last
        Jacobian; central differences without a polish).
    search_jacobian_ : ndarray, shape (residuals, p)
        The same by the search coordinates (log-scaled parameters, a Stribeck bump's log of fs − fc) at the fit:
        the polish's last Jacobian as it computed it; ``jacobian_`` without a polish.  Finite where a parameter
        sits on its bound (a bump of zero, fs = fc), where the change to the parameters' coordinates is not.
    stages_ : list of Stage
        Outcome of each stage.
    history_ : ndarray
        Best cost per iteration of the search whose fit was kept.
    restarts_ : int
        Searches after the first (0 when the first fit was at the noise floor).
    floor_ : FloorTest or None
        The kept fit against the noise floor (None for time-domain data, which has no known noise level).
    roughness_ : float
        Records: the largest rise of −2·ln L one standard error from the polished fit (about 1; above
        roughness.ROUGH_RISE the response is chaotic in the parameters and the intervals do not hold); NaN for
        stepped-sine data or without a polish.
    seconds_, evaluations_ : float, int
        Wall time and model evaluations of the whole fit.

    Examples
    --------
    >>> from servofmu import PSOANNIdentifier, load_plant, read_data_file, sine_data
    >>> est = PSOANNIdentifier(load_plant("g1"), method="pso")      # doctest: +SKIP
    >>> est.fit(sine_data(read_data_file("g1.h5"))).plant_.poles   # doctest: +SKIP
    ((-10.000000000...+0j),)
    """

    polish_iterations = MAX_POLISH_ITERATIONS  # Levenberg–Marquardt steps at most (a selection's screening: fewer)
    check_roughness = True  # roughness_ of a polished records fit (a selection checks only the one it chooses)
    search_deadline: float | None = None  # time.perf_counter() at which the swarm stops (a selection's budget)
    work_limit: float = WORK_LIMIT_HOURS  # hours the search may be estimated at (runtime.check_work)
    _reduced_crit = None  # a long open-loop record's criterion at its reduced rate: the polish's first descent
    start: tuple | None = None  # (lower, upper, y0) in target coordinates: a box and first particle from elsewhere
    # records: the polish first descends with the law's sign smoothed these many times wider, one after the other,
    # then with the structure's own (docs/broadband.md: long records of stick and slip have minima a stick event apart)
    smoothing_continuation: tuple = ()
    _smoothed_crits: tuple = ()
    # what the network reads where the fitted data are records: a broadband file's bands (broadband_ann)
    ann_data: SineData | None = None
    # records the swarm scores its particles on instead of the fitted records' search share (broadband data: every
    # level's first realisation, broadband_identify.level_pieces; the run's start holds the first level alone)
    search_data = None

    def __init__(self, structure: Plant, ann: AnnModel | None = None, method: str = "pso-ann",
                 pso: PsoOptions = PsoOptions(), polish: bool = True, box: float = 4.0, spread: float = 0.5,
                 seed: int = 0, threads: int | None = None, progress: Progress | None = None,
                 search_rtol: float = SEARCH_RTOL, restarts: RestartOptions = RestartOptions()):
        self.structure, self.ann, self.method, self.pso = structure, ann, method, pso
        self.search_rtol, self.restarts = search_rtol, restarts
        self.polish, self.box, self.spread, self.seed = polish, box, spread, seed
        self.threads, self.progress = threads, progress

    # ---- coordinates ------------------------------------------------------------------------------------
    def _to_theta(self, y: np.ndarray) -> np.ndarray:
        """Target coordinates (N, p) → identified parameters (N, p) in canonical order."""
        return canonical_order(self.structure, from_targets(self.structure, y))

    # ---- stage 1: the network --------------------------------------------------------------------------
    def _ann_estimate(self, data: SineData) -> tuple[np.ndarray, np.ndarray]:
        """The network's estimate and its search half-width, both in target coordinates."""
        names = identified_names(self.structure)
        layout = FeatureLayout(feature_names=feature_names(data.amplitudes.size), parameter_names=names,
                               plan=data.plan)
        self.ann.layout.check_compatible(layout, self.ann.source)
        x = ann_features(data.H[None], data.dc[None], data.amplitudes)
        y = self.ann.network.predict(x)[0]
        half = self.box * self.ann.network.validation_rmse * np.asarray(self.ann.network.y_scale)
        return y, half

    def ann_theta(self, data: SineData) -> np.ndarray:
        """The network's estimate of the identified parameters (the first stage alone).

        Parameters
        ----------
        data : SineData
            The stepped-sine data.

        Returns
        -------
        ndarray
            The estimate, in ``identified_names`` order.
        """
        y, _ = self._ann_estimate(data)
        return self._to_theta(y[None])[0]

    # ---- stage 2: the search ----------------------------------------------------------------------------
    def _search(self, cost, lower, upper, y0, seed):
        search = SEARCH_NAMES[self.method]
        if search == "pso":
            deadline = self.search_deadline
            stop = None if deadline is None else (lambda: time.perf_counter() > deadline)
            return search, minimize_pso(cost, lower, upper, self.pso, x0=y0, seed=seed, progress=self.progress,
                                        stop=stop)
        budget = self.pso.particles * (self.pso.iterations + 1)  # the swarm's number of model evaluations
        options = GaOptions(max_evaluations=budget) if search == "ga" else AdaptiveGaOptions(max_evaluations=budget)
        return search, minimize_ga(cost, lower, upper, options, x0=y0, seed=seed, progress=self.progress)

    # ---- the fit ---------------------------------------------------------------------------------------
    def _check(self, data) -> None:
        check_method(self.method)
        check_int("seed", self.seed, 0)
        check_work_limit(self.work_limit)
        if self.method in NEEDS_ANN and self.ann is None:
            raise UserError(f"method {self.method} needs a trained network (see `servofmu train`)")
        if self.method in NEEDS_ANN and not isinstance(self.ann_data or data, SineData):
            raise UserError("the ANN works on stepped-sine and broadband data; identify records with method pso")

    def _criterion(self, data):
        """What candidates are scored by: the data's own criterion when it brings one (closed-loop records)."""
        if isinstance(data, SineData):
            return SineCriterion(self.structure, data, BatchSimulator(self.structure, threads=self.threads))
        if isinstance(data, RecordData):
            return RecordCriterion(self.structure, data, BatchSimulator(self.structure, threads=self.threads))
        return data.criterion(self.structure, self.threads)

    def fit(self, data: SineData | RecordData) -> "PSOANNIdentifier":
        """Identify the structure's parameters from ``data``.

        Parameters
        ----------
        data : SineData, RecordData or ClosedLoopData
            Stepped-sine data (:func:`servofmu.sine_data`), time-domain records, or closed-loop records with their
            controller (servofmu.identification.closed_loop), which bring their own criterion.

        Returns
        -------
        PSOANNIdentifier
            ``self``, with the fitted attributes set.

        Raises
        ------
        UserError
            For an unknown method, a method that needs a network given none, or a network trained for another
            plan or structure.
        """
        self._check(data)
        self.data_ = data
        start = time.perf_counter()
        crit = self._criterion(data)
        # long records: the swarm on SEARCH_SAMPLES of them, the polish first on open-loop ones at a reduced rate
        reduced = long_open_loop(data)
        share = self.search_data if self.search_data is not None else search_share(data if reduced is None
                                                                                      else reduced)
        search = crit if share is data else self._criterion_of(share)
        self._reduced_crit = None if reduced is None else search if share is reduced else self._criterion_of(reduced)
        self._smoothed_crits = self._smoothed_criteria(data) if self.polish else ()
        self.names_ = identified_names(self.structure)

        def cost(y):
            return rms(search.residuals(self._to_theta(y), self.search_rtol))

        stages = []
        self._check_work(cost, search)
        if self.method in NEEDS_ANN:
            t0 = time.perf_counter()
            y0, half = self._ann_estimate(self.ann_data or data)
            stages.append(Stage("ann", self._to_theta(y0[None])[0], float(cost(y0[None])[0]),
                                time.perf_counter() - t0, 1))
            lower, upper = y0 - half, y0 + half
        else:
            lower, upper = prior_box(self.structure, self.spread)
            y0 = None
        if self.start is not None:  # broadband data: the box around the frequency-domain fit of G
            lower, upper, y0 = self.start

        fits = [self._search_and_polish(crit, cost, lower, upper, y0, self.seed, stages)]
        chosen = self._restart_while_above_floor(crit, cost, data, fits, (lower, upper), y0, stages)
        self.intervals_ = chosen.intervals
        self.covariance_ = chosen.covariance
        self.jacobian_ = chosen.jacobian
        self.search_jacobian_ = chosen.search_jacobian
        self.fit_percent_ = crit.fit_percent(chosen.theta, POLISH_RTOL) if crit.blocks is not None else None
        # records: whether the cost is as quadratic about the fit as its intervals assume (a chaotic response is not)
        self.roughness_ = self._roughness(crit, chosen) \
            if self.check_roughness and self.polish and crit.blocks is not None else math.nan
        self.theta_ = chosen.theta
        self.fitness_ = chosen.fitness
        self.history_ = chosen.history
        self.plant_ = self.structure.with_parameters(full_vectors(self.structure, self.theta_)[0])
        self.stages_ = stages
        self.seconds_ = time.perf_counter() - start
        self.evaluations_ = sum(c.evaluations for c in {id(c): c for c in (crit, search, self._reduced_crit,
                                                                            *self._smoothed_crits)
                                                        if c is not None}.values())
        return self

    def _roughness(self, crit, chosen) -> float:
        """The fit's roughness (roughness.response_roughness); a long open-loop record's on its reduced rate (the
        same information for white noise, docs/identification.md: 2p + 1 simulations of every sample were a quarter
        of a 10 kHz record's identification)."""
        covariance = finite_covariance(chosen.covariance, chosen.intervals)
        if self._reduced_crit is not None:
            return response_roughness(self._reduced_crit, chosen.theta, covariance, centred=True,
                                      information=curvature_at(self._reduced_crit, chosen.theta))
        return response_roughness(crit, chosen.theta, covariance,
                                  information=curvature(chosen.jacobian, crit.blocks, chosen.r))

    def _check_work(self, cost, search) -> None:
        """Refuse a search estimated (evaluations × one's measured time, up to a time budget) beyond the limit."""
        evaluations = self.pso.particles * (self.pso.iterations + 1) * (1 + self.restarts.restarts)
        if evaluations <= UNCHECKED_EVALUATIONS:
            return
        y = np.mean(prior_box(self.structure, self.spread), axis=0)[None]
        t0 = time.perf_counter()
        cost(np.repeat(y, WORK_SAMPLE, axis=0))
        seconds = (time.perf_counter() - t0) / WORK_SAMPLE * evaluations
        if self.search_deadline is not None:
            seconds = min(seconds, self.search_deadline - time.perf_counter())
        check_work(f"the search ({self.pso.particles} particles × {self.pso.iterations} iterations"
                   f"{' and its restarts' if self.restarts.restarts else ''})", seconds, self.work_limit,
                   "give fewer --iterations")

    def _criterion_of(self, data):
        """A criterion on a shortened form of the fitted data (shortening: the search's, the reduced polish's): the
        swarm finds the valley on SEARCH_SAMPLES of long records, the polish descends it on a long open-loop
        record at the rate its input needs, then on every sample, starting at the bottom (a 10 kHz record of
        6·10⁵ samples: 60 polish simulations of every sample were 25 of 29 s)."""
        return PSOANNIdentifier._criterion(self, data)

    def _smoothed_criteria(self, data) -> tuple:
        """The records' criteria of the structure with its v_smooth times each of smoothing_continuation; none for
        other data or a law without a tanh sign."""
        names = self.structure.parameter_names()
        if not isinstance(data, RecordData) or "v_smooth" not in names:
            return ()
        out = []
        for factor in self.smoothing_continuation:
            full = self.structure.parameter_vector()
            full[names.index("v_smooth")] *= factor
            smoothed = self.structure.with_parameters(full)
            out.append(RecordCriterion(smoothed, data, BatchSimulator(smoothed, threads=self.threads)))
        return tuple(out)

    def _search_and_polish(self, crit, cost, lower, upper, guesses, seed, stages: list) -> "_Fit":
        """One search from ``guesses`` in the box and its polish, their stages appended to ``stages``."""
        t0 = time.perf_counter()
        search, result = self._search(cost, lower, upper, guesses, seed)
        y_best = result.position
        stages.append(Stage(search, self._to_theta(y_best[None])[0], float(result.cost), time.perf_counter() - t0,
                            int(result.evaluations)))
        time_domain = crit.blocks is not None
        if self.polish:
            counted = (crit, *self._smoothed_crits)  # the polish's simulations (the smoothed descents' too)
            t0, before = time.perf_counter(), sum(c.evaluations for c in counted)
            if self._reduced_crit is not None:
                y_best, _ = polish(self._reduced_crit, self._to_theta, y_best, self.polish_iterations)
            for smoothed in self._smoothed_crits:
                y_best, _ = polish(smoothed, self._to_theta, y_best, self.polish_iterations)
            y_best, jac_y = polish(crit, self._to_theta, y_best, self.polish_iterations)
            if time_domain and len(crit.blocks) > 1:  # weights from each signal's noise, then the fit again
                crit.reweight(self._to_theta(y_best[None]), POLISH_RTOL)
                y_best, jac_y = polish(crit, self._to_theta, y_best, self.polish_iterations)
            theta = self._to_theta(y_best[None])[0]
            r = crit.residuals(theta, POLISH_RTOL)[0]
            fitness = crit.relative_rms(theta, POLISH_RTOL) if time_domain else float(rms(r))
            stages.append(Stage("polish", theta, fitness, time.perf_counter() - t0,
                                sum(c.evaluations for c in counted) - before))
            # the polish's last Jacobian, taken from target to parameter coordinates, gives the intervals
            jac = jac_y @ target_jacobian(self.structure, y_best)
            if not np.all(np.isfinite(jac)) and np.all(np.isfinite(r)):  # a parameter at its domain's edge (fs = fc)
                jac = with_finite_columns(crit, theta, jac)
        else:
            theta, fitness = stages[-1].theta, stages[-1].fitness
            r = crit.residuals(theta, POLISH_RTOL)[0]
            jac = jac_y = central_jacobian(crit, theta)
        cov, dof = covariance_from_jacobian(r, jac, crit.blocks, getattr(crit, "concurrent", None))
        return _Fit(theta=theta, y=y_best, r=r, fitness=fitness, history=result.cost_history,
                    intervals=intervals_from_covariance(theta, cov, dof, jac),
                    covariance=with_free_directions(cov, jac), jacobian=jac, search_jacobian=jac_y)

    def _restart_while_above_floor(self, crit, cost, data, fits: list, box, y0, stages: list) -> "_Fit":
        """Search again while the best fit is above the noise floor (servofmu.identification.restarts), until a
        fit reaches it, two fits agree or the budget is spent; the fit kept: the best, or the first fit that
        agrees with it (a restart that only confirms the first fit leaves the result as it was)."""
        opts, p = self.restarts, len(self.names_)

        def same(i: int, j: int) -> bool:  # one minimum found twice (fits that failed to simulate are none)
            a, b = fits[i], fits[j]
            return bool(np.isfinite(a.fitness) and np.isfinite(b.fitness) and fits_agree(
                a.theta, noise_half_widths(a.intervals, tests[i]), b.theta, noise_half_widths(b.intervals, tests[j]),
                opts.agree_rtol))

        tests = [floor_test(data, fits[0].r, p, opts)]
        best, agreed = 0, False
        while tests[best] is not None and not tests[best].at_floor and not agreed and len(fits) <= opts.restarts:
            k = len(fits)
            guesses = y0 if y0 is None else np.vstack([y0, self._neighbour_estimate(data, fits[best], y0)])
            guesses = guesses if guesses is None else guesses[:self.pso.particles]
            t0, before, inner = time.perf_counter(), crit.evaluations, []
            fits.append(self._search_and_polish(crit, cost, *restart_box(k, *box), guesses, restart_seed(self.seed, k),
                                                inner))
            tests.append(floor_test(data, fits[-1].r, p, opts))
            stages.append(Stage(f"restart {k}", fits[-1].theta, fits[-1].fitness, time.perf_counter() - t0,
                                crit.evaluations - before))
            best = min(range(len(fits)), key=lambda i: (fits[i].fitness, i))
            agreed = any(i != best and same(i, best) for i in range(len(fits)))
        kept = next(i for i in range(len(fits)) if i == best or same(i, best))
        self.restarts_ = len(fits) - 1
        self.floor_ = tests[kept]
        if tests[kept] is not None and not tests[kept].at_floor and not agreed and self.restarts_:
            warnings.warn(f"the fit stayed above the noise floor after {self.restarts_} restarts (residuals "
                          f"{tests[kept].ratio:.3g} times the noise) and no two searches agreed: the structure may "
                          "not fit the data, or a larger budget may find its minimum", ServofmuWarning, stacklevel=3)
        return fits[kept]

    def _neighbour_estimate(self, data: SineData, fit: "_Fit", y0: np.ndarray) -> np.ndarray:
        """The network's estimate corrected by its own error at the fitted plant: the network's reading of the
        fit's simulated features (recovered from its residuals) against the fit itself, subtracted from its
        reading of the data — the estimate of a plant beside the fit, where the network may read better."""
        n = data.amplitudes.size
        scale = np.abs(data.H)
        H = data.H + (fit.r[:n] + 1j * fit.r[n:2 * n]) * scale
        dc = data.dc + fit.r[2 * n:] * scale * data.amplitudes / np.sqrt(2)
        read = self.ann.network.predict(ann_features(H[None], dc[None], data.amplitudes))[0]
        estimate = y0 + (fit.y - read)
        return np.where(np.isfinite(estimate), estimate, y0)

    def result(self, provenance: dict | None = None) -> Result:
        """The fitted identification as a :class:`~servofmu.identification.results.Result` (what :func:`servofmu.write_result` stores).

        Parameters
        ----------
        provenance : dict, optional
            Where the data came from, the command, the date: stored with the result.

        Returns
        -------
        Result
            The identified plant, its intervals, fitness and stages.
        """
        return result_from_estimator(self, self.method, dict(provenance or {}))


def swarm_options(iterations: int | None = None) -> PsoOptions:
    """The paper's swarm (Table I), with ``iterations`` instead of its 50 when given (`identify --iterations`)."""
    if iterations is None:
        return PsoOptions()
    check_int("--iterations (swarm iterations)", iterations, 0)
    return PsoOptions(iterations=iterations)
