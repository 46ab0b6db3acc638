"""A selection's rounds of fits: the candidates of one or more groups of starts fitted in worker processes or on a
Dask cluster, the costliest first, and their scores merged with the rounds before."""
from __future__ import annotations

from dataclasses import replace

from ..model.laws.registry import get_law
from ..runtime import RunOptions, available_cores
from ..simulation.parallel import Workers
from .select import CandidateJob, CandidateScore, fit_candidate, searches_ripple

__all__ = ["SAME_FIT", "keep_better", "with_new", "fit_all", "fit_groups", "threads_per_job", "expected_cost"]

# A structure ranked first whose BIC moved by less than this between two rounds still has the same fit (a polish
# stops when a step gains less than a noise variance, ~1 in −2·ln L): load terms started from its earlier fit stand.
SAME_FIT = 2.0


def keep_better(scores: list[CandidateScore], again: list[CandidateScore]) -> list[CandidateScore]:
    """``scores`` with each candidate of ``again`` replaced where its new fit has the lower BIC."""
    better = {s.candidate: s for s in again if s.status == "fitted" and
              not any(o.candidate == s.candidate and o.status == "fitted" and o.bic <= s.bic for o in scores)}
    return [better.get(s.candidate, s) for s in scores]


def with_new(scores: list[CandidateScore], more: list[CandidateScore]) -> list[CandidateScore]:
    """``scores`` and the scores of ``more`` of candidates it does not have."""
    known = {s.candidate for s in scores}
    return scores + [s for s in more if s.candidate not in known]


def fit_all(pool: Workers, job: CandidateJob, starts: dict, run: RunOptions, done: list) -> list[CandidateScore]:
    """``done`` and the scores of the candidates of ``starts`` (a candidate without a start fails at once)."""
    return list(done) + fit_groups(pool, [(job, starts)], run, len(done))[0]


def fit_groups(pool: Workers, groups: list[tuple[CandidateJob, dict]], run: RunOptions, done: int
                ) -> list[list[CandidateScore]]:
    """The scores of the candidates of every (job, dict of starts) in ``groups``, each fitted as its group's job
    says, in one round (a candidate without a start fails at once), the costliest first (expected_cost) so that no
    long fit starts last; ``done`` candidates were fitted before (for the progress)."""
    out = [[CandidateScore(c, "failed", message=str(s)) for c, s in starts.items() if isinstance(s, Exception)]
           for _, starts in groups]
    jobs = [(g, replace(job, candidate=c, start=s)) for g, (job, starts) in enumerate(groups)
            for c, s in starts.items() if not isinstance(s, Exception)]
    spare = threads_per_job(pool, len(jobs))
    local = threads_per_job(pool, 1)
    # fewer fits than local workers: each fit's simulations on the idle cores too; a ripple's search (the longest
    # fit of its round, which mostly ends alone) on all of them from the start
    if local > 1:
        jobs = [(g, replace(j, threads=local if searches_ripple(j) or j.continued else spare)) for g, j in jobs]
    jobs.sort(key=lambda gj: expected_cost(gj[1]), reverse=True)
    total = done + sum(len(starts) for _, starts in groups)
    count = done + sum(map(len, out))
    run.report(count, total)
    for i, score in pool.imap(fit_candidate, [j for _, j in jobs]):
        out[jobs[i][0]].append(score)
        count += 1
        run.report(count, total)
    return out


def threads_per_job(pool: Workers, jobs: int) -> int:
    """The cores each of ``jobs`` fits may use on a local pool with more workers than fits (a round of one or two
    late candidates would leave cores idle: the batch simulator runs a swarm's particles and a Jacobian's columns
    on threads, with results that do not depend on their number); 1 otherwise, and on a Dask cluster."""
    if pool.scheduler is not None or pool.workers == 0 or jobs == 0:
        return 1
    return max(1, min(pool.workers, available_cores()) // jobs)


def expected_cost(job: CandidateJob) -> tuple:
    """A key that orders fits by their expected time: a ripple's search first, then a swarm before a polish
    alone, then by the order of G and its zeros (third-order fits with a zero take ten times a first-order one's
    time), then the law's cost (FrictionLaw.cost: its states and parameters; LuGre's stiff bristles)."""
    c = job.candidate
    swarm = job.mode != "refit" and not job.polished
    return searches_ripple(job), job.continued, swarm, c.order + c.zeros, get_law(c.law).cost, len(c.terms)
