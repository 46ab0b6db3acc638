"""`servofmu select`: which friction law, which order of G(s) — candidate structures fitted and ranked
(docs/selection.md).

Every candidate (servofmu.selection.candidates) is identified with the swarm alone (``method="pso"``: the ANN
would need a network trained per structure), from a box around the linear least-squares estimate of its G and
Coulomb levels (servofmu.selection.estimate), then polished.  Each fit is scored

- on the data it was fitted to by the Bayesian information criterion of its output-error residuals,
  BIC = Σ_k N_k·ln(2π·RSS_k/N_k) + N + p·ln N (a searched ripple period counting as SEARCHED_PERIOD
  parameters), the noise variance of every signal k (record, or the stepped-sine harmonics) estimated from its
  residuals (RSS_k/N_k, the maximum-likelihood estimate), p the identified parameters and N the residuals.  AIC
  (penalty 2p) is reported too but does not rank: a superfluous parameter lowers −2·ln L by a χ²(1) amount,
  which exceeds AIC's 2 in 16 % of fits, and BIC's ln N (7.6 for 2000 samples) in under 1 %;
- on data it was not fitted to (the validation file): its fit % there (identification.criterion.fit_percent,
  as ``validate``), the same −2·ln L on the validation residuals, and for records the residual tests of
  ``validate`` (identification.residuals: whiteness and independence of the input for open-loop records,
  independence of the reference in a closed loop);
- by its 95 % intervals: a parameter whose interval is wider than twice its value (the interval reaches past
  zero) or unbounded is not determined by the data;
- by its roots: a zero within CANCELLATION (relative) of a pole cancels it, the pair has no response of its own;
  a zero at the origin is a spring's (candidates.spring_form), and the structure with the spring is fitted too.

The ranking: candidates whose fit failed come last; before them those with a flag — validation −2·ln L more
than validation_margin(p) (the 99.9 % quantile of χ²(p)) above the best candidate's, or, for records and a
candidate within STRONG_EVIDENCE of the best BIC, more than its validation_allowance if that is larger (the
quantile of its own estimation error's cost on the validation record), a parameter not determined,
a pole-zero cancellation, a zero at the origin whose spring was fitted, or residual tests failed where another
candidate without a flag passes them with a BIC at most STRONG_EVIDENCE above; each group in the order of BIC.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..display import Shown, figure, options_html, options_repr, shown_html, shown_repr
from ..errors import UserError
from ..identification.confounding import interval_quantile
from ..identification.criterion import POLISH_RTOL, SineData, fit_percent
from ..identification.identifier import PSOANNIdentifier, swarm_options
from ..identification.prior import identified_names
from ..identification.residuals import residual_test
from ..identification.restarts import RestartOptions
from ..identification.results import Result
from ..identification.roughness import curvature, neg2loglik
from ..identification.roughness import response_roughness as roughness_of
from ..identification.search import OptimizeResult
from ..model.plant import Plant
from ..runtime import WORK_LIMIT_HOURS
from .candidates import Candidate, spring_form
from .data import criterion_for, data_kind, without_quantiser
from .period import SEARCHED_PERIOD, continued_start, ripple_start
from .screening import screen_bound, screening_jacobian
from .validation import SCREEN_RTOL, validation_allowance, validation_margin

__all__ = ["SelectOptions", "CandidateJob", "CandidateScore", "fit_candidate", "start_neg2loglik", "rank",
           "searches_ripple", "screen_bound", "could_win", "cancels", "validation_margin", "validation_allowance",
           "response_roughness", "DEFAULT_SPREAD", "DEFAULT_BUDGET", "SCREEN_RTOL", "SCREEN_MARGIN"]

LOCATION_PARAMETERS = ("x0", "ripple_phase")  # where zero is a value like any other (not "undetermined")
# The Coulomb levels are tested by their mean: no candidate has a law without one side, and their difference is
# a constant force while the axis moves, which a load's offset or a spring's rest position shares (where a fit
# lands along that valley decided whether one level's interval reached zero: coulomb1_spring seed 7, the truth's
# fit at fc− 0.01 ± 0.07 N, another of the same cost at 0.40)
COULOMB_LEVELS = ("fc_pos", "fc_neg")
DEFAULT_SPREAD = 1.5  # the swarm's box: factors in [1/2.5, 2.5] around the linear estimate
# Searches after the first of a candidate whose stepped-sine fit stays above the noise floor (the identifier's: up
# to 6, until two agree).  A wrong structure never reaches the floor and its searches never agree, so each took
# seven: on noise-free g1 data the default selection spent 350 s of CPU, 300 of them in the restarts of the 14
# structures that are not g1's.  One more search keeps a second chance for a right structure whose swarm missed,
# beside the starts the selection hands on from the other candidates' fits.
SELECT_RESTARTS = 1
# The seconds a candidate's swarm may take (SelectOptions.budget): the benchmark's slowest swarm took 10 s, a
# drive log's 5 s; a candidate whose simulations crawl (a stiff LuGre loop, a third-order chattering one) is cut
# there rather than holding up the selection
DEFAULT_BUDGET = 60.0
CANCELLATION = 0.1  # a zero this close to a pole (relative) cancels it: the pair is flagged
# The screening fit's swarm tolerance (the identifier's SEARCH_RTOL is 1e-5): a quarter less time per simulation,
# and the swarm only ranks its particles, whose costs differ by far more than 1e-4 of the signal.
SCREEN_SEARCH_RTOL = 1e-4
# The screening polish's Levenberg–Marquardt steps at most (the identifier's: 20): a fit that needs more is far from
# its minimum after them, and its bic_bound (one Gauss–Newton step more) says whether a full polish could win.
SCREEN_POLISH_ITERATIONS = 10
# What a candidate's screened BIC, less the Gauss–Newton gain a full polish could still make (screen_bound), may
# exceed the chosen candidate's final BIC by and still be polished in full: a margin for the gain's linearisation.
SCREEN_MARGIN = 20.0
# A BIC this much below another's: the data favour its structure by odds over 150:1 ("very strong", Kass & Raftery
# 1995).  A failed residual test flags a candidate only where one that passes is not worse by more: that is far
# more than a test at the 1 % level fails by chance on a right structure (coulomb1_spring seed 7: the truth,
# failing on its validation record, lost to the only candidates that passed, undetermined ones 10 to 24 worse by
# BIC).  And a candidate more than this above the best BIC is no right structure, whose estimation error alone
# would explain a validation loss (validation_allowance).
STRONG_EVIDENCE = 10.0


@dataclass(frozen=True)
class SelectOptions:
    """What a selection computes.

    Parameters
    ----------
    candidates : tuple of str, optional
        Candidate names (servofmu.selection.candidates.parse_candidates: ``coulomb``, ``stribeck+offset``,
        ``lugre/2z``); None: the default set.
    orders : tuple of int
        The orders of G(s) a law without an order is tried at (with and without a zero).
    seed : int
        Seed of every candidate's swarm.
    iterations : int, optional
        Swarm iterations per candidate (None: the paper's 50).
    spread : float
        The swarm's box around each candidate's linear estimate: factors in [1/(1+spread), 1+spread].
    skip : float
        Seconds left out at the start of every record.
    closed_loop : str or ControllerSpec, optional
        The controller file of closed-loop records.
    screen : bool
        Records: fit every candidate with its polish at SCREEN_RTOL first, and polish again at the identifier's
        tolerance only the candidates whose screened BIC could still win (docs/selection.md); False: every
        candidate at the full tolerance.
    budget : float
        Seconds a candidate's swarm may take: it stops at the iteration that passes them, the polish goes on from
        its best, and the candidate's row says so (its fit then depends on the machine's speed).
    work_limit : float
        Hours the selection may be estimated at: the candidates' swarms at most ``budget`` each
        (servofmu.runtime.check_work).
    """

    candidates: tuple[str, ...] | None = None
    orders: tuple[int, ...] = (1, 2, 3)
    seed: int = 0
    iterations: int | None = None
    spread: float = DEFAULT_SPREAD
    skip: float = 0.0
    closed_loop: object = None  # a controller file's path, or a ControllerSpec
    screen: bool = True
    budget: float = DEFAULT_BUDGET
    work_limit: float = WORK_LIMIT_HOURS

    _units = {"skip": "s", "budget": "s", "work_limit": "h"}
    __repr__, _repr_html_ = options_repr, options_html


@dataclass(frozen=True)
class CandidateJob:
    """One candidate's fit, as sent to a worker: its start plant, the fitted and the validation data; ``mode``
    "full" (swarm and polish at the identifier's tolerances), "screen" (swarm, polish at SCREEN_RTOL) or "refit"
    (the polish alone at the identifier's tolerances, from ``start``: a screened fit's plant); ``seeded``: the
    start is a fit, made the swarm's first particle; ``polished``: the start is a fit of this structure (a larger
    candidate's without the roots beyond the data): the polish alone from it; ``continued``: the start is first
    polished on growing shares of the records (selection.period.continued_start).  A ripple at zero force in the
    start is first put where the fitted data's residuals show one (selection.period), and the polish starts there
    without a swarm."""

    candidate: Candidate
    start: Plant
    data: object
    validation: object
    options: SelectOptions
    threads: int | None
    provenance: dict
    mode: str = "full"
    seeded: bool = False  # the start is a fit (a larger candidate's, the parent's): the swarm's first particle
    polished: bool = False  # the start is a fit of this structure: no swarm, the polish alone from it
    continued: bool = False  # the start polished on growing shares of the records first (period.continued_start)
    covariance: np.ndarray | None = None  # the start's covariance, where it is a fit (response_roughness)
    information: np.ndarray | None = None  # and its cost's Gauss–Newton curvature (roughness.curvature)


@dataclass(frozen=True)
class CandidateScore:
    """A candidate's fit and scores.  ``status`` "fitted" or "failed" (``message`` says why); ``result`` the
    identification; ``parameters`` p; ``samples`` N; ``neg2loglik``, ``aic``, ``bic`` on the fitted data;
    ``validation_fit`` (%, per signal), ``validation_neg2loglik``; ``white``: the residual tests on the validation
    records passed (None: not tested, stepped-sine data); ``undetermined``: names of parameters the data does not
    determine; ``screened``: the scores are those of the screening fit (polish at SCREEN_RTOL), ``bic_bound`` then
    the lowest BIC a full polish could reach from it (:func:`screen_bound`); ``flags`` and ``rank`` (1 = chosen)
    set by :func:`rank`."""

    candidate: Candidate
    status: str
    message: str = ""
    result: Result | None = None
    parameters: int = 0
    samples: int = 0
    neg2loglik: float = math.nan
    aic: float = math.nan
    bic: float = math.nan
    validation_fit: dict = field(default_factory=dict)
    validation_neg2loglik: float = math.nan
    white: bool | None = None
    undetermined: tuple[str, ...] = ()
    seconds: float = math.nan
    screened: bool = False
    bic_bound: float = math.nan
    validation_allowance: float = math.nan
    flags: tuple[str, ...] = ()
    rank: int = 0
    information: np.ndarray | None = None  # the fit's Gauss–Newton curvature of −2·ln L (roughness.curvature)

    @property
    def name(self) -> str:
        """The candidate's name."""
        return self.candidate.name

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return Shown(type(self).__name__, f"#{self.rank} {self.name!r}: {self.status}, {self.parameters} parameters",
                     (figure("BIC", self.bic, "", ".6g"), figure("worst validation fit", self.worst_validation_fit, "%",
                                                                 ".4g"), figure("time", self.seconds, "s", ".3g")),
                     notes=tuple(x for x in (self.message, ", ".join(self.flags)) if x))

    @property
    def worst_validation_fit(self) -> float:
        """The lowest validation fit (%) over the signals (NaN without one)."""
        return min(self.validation_fit.values()) if self.validation_fit else math.nan


def _signal_errors(crit, data, theta: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(measured, model − measured) of every signal at ``theta``: per record signal, or the stepped-sine
    harmonics as one signal (the response phasors H and mean velocities, in the criterion's relative units)."""
    if isinstance(data, SineData):
        r = crit.residuals(theta[None], POLISH_RTOL)[0]
        n = data.H.size
        scale = np.abs(data.H)
        measured = np.concatenate([data.H.real, data.H.imag])
        return [(measured, np.concatenate([r[:n] * scale, r[n:2 * n] * scale]))]
    signals = crit.signals()
    return [(y, e[0]) for (_, y), e in zip(signals, crit.errors(theta[None], POLISH_RTOL))]


def _whiteness(crit, data, errors) -> bool | None:
    """The validation records' residual tests (validate's, bounds joint over every function tested); None for
    stepped-sine data."""
    kind = data_kind(data)
    if kind == "sine":
        return None
    if kind == "records":
        inputs = [(r.u[r.fitted], True) for r in data.records]
    else:  # closed loop: position and force per record, tested against the reference only
        inputs = [(r.reference[r.fitted], False) for r in data.records for _ in range(2)]
    functions = sum(2 if white else 1 for _, white in inputs)
    ok = True
    for (y, e), (u, white) in zip(errors, inputs):
        test = residual_test(e, u, y, functions=functions)
        ok = ok and (test.passed if white else test.independent)
    return ok


def _undetermined(result: Result) -> tuple[str, ...]:
    """Parameters whose 95 % interval is unbounded or reaches past zero (half-width above the value); past zero
    is no test for a position or a phase (LOCATION_PARAMETERS: a spring's rest position at 0 is no spring's
    absence), and the Coulomb levels reach past zero only where their mean does (COULOMB_LEVELS)."""
    lo, hi = result.intervals[:, 0], result.intervals[:, 1]
    half = (hi - lo) / 2
    names = list(result.names)
    location = np.isin(names, LOCATION_PARAMETERS)
    past_zero = half >= np.abs(result.theta)
    if set(COULOMB_LEVELS) <= set(names) and result.covariance is not None:
        i, j = names.index(COULOMB_LEVELS[0]), names.index(COULOMB_LEVELS[1])
        cov = np.asarray(result.covariance)
        mean = (result.theta[i] + result.theta[j]) / 2
        sd = math.sqrt(max(cov[i, i] + cov[j, j] + cov[i, j] + cov[j, i], 0.0)) / 2
        past_zero[[i, j]] = interval_quantile(cov, result.intervals) * sd >= abs(mean)
    bad = ~np.isfinite(half) | (past_zero & ~location)
    return tuple(n for n, b in zip(names, bad) if b)


def fit_candidate(_, job: CandidateJob) -> CandidateScore:
    """Worker task: fit one candidate and score it; any failure becomes a failed score (it never stops the
    others)."""
    start = time.perf_counter()
    try:
        # warnings are about this candidate's fit: its row says them (a selection's output is the table)
        with np.errstate(all="ignore"), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            score = _fitted(job, start)
        said = sorted({str(w.message).splitlines()[0] for w in caught})
        return replace(score, message="; ".join([score.message] * bool(score.message) + said))
    except Exception as exc:  # noqa: BLE001 — one candidate's failure, whatever it is, must not stop the others
        text = " ".join(str(exc).split()) or type(exc).__name__
        return CandidateScore(candidate=job.candidate, status="failed", message=f"{type(exc).__name__}: {text}"
                              if not isinstance(exc, UserError) else text, seconds=time.perf_counter() - start)


def searches_ripple(job: CandidateJob) -> bool:
    """Whether the fit begins with a ripple's search (selection.period.ripple_start): a ripple term at zero force
    in the start (None where the structure has none), in any mode but a refit."""
    return job.start.load.ripple_amplitude == 0 and job.mode != "refit"


def response_roughness(_, job: CandidateJob) -> float:
    """Worker task: identification.roughness.response_roughness of the fit ``job.start`` with its covariance
    ``job.covariance`` on the fitted data (NaN where it cannot be checked)."""
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            crit = criterion_for(job.start, job.data, job.threads)
            theta = np.array([job.start.parameters()[k] for k in identified_names(job.start)], dtype=float)
            return roughness_of(crit, theta, job.covariance, information=job.information)
    except Exception:  # noqa: BLE001 — a check that cannot be made says nothing
        return math.nan


def start_neg2loglik(_, job: CandidateJob) -> float:
    """Worker task: −2·ln L of the fitted data at the values of ``job.start`` (inf where they cannot be
    simulated), at the polish's tolerance."""
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            crit = criterion_for(job.start, job.data, job.threads)
            theta = np.array([job.start.parameters()[k] for k in identified_names(job.start)], dtype=float)
            value, _ = neg2loglik([e for _, e in _signal_errors(crit, job.data, theta)])
    except Exception:  # noqa: BLE001 — a start that cannot be scored is no better than the fit it would replace
        return math.inf
    return value if np.isfinite(value) else math.inf


class _CandidateIdentifier(PSOANNIdentifier):
    """The identifier with the selection's criterion: records simulated within a step budget
    (data.BoundedSimulator), so that a candidate whose simulation chatters cannot hold up the selection; no
    tolerance below ``rtol_floor`` (the screening fit's); with ``seeded`` the structure's own values (a fit) are
    the swarm's first particle; with ``from_start`` no search: the polish starts there (a screened fit polished
    again)."""

    rtol_floor = 0.0
    from_start = False
    seeded = False
    check_roughness = False  # the selection checks the candidate it chooses (run._roughness)

    def _criterion(self, data):
        self.criterion_ = criterion_for(self.structure, data, self.threads)
        if hasattr(getattr(self.criterion_, "simulator", None), "rtol_floor"):
            self.criterion_.simulator.rtol_floor = self.rtol_floor
        return self.criterion_

    def _criterion_of(self, data):
        """As the identifier's, simulated within the step budget at the fit's tolerance floor."""
        crit = criterion_for(self.structure, data, self.threads)
        crit.simulator.rtol_floor = self.rtol_floor
        return crit

    def _search(self, cost, lower, upper, y0, seed):
        centre = (lower + upper) / 2  # the prior box's centre: the structure's values
        if not self.from_start:  # a start that is a fit is a particle: the search ends no worse than the fit
            return super()._search(cost, lower, upper, centre if self.seeded and y0 is None else y0, seed)
        c = float(cost(centre[None])[0])
        return "start", OptimizeResult(position=centre, cost=c, cost_history=np.array([c]),
                                       position_history=centre[None], evaluations=1, iterations=0,
                                       stopped_early=False)


def _fitted(job: CandidateJob, start: float) -> CandidateScore:
    """The fit and scores of one candidate (exceptions to the caller)."""
    if job.mode == "screen":  # a screening fit's loops without the encoder's quantiser (data.without_quantiser)
        job = replace(job, data=without_quantiser(job.data), validation=without_quantiser(job.validation))
    searched = searches_ripple(job)
    if searched:
        found = ripple_start(job.start, job.data, job.threads)
        searched, job = found is not job.start, replace(job, start=found)
    elif job.continued:
        job = replace(job, start=continued_start(job.start, job.data, job.threads))
    est = _CandidateIdentifier(job.start, method="pso", pso=swarm_options(job.options.iterations),
                               spread=job.options.spread, seed=job.options.seed, threads=job.threads,
                               restarts=RestartOptions(restarts=SELECT_RESTARTS),
                               **({"search_rtol": SCREEN_SEARCH_RTOL} if job.mode == "screen" else {}))
    est.rtol_floor = SCREEN_RTOL if job.mode == "screen" else 0.0
    if job.mode == "screen":
        est.polish_iterations = SCREEN_POLISH_ITERATIONS
    # a searched ripple's start is in its valley, whose width in the period is a fraction of the swarm's box: the
    # polish alone from there (a swarm's particles, scored at its coarser tolerance, led the polish to another)
    est.from_start = job.mode == "refit" or searched or job.polished
    est.seeded = job.seeded
    est.search_deadline = time.perf_counter() + job.options.budget
    est.work_limit = job.options.work_limit
    est.fit(job.data)
    swarm = len(est.history_) - 1  # the swarm's iterations (its first particles are the history's first entry)
    budget = f"time budget: the swarm stopped after {swarm} of {est.pso.iterations} iterations " \
             f"({job.options.budget:g} s)" if not est.from_start and swarm < est.pso.iterations and \
        time.perf_counter() > est.search_deadline else ""
    result = est.result(dict(job.provenance, candidate=job.candidate.name))
    theta = np.asarray(est.theta_, dtype=float)
    crit = est.criterion_  # its simulations of the fit are reused: the scores ask for the same errors
    crit_v = criterion_for(job.start, job.validation, job.threads)
    if hasattr(getattr(crit_v, "simulator", None), "rtol_floor"):
        crit_v.simulator.rtol_floor = est.rtol_floor
    fitted = _signal_errors(crit, job.data, theta)
    neg2, n = neg2loglik([e for _, e in fitted])
    validated = _signal_errors(crit_v, job.validation, theta)
    names = [name for name, _ in crit_v.signals()] if crit_v.blocks is not None else ["harmonics"]
    val_neg2, _ = neg2loglik([e for _, e in validated])
    p = theta.size
    penalty = (p + (SEARCHED_PERIOD - 1) * ("ripple_period" in result.names)) * math.log(max(n, 1))
    # the reachable drop is the same in any coordinates, and the search's are finite where a Stribeck bump has
    # collapsed (fs = fc: the parameters' Jacobian is not, and a bound of −inf sent every such fit to the full
    # polish — on coulomb1_fv seed 3 seven of them, one for 9.9 s, 3500 above the first by BIC)
    bound = screen_bound(*screening_jacobian(est.search_jacobian_, crit, job.data),
                         [e for _, e in fitted]) + penalty if job.mode == "screen" else math.nan
    undetermined = _undetermined(result)
    allowance = math.nan if undetermined or crit.blocks is None else validation_allowance(
        est.jacobian_, crit.scales, [e for _, e in fitted], crit_v, theta, [e for _, e in validated])
    stopped = getattr(getattr(est.criterion_, "simulator", None), "stopped", 0)
    return CandidateScore(
        candidate=job.candidate, status="fitted", result=result, parameters=p, samples=n, neg2loglik=neg2,
        message="; ".join(m for m in (budget, f"{stopped} simulations stopped at the step budget or failed"
                                       * bool(stopped)) if m),
        aic=neg2 + 2 * p, bic=neg2 + penalty,
        validation_fit={k: fit_percent(y, e) for k, (y, e) in zip(names, validated)},
        validation_neg2loglik=val_neg2, white=_whiteness(crit_v, job.validation, validated),
        undetermined=undetermined, seconds=time.perf_counter() - start, screened=job.mode == "screen",
        bic_bound=bound, validation_allowance=allowance,
        information=curvature(est.jacobian_, crit.blocks, np.concatenate([e / w for (_, e), w in
                                                                          zip(fitted, crit.scales)]))
        if crit.blocks is not None and est.jacobian_ is not None else None)


def could_win(score: CandidateScore, chosen: CandidateScore) -> bool:
    """Whether a screened candidate could still be chosen over ``chosen`` (the candidate ranked first) once
    polished in full: ``chosen`` itself, every candidate without a flag of its own when ``chosen`` is flagged (a
    flag decides before BIC), and every one whose lowest reachable BIC (``bic_bound``) less SCREEN_MARGIN is not
    above ``chosen``'s BIC.  ``score.flags`` are those :func:`rank` gave its screened fit: on a real axis's log
    every candidate may carry one (a model error thousands above the noise flags all but one on validation, and
    no structure has every parameter determined), and a flagged candidate far above the first by BIC stays below
    it once polished (before, every candidate was polished again there: 23 full polishes on a drive's log)."""
    if not score.screened or score.status != "fitted":
        return False
    return score.candidate == chosen.candidate or (bool(chosen.flags) and not score.flags) or not \
        score.bic_bound - SCREEN_MARGIN > chosen.bic


def _cancelling(result: Result | None, within: float = CANCELLATION) -> bool:
    """Whether a zero of the fitted G lies within ``within`` (relative) of one of its poles: the pair nearly
    cancels, and adds parameters without a response of its own."""
    if result is None:
        return False
    poles, zeros = result.plant.all_poles(), result.plant.all_zeros()
    return any(cancels(z, p, within) for z in zeros for p in poles)


def _spring_zero(score: CandidateScore, fitted: set) -> bool:
    """Whether the candidate's G has a zero at the origin whose reading as a spring (candidates.spring_form) was
    fitted too: the two are one response (a spring's is exactly such a zero), and the structure that names the
    force ranks before the one that hides it in G."""
    found = spring_form(score.candidate, score.result.plant) if score.result is not None else None
    return found is not None and found[0] in fitted


def cancels(zero: complex, pole: complex, within: float = CANCELLATION) -> bool:
    """Whether ``zero`` lies within ``within`` (relative) of ``pole``: the pair nearly cancels."""
    return abs(zero - pole) <= within * abs(pole)


def rank(scores: list[CandidateScore]) -> list[CandidateScore]:
    """The candidates in rank order with their flags and ranks set (see the module's docstring)."""
    fitted = [s for s in scores if s.status == "fitted" and np.isfinite(s.bic)]
    best_val = min((s.validation_neg2loglik for s in fitted), default=math.nan)
    best_bic = min((s.bic for s in fitted), default=math.nan)
    names = {f.candidate for f in fitted}
    flags = {}
    for s in fitted:
        # the validation loss a right structure's estimation error may cost: where the data do not reject the
        # structure (a BIC within STRONG_EVIDENCE of the best), its own allowance if that is larger
        allowed = validation_margin(s.parameters)
        if s.bic <= best_bic + STRONG_EVIDENCE and np.isfinite(s.validation_allowance):
            allowed = max(allowed, s.validation_allowance)
        flags[s.candidate] = [name for name, raised in (
            ("validation", not s.validation_neg2loglik <= best_val + allowed),
            ("undetermined", bool(s.undetermined)), ("pole-zero cancellation", _cancelling(s.result)),
            ("zero at the origin", _spring_zero(s, names))) if raised]
    # residual tests passed count only by a candidate without another flag (an undetermined one passes them by
    # fitting the noise) and with a BIC within STRONG_EVIDENCE of the one that fails them
    white_bics = [s.bic for s in fitted if s.white and not flags[s.candidate]]
    out = []
    for s in scores:
        if s not in fitted:
            out.append(replace(s, flags=("fit failed",) if s.status == "failed" else ("not finite",)))
            continue
        residuals = s.white is False and any(b <= s.bic + STRONG_EVIDENCE for b in white_bics)
        out.append(replace(s, flags=tuple(flags[s.candidate] + ["residuals"] * residuals)))
    key = lambda s: (s.status != "fitted" or not np.isfinite(s.bic), bool(s.flags),  # noqa: E731
                     s.bic if np.isfinite(s.bic) else math.inf, s.parameters, s.name)
    return [replace(s, rank=i + 1) for i, s in enumerate(sorted(out, key=key))]
