"""`servofmu select`: which friction law, which order of G(s) — candidate structures fitted and ranked
(docs/selection.md).

Every candidate (servofmu.selection.candidates) is identified with the swarm alone (``method="pso"``: the ANN
would need a network trained per structure), from a box around the linear least-squares estimate of its G and
Coulomb levels (servofmu.selection.estimate), then polished.  Each fit is scored

- on the data it was fitted to by the Bayesian information criterion of its output-error residuals,
  BIC = Σ_k N_k·ln(2π·RSS_k/N_k) + N + p·ln N, the noise variance of every signal k (record, or the
  stepped-sine harmonics) estimated from its residuals (RSS_k/N_k, the maximum-likelihood estimate), p the
  identified parameters and N the residuals.  AIC (penalty 2p) is reported too but does not rank: a superfluous
  parameter lowers −2·ln L by a χ²(1) amount, which exceeds AIC's 2 in 16 % of fits, and BIC's ln N (7.6 for
  2000 samples) in under 1 %;
- on data it was not fitted to (the validation file): its fit % there (identification.criterion.fit_percent,
  as ``validate``), the same −2·ln L on the validation residuals, and for records the residual tests of
  ``validate`` (identification.residuals: whiteness and independence of the input for open-loop records,
  independence of the reference in a closed loop);
- by its 95 % intervals: a parameter whose interval is wider than twice its value (the interval reaches past
  zero) or unbounded is not determined by the data;
- by its roots: a zero within CANCELLATION (relative) of a pole cancels it, the pair has no response of its own.

The ranking: candidates whose fit failed come last; before them those with a flag — validation −2·ln L more
than VALIDATION_MARGIN above the best candidate's, a parameter not determined, a pole-zero cancellation, or
residual tests failed where another candidate passes them; each group in the order of BIC.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import UserError
from ..identification.criterion import POLISH_RTOL, SineData, fit_percent
from ..identification.identifier import PSOANNIdentifier, swarm_options
from ..identification.residuals import residual_test
from ..identification.results import Result
from ..model.plant import Plant
from .candidates import Candidate
from .data import criterion_for, data_kind

__all__ = ["SelectOptions", "CandidateJob", "CandidateScore", "fit_candidate", "rank", "VALIDATION_MARGIN",
           "DEFAULT_SPREAD"]

# Validation −2·ln L a candidate may lose to the best one before it is flagged: the 99.9 % quantile of χ²(1),
# what one parameter's estimation error costs a right model on new data far less often than that.
VALIDATION_MARGIN = 10.83
DEFAULT_SPREAD = 1.5  # the swarm's box: factors in [1/2.5, 2.5] around the linear estimate
CANCELLATION = 0.1  # a zero this close to a pole (relative) cancels it: the pair is flagged


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
    closed_loop : str, optional
        The controller file of closed-loop records.
    """

    candidates: tuple[str, ...] | None = None
    orders: tuple[int, ...] = (1, 2, 3)
    seed: int = 0
    iterations: int | None = None
    spread: float = DEFAULT_SPREAD
    skip: float = 0.0
    closed_loop: str | None = None


@dataclass(frozen=True)
class CandidateJob:
    """One candidate's fit, as sent to a worker: its start plant, the fitted and the validation data."""

    candidate: Candidate
    start: Plant
    data: object
    validation: object
    options: SelectOptions
    threads: int | None
    provenance: dict


@dataclass(frozen=True)
class CandidateScore:
    """A candidate's fit and scores.  ``status`` "fitted" or "failed" (``message`` says why); ``result`` the
    identification; ``parameters`` p; ``samples`` N; ``neg2loglik``, ``aic``, ``bic`` on the fitted data;
    ``validation_fit`` (%, per signal), ``validation_neg2loglik``; ``white``: the residual tests on the validation
    records passed (None: not tested, stepped-sine data); ``undetermined``: names of parameters the data does not
    determine; ``flags`` and ``rank`` (1 = chosen) set by :func:`rank`."""

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
    flags: tuple[str, ...] = ()
    rank: int = 0

    @property
    def name(self) -> str:
        """The candidate's name."""
        return self.candidate.name

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


def _neg2loglik(errors: list[np.ndarray]) -> tuple[float, int]:
    """−2·ln L of Gaussian residuals with every signal's variance estimated (its mean square), and N."""
    total, n = 0.0, 0
    for e in errors:
        rss = float(e @ e)
        if not np.isfinite(rss):
            return math.inf, n
        total += e.size * (math.log(2 * math.pi * max(rss / e.size, 1e-300)) + 1)
        n += e.size
    return total, n


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
    """Parameters whose 95 % interval is unbounded or reaches past zero (half-width above the value)."""
    lo, hi = result.intervals[:, 0], result.intervals[:, 1]
    half = (hi - lo) / 2
    bad = ~np.isfinite(half) | (half >= np.abs(result.theta))
    return tuple(n for n, b in zip(result.names, bad) if b)


def fit_candidate(_, job: CandidateJob) -> CandidateScore:
    """Worker task: fit one candidate and score it; any failure becomes a failed score (it never stops the
    others)."""
    start = time.perf_counter()
    try:
        with np.errstate(all="ignore"):  # candidates far off the data overflow on their way out of the search
            return _fitted(job, start)
    except Exception as exc:  # noqa: BLE001 — one candidate's failure, whatever it is, must not stop the others
        text = " ".join(str(exc).split()) or type(exc).__name__
        return CandidateScore(candidate=job.candidate, status="failed", message=f"{type(exc).__name__}: {text}"
                              if not isinstance(exc, UserError) else text, seconds=time.perf_counter() - start)


class _CandidateIdentifier(PSOANNIdentifier):
    """The identifier with the selection's criterion: records simulated within a step budget
    (data.BoundedSimulator), so that a candidate whose simulation chatters cannot hold up the selection."""

    def _criterion(self, data):
        self.criterion_ = criterion_for(self.structure, data, self.threads)
        return self.criterion_


def _fitted(job: CandidateJob, start: float) -> CandidateScore:
    """The fit and scores of one candidate (exceptions to the caller)."""
    est = _CandidateIdentifier(job.start, method="pso", pso=swarm_options(job.options.iterations),
                               spread=job.options.spread, seed=job.options.seed, threads=job.threads).fit(job.data)
    result = est.result(dict(job.provenance, candidate=job.candidate.name))
    theta = np.asarray(est.theta_, dtype=float)
    fitted = _signal_errors(criterion_for(job.start, job.data, job.threads), job.data, theta)
    neg2, n = _neg2loglik([e for _, e in fitted])
    crit_v = criterion_for(job.start, job.validation, job.threads)
    validated = _signal_errors(crit_v, job.validation, theta)
    names = [name for name, _ in crit_v.signals()] if crit_v.blocks is not None else ["harmonics"]
    val_neg2, _ = _neg2loglik([e for _, e in validated])
    p = theta.size
    stopped = getattr(getattr(est.criterion_, "simulator", None), "stopped", 0)
    return CandidateScore(
        candidate=job.candidate, status="fitted", result=result, parameters=p, samples=n, neg2loglik=neg2,
        message=f"{stopped} simulations stopped at the step budget or failed" if stopped else "",
        aic=neg2 + 2 * p, bic=neg2 + p * math.log(max(n, 1)),
        validation_fit={k: fit_percent(y, e) for k, (y, e) in zip(names, validated)},
        validation_neg2loglik=val_neg2, white=_whiteness(crit_v, job.validation, validated),
        undetermined=_undetermined(result), seconds=time.perf_counter() - start)


def _cancelling(result: Result | None, within: float = CANCELLATION) -> bool:
    """Whether a zero of the fitted G lies within ``within`` (relative) of one of its poles: the pair nearly
    cancels, and adds parameters without a response of its own."""
    if result is None:
        return False
    poles, zeros = result.plant.all_poles(), result.plant.all_zeros()
    return any(abs(z - p) <= within * abs(p) for z in zeros for p in poles)


def rank(scores: list[CandidateScore]) -> list[CandidateScore]:
    """The candidates in rank order with their flags and ranks set (see the module's docstring)."""
    from dataclasses import replace

    fitted = [s for s in scores if s.status == "fitted" and np.isfinite(s.bic)]
    best_val = min((s.validation_neg2loglik for s in fitted), default=math.nan)
    any_white = any(s.white for s in fitted)
    out = []
    for s in scores:
        if s not in fitted:
            out.append(replace(s, flags=("fit failed",) if s.status == "failed" else ("not finite",)))
            continue
        flags = []
        if not s.validation_neg2loglik <= best_val + VALIDATION_MARGIN:
            flags.append("validation")
        if s.undetermined:
            flags.append("undetermined")
        if _cancelling(s.result):
            flags.append("pole-zero cancellation")
        if any_white and s.white is False:
            flags.append("residuals")
        out.append(replace(s, flags=tuple(flags)))
    key = lambda s: (s.status != "fitted" or not np.isfinite(s.bic), bool(s.flags),  # noqa: E731
                     s.bic if np.isfinite(s.bic) else math.inf, s.parameters, s.name)
    return [replace(s, rank=i + 1) for i, s in enumerate(sorted(out, key=key))]
