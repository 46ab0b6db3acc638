"""The second stage's terms in a selection's rounds: the starts of the structure ranked first with each term the
data can rank, and the forward and backward steps of the friction terms (docs/selection.md, the candidates)."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..identification.residuals import EXACT
from ..runtime import RunOptions
from ..simulation.parallel import Workers
from .candidates import FRICTION_TERMS
from .data import data_kind
from .fitting import SAME_FIT, fit_all, keep_better, with_new
from .select import CandidateJob, CandidateScore, rank
from .starts import nested_law_starts, nested_structures, term_starts, without_terms

__all__ = ["ranked_term_starts", "more_friction_terms", "friction_terms_on_final", "nested_in_leaders",
           "fewer_friction_terms", "SCREENED_EXACT"]

# A screened fit is polished at the screening's coarser tolerance, whose floor lies above EXACT (noise-free g1's
# coulomb/1 stopped at 1.2e-7); 40 dB of noise leaves an RMS relative error near 1e-2, 80 dB near 1e-4.
SCREENED_EXACT = 100 * EXACT


def ranked_term_starts(first: CandidateScore, data) -> dict:
    """The second stage's starts (starts.term_starts) the data can rank, load and friction terms not combined, and
    no friction term where ``first`` reproduces the data exactly (its RMS relative error below EXACT: noise-free
    data, where a term can only move residuals at the simulation's precision, and a BIC of those picks at random:
    noise-free g1 chose coulomb+fv_asym/1 by 2.3); on stepped sines none that depend on the position — at zero
    force a spring leaves the position drifting, with no periodic steady state to converge to (each evaluation
    ran to the steady state's time limit: on noise-free g1 `coulomb+stiffness/1` took 118 of the selection's 264
    CPU seconds and was never fitted), and a ripple's period has no measured position to be searched along; a
    spring still enters a stepped-sine selection as the zero at the origin it puts in G (starts.spring_starts)."""
    exact = first.status == "fitted" and first.result.fitness <= (SCREENED_EXACT if first.screened else EXACT)
    starts = {c: p for c, p in term_starts(first).items()  # the two kinds not combined (more_friction_terms)
              if not set(c.terms) & set(FRICTION_TERMS) or (set(c.terms) <= set(FRICTION_TERMS) and not exact)}
    if data_kind(data) == "sine":
        starts = {c: p for c, p in starts.items() if not p.load.depends_on_position()}
    return starts


def more_friction_terms(pool: Workers, job: CandidateJob, scores: list[CandidateScore], data, run: RunOptions
                         ) -> list[CandidateScore]:
    """The forward selection of friction terms goes on while a structure with terms ranks first: its fit with each
    friction term it lacks, until one ranks first that has been extended already (or has them all).  A term can
    stand in for another in a richer law: on viscous_axis (Coulomb friction, fv_neg > fv_pos) the first stage
    ranks stribeck/2 first, which the shape exponent fits better still; only with both terms does the Stribeck bump
    leave, and coulomb+fv_asym/2 is nested in the winner (starts.nested_law_starts); fewer_friction_terms takes
    the step back once the nested structures are fitted.  Load terms are combined neither with each other (a
    ripple's search each time) nor with friction terms: a ripple's fit is a lottery among its period's valleys,
    and an added parameter can win one by chance (coulomb1_ripple seed 1 chose coulomb+ripple+fv_asym/1, and took
    2.4 times as long)."""
    extended = set()
    while True:
        first = rank(scores)[0]
        if not _extensible(first) or first.candidate in extended:
            return scores
        extended.add(first.candidate)
        done = {s.candidate for s in scores}
        starts = {c: p for c, p in _friction_starts(first, data).items() if c not in done}
        if not starts:
            return scores
        scores = fit_all(pool, job, starts, run, scores)


def _friction_starts(first: CandidateScore, data) -> dict:
    """ranked_term_starts of ``first`` that add a friction term only."""
    return {c: p for c, p in ranked_term_starts(first, data).items()
            if set(c.terms) - set(first.candidate.terms) <= set(FRICTION_TERMS)}


def _extensible(first: CandidateScore) -> bool:
    """Whether friction terms are tried on ``first``: fitted, with friction terms and no load term."""
    terms = set(first.candidate.terms)
    return first.status == "fitted" and bool(terms) and terms <= set(FRICTION_TERMS)


def friction_terms_on_final(pool: Workers, job: CandidateJob, scores: list[CandidateScore], data,
                             speeds: np.ndarray, run: RunOptions) -> list[CandidateScore]:
    """The friction terms again on the structure ranked first once the screened contenders are polished in full,
    where their fits started from another fit of it: the second stage starts from the first stage's screened
    leader, whose full polish can end far from there (stribeck_delta seed 0: lugre/1 screened 3 900 above its full
    polish, and lugre+delta/1, started from the screened fit, never reached it).  A term's structure is fitted
    again from the first's fit (polished alone) where it was not fitted or fits worse than the first (−2·ln L more
    than SAME_FIT above: a term added where it changes nothing only lowers it); where one then ranks first, the
    forward steps follow; the terms go on the structures of the first with the laws its law contains too
    (_nested_laws).  Then the structures nested in the leaders with friction terms (nested_in_leaders) and the
    backward step, as in the second stage.  Where a structure with a load term ranks first, the friction
    terms go on the first without one, where none was fitted on it: the second stage may have run on a law
    whose full polish then failed (stribeck_delta seed 6: every lugre refit without a steady state, and
    stribeck+ripple/1 first with stribeck+delta/1, the truth, never fitted)."""
    ranked = [s for s in rank(scores) if s.status == "fitted" and np.isfinite(s.neg2loglik)]
    first = next((s for s in ranked if set(s.candidate.terms) <= set(FRICTION_TERMS)), None)
    if first is None:
        return scores
    fitted = {s.candidate: s for s in ranked}
    worse = first.neg2loglik + SAME_FIT if first is ranked[0] else math.inf  # else: only those never fitted
    starts = {c: p for c, p in _friction_starts(first, data).items()
              if c not in fitted or fitted[c].neg2loglik > worse}
    for nested in _nested_laws(first, fitted):
        starts.update({c: p for c, p in _friction_starts(nested, data).items() if c not in fitted and c not in starts})
    if starts:
        again = fit_all(pool, job, starts, run, [])
        scores = with_new(keep_better(scores, again), again)
        if rank(scores)[0].candidate.terms and rank(scores)[0].candidate != first.candidate:
            scores = more_friction_terms(pool, job, scores, data, run)
    laws = nested_in_leaders(scores, speeds)
    scores = fit_all(pool, job, laws, run, scores) if laws else scores
    return fewer_friction_terms(pool, job, scores, run)


def _nested_laws(first: CandidateScore, fitted: dict) -> list[CandidateScore]:
    """The fits of the structures of ``first`` (its order, zeros and terms) with each law its law contains: a richer
    law's own parameters can stand in for a friction term of the law it contains (stribeck_delta seeds 7, 13, 18:
    lugre/1 ranked above stribeck/1 by the shape its bristle dynamics lent it, the shape exponent added to LuGre
    changed nothing, and stribeck+delta/1, the truth, was never fitted)."""
    top = first.candidate
    return [fitted[c] for c in nested_structures(top) if c in fitted and (c.order, c.zeros) == (top.order, top.zeros)]


def nested_in_leaders(scores: list[CandidateScore], speeds: np.ndarray) -> dict:
    """Starts of the structures nested in the candidate ranked first and in the one of the lowest BIC, where they
    have friction terms (starts.nested_law_starts), not fitted yet.  The lowest BIC's too: a term can stand in for
    another in a richer law, and the structure with every term may fit best and yet rank below a smaller one for
    a parameter the data do not determine — its Stribeck bump, where the truth is the Coulomb law with that term
    (viscous_axis seeds 1–4: stribeck+delta+fv_asym/2 lowest, undetermined, and coulomb+fv_asym/2 never fitted)."""
    fitted = [s for s in scores if s.status == "fitted" and np.isfinite(s.bic)]
    leaders = [rank(scores)[0], *sorted(fitted, key=lambda s: s.bic)[:1]]
    out = {}
    for leader in leaders:
        if _extensible(leader):
            out.update({c: p for c, p in nested_law_starts(leader, scores, speeds).items() if c not in out})
    return out


def fewer_friction_terms(pool: Workers, job: CandidateJob, scores: list[CandidateScore], run: RunOptions
                          ) -> list[CandidateScore]:
    """The backward step of the forward selection of friction terms: the structure ranked first (with friction
    terms alone) without each of them in turn, from its own fit without it (starts.without_terms), where no such
    structure was fitted or its fit ranks below the first by BIC (the better of its two fits kept) — a term
    added on the way may have been standing in for the one added after it, and a structure fitted before the
    term that followed it may have stopped short of where the first's fit shows its optimum to be
    (stribeck_delta seed 6: stribeck+delta/1 from stribeck/1's fit 43 in BIC above stribeck+delta+fv_asym/1)."""
    first = rank(scores)[0]
    if not _extensible(first) or len(first.candidate.terms) < 2:
        return scores  # with one term, the structure without it is the first stage's
    bic = {s.candidate: s.bic for s in scores if s.status == "fitted"}
    starts = {}
    for term in first.candidate.terms:
        fewer = replace(first.candidate, terms=tuple(t for t in first.candidate.terms if t != term))
        if not bic.get(fewer, math.inf) <= first.bic:
            starts[fewer] = without_terms(first.result.plant, {term})
    if not starts:
        return scores
    again = fit_all(pool, replace(job, polished=True), starts, run, [])
    return with_new(keep_better(scores, again), again)
