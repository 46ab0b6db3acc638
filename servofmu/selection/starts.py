"""Where the selection's later rounds start their candidates: from the fits of the rounds before — a larger
candidate's fit without the roots beyond the data, a richer law's reduced to the law it contains, a zero at the
origin read as a spring, the structure ranked first with each load or friction term, and a term's leader reduced to
the structures nested in it (docs/selection.md, the candidates)."""
from __future__ import annotations

import math
import tomllib
from dataclasses import replace

import numpy as np

from ..model.friction import steady_friction
from ..model.laws.registry import contained_laws, get_law
from ..model.laws.viscous import VISCOUS_KEYS
from ..model.plant import Friction, plant_from_dict
from .candidates import (FRICTION_TERMS, LOAD_TERMS, Candidate, spring_form, term_applies, term_candidates,
                         with_friction_term, with_viscous_share, without_friction_term)
from .select import SCREEN_MARGIN, CandidateScore, cancels, rank

__all__ = ["contained_laws", "with_terms", "term_starts", "reduced_starts", "term_leader",
           "nested_law_starts", "from_winner", "nested_structures", "reduced_to", "spring_starts", "with_law",
           "without_cancelling", "within_first", "without_terms"]


# The friction law each law contains as a limit (FrictionLaw.nested, servofmu.model.laws): Stribeck is LuGre with
# stiff bristles, Coulomb is Stribeck with fs = fc.
SPEED_QUANTILES = 512  # the data's velocities a Coulomb level is averaged over (with_law)


def with_terms(plant, candidate: Candidate, found=None):
    """``plant`` (a fitted candidate's) with the terms of ``candidate`` it lacks: at their values in ``found``
    (another candidate's fitted plant) where it has them, a ripple excepted, else where they change nothing
    (zero force, δ = 2, fv_neg = fv_pos: with a share of G's damping, candidates.with_viscous_share) — the second
    stage starts where its parent fits, so that a term can only lower its criterion, and a ripple at zero force is
    searched from there (selection.period)."""
    data = tomllib.loads(plant.to_toml())
    known = tomllib.loads(found.to_toml()) if found is not None else {}
    load = data.setdefault("load", {})
    for term in candidate.terms:
        if term in FRICTION_TERMS:
            data["friction"] = with_friction_term(data["friction"], term, known.get("friction"))
            continue
        for key, value in LOAD_TERMS[term].items():
            load.setdefault(key, value if term == "ripple" else known.get("load", {}).get(key, value))
    if not load:
        data.pop("load")
    data["name"] = "candidate"
    return with_viscous_share(plant_from_dict(data, source=f"candidate {candidate.name}"))


def term_starts(first: CandidateScore) -> dict:
    """The second stage's starts: the fit of ``first`` (the candidate ranked first) with each term
    (candidates.term_candidates) added where it changes nothing; none when ``first`` was not fitted."""
    if first.status != "fitted":
        return {}
    return {c: with_terms(first.result.plant, c) for c in term_candidates(first.candidate)}


def reduced_starts(scores: list[CandidateScore], candidates: list[Candidate], bandwidth: float,
                    speeds: np.ndarray) -> dict:
    """Starts for candidates nested in a fitted one: one order (or zero) smaller where its G has poles or zeros
    beyond the data's bandwidth or a zero that cancels a pole (that fit without them; of several such fits the one
    of the lowest BIC), and the law the best candidate's contains where that law's own fit is worse (LuGre's G and
    levels for Stribeck, Stribeck's for Coulomb: a smaller model that fits worse than a model containing it has
    missed its optimum — only for the best, whose rivals are the ones that matter).  The smaller one is polished
    again from there (no swarm: the start is its fit), and the better of its two fits kept."""
    fitted = _by_bic(scores)
    bic = {s.candidate: s.bic for s in fitted}
    out = {}
    for s in fitted:
        plant, c = s.result.plant, s.candidate
        poles, zeros = without_cancelling(tuple(p for p in plant.poles if abs(p) <= bandwidth),
                                           tuple(z for z in plant.zeros if abs(z) <= bandwidth))
        if poles and (poles, zeros) != (plant.poles, plant.zeros):
            smaller = replace(plant, poles=poles, zeros=zeros)
            target = replace(c, order=smaller.order, zeros=len(smaller.all_zeros()))
            if target in candidates and len(smaller.all_zeros()) < smaller.order and target not in out:
                out[target] = smaller
    best = fitted[0] if fitted else None
    law = get_law(best.candidate.law).nested if best else None
    if law:
        c = best.candidate
        target = Candidate(law, c.order, c.zeros, tuple(t for t in c.terms if term_applies(t, law)))
        if target in candidates and target not in out and bic.get(target, math.inf) > best.bic:
            out[target] = with_law(best.result.plant, law, speeds)
    return out


def term_leader(scores: list[CandidateScore]) -> CandidateScore:
    """The candidate ranked first, or where it has no terms, the screened candidate with terms whose
    full polish could reach a BIC below its own (select.screen_bound, less SCREEN_MARGIN) — of several, the lowest
    bound: a ripple's screened fit can be far from its optimum (coulomb2_ripple seed 0: the screened
    stribeck+ripple/2z ranked below stribeck/2z, polished in full it was 400 lower)."""
    first = rank(scores)[0]
    rivals = [s for s in scores if s.candidate.terms and s.screened and s.status == "fitted"
              and s.bic_bound - SCREEN_MARGIN <= first.bic]
    return first if first.candidate.terms or not rivals else min(rivals, key=lambda s: s.bic_bound)


def nested_law_starts(first: CandidateScore, scores: list[CandidateScore], speeds: np.ndarray) -> dict:
    """Starts for the structures nested in the one of ``first`` (nested_structures: the laws its law contains,
    and it and those without its zero) with its load terms, where ``first`` has load terms: the first stage chose
    its law, order and zero without them, and a force it could not explain (a ripple) may have been taken up by a
    richer friction law or a zero; none for a candidate already fitted."""
    if first.status != "fitted" or not first.candidate.terms:
        return {}
    fitted = {s.candidate: s.result.plant for s in scores if s.status == "fitted"}
    done, out = {s.candidate for s in scores}, {}
    for target in nested_structures(first.candidate):
        own = replace(target, terms=())
        if target not in done:  # its own first-stage fit, else the winner's G and levels; its load's values
            source = fitted[own] if own in fitted else reduced_to(first.result.plant, target, speeds)
            out[target] = with_terms(source, target, first.result.plant)
    return out


def from_winner(first: CandidateScore, scores: list[CandidateScore], speeds: np.ndarray, orders=(1, 2, 3)) -> dict:
    """Starts for the structures nested in the one of ``first`` (the candidate ranked first, with load terms) with
    its load terms — its own law one order lower too where ``orders`` (the selection's) has it — whose fits rank
    below it or that were not fitted: from the fit of ``first`` reduced to them (reduced_to) with its load
    values, a ripple's included (polished on growing shares of the records, then on all of them).  A ripple's
    output error is many-valleyed, and a nested structure whose fit ends a valley off — or whose ripple search
    started from a fit a valley off — is beaten by a richer one whose fit does not."""
    if first.status != "fitted" or not first.candidate.terms:
        return {}
    bic = {s.candidate: s.bic for s in scores if s.status == "fitted" and np.isfinite(s.bic)}
    return {target: reduced_to(first.result.plant, target, speeds)
            for target in nested_structures(first.candidate, orders) if bic.get(target, math.inf) > first.bic}


def within_first(first: CandidateScore, scores: list[CandidateScore], speeds: np.ndarray) -> dict:
    """Starts for the fitted candidates nested in the one of ``first`` (the candidate ranked first): some of its
    load terms, a law its law contains, an order and zeros no more than its own, fewer parameters — from the fit
    of ``first`` without the other load terms, reduced to them (reduced_to; a zero that cancels a pole dropped
    with it first, so that the poles kept are the ones with a response)."""
    if first.status != "fitted":
        return {}
    top, plant = first.candidate, first.result.plant
    laws = contained_laws(top.law)
    poles, zeros = without_cancelling(plant.poles, plant.zeros)
    bare = replace(plant, poles=poles, zeros=zeros) if poles else plant
    out = {}
    for s in scores:
        c = s.candidate
        if (s.status == "fitted" and c != top and set(c.terms) <= set(top.terms) and c.law in laws
                and c.order <= top.order and c.zeros <= top.zeros and s.parameters < first.parameters):
            source = bare if bare.order >= c.order and len(bare.all_zeros()) >= c.zeros else plant
            out[c] = reduced_to(without_terms(source, set(top.terms) - set(c.terms)), c, speeds)
    return out


def without_terms(plant, terms):
    """``plant`` without the load and friction terms ``terms`` (their parameters removed)."""
    if not terms:
        return plant
    data = tomllib.loads(plant.to_toml())
    load = data.get("load", {})
    for term in terms:
        if term in FRICTION_TERMS:
            data["friction"] = without_friction_term(data["friction"], term)
        for key in LOAD_TERMS.get(term, ()):
            load.pop(key, None)
    if not load:
        data.pop("load", None)
    return plant_from_dict(data, source="candidate without " + ", ".join(sorted(terms)))


def nested_structures(candidate: Candidate, orders=()):
    """The candidates nested in ``candidate`` with its terms (those their law takes): the laws its law contains
    (FrictionLaw.nested, all the way down) at its order and zero, then, where it has a zero, its own law and those
    without the zero, then its own law one order lower where ``orders`` has it (an order chosen without the load
    term may hold its force in a pole)."""
    laws = contained_laws(candidate.law)

    def of(law):
        return tuple(t for t in candidate.terms if term_applies(t, law))
    for law in laws[1:]:
        yield replace(candidate, law=law, terms=of(law), choices=())
    if candidate.zeros:  # laws[0] is its own: it keeps its structure choices
        for i, law in enumerate(laws):
            yield replace(candidate, law=law, zeros=0, terms=of(law), choices=() if i else candidate.choices)
    if candidate.order - 1 in orders:
        yield replace(candidate, order=candidate.order - 1, zeros=min(candidate.zeros, candidate.order - 2))


def reduced_to(plant, target: Candidate, speeds: np.ndarray):
    """``plant`` (a fit) as a start of the nested structure ``target``: its law reduced (with_law), without its
    zeros where ``target`` has none, and of a lower order without its fastest poles (the slowest roots kept, a
    complex pair that does not fit as one real pole at its magnitude; the DC gain kept)."""
    if target.law != plant.friction.model:
        plant = with_law(plant, target.law, speeds)
    if target.order < plant.order:
        plant = replace(plant, poles=_slowest(plant.poles, target.order), zeros=_slowest(plant.zeros, target.zeros))
    return replace(plant, zeros=()) if not target.zeros and plant.zeros else plant


def _slowest(roots: tuple, count: int) -> tuple:
    """The slowest of ``roots`` (a complex pair listed once, counting two) up to ``count`` roots: a pair that does
    not fit whole becomes one real root at its magnitude."""
    out, n = [], 0
    for r in sorted(roots, key=abs):
        if n + (2 if r.imag else 1) <= count:
            out.append(r)
            n += 2 if r.imag else 1
        elif n < count:
            out.append(complex(-abs(r), 0.0))
            n += 1
    return tuple(out)


def spring_starts(scores: list[CandidateScore]) -> dict:
    """Starts for the structures with a spring that fitted candidates stand for by a zero at the origin
    (candidates.spring_form), of several sources the lowest BIC's; none for a structure already fitted."""
    done, out = {s.candidate for s in scores}, {}
    for s in _by_bic(scores):
        found = spring_form(s.candidate, s.result.plant)
        if found and found[0] not in done and found[0] not in out:
            out[found[0]] = found[1]
    return out


def _by_bic(scores: list[CandidateScore]) -> list[CandidateScore]:
    """The fitted candidates of finite BIC, the lowest first."""
    return sorted((s for s in scores if s.status == "fitted" and np.isfinite(s.bic)), key=lambda s: s.bic)


def with_law(plant, law: str, speeds: np.ndarray):
    """``plant`` with the friction law ``law`` nested in its own: the levels they share, and Coulomb levels that
    are the mean of its steady friction curve over the data's velocities ``speeds`` on either side (a Stribeck
    fit may hold the axis's level in fs with a Stribeck velocity above the speeds, and fc far below it)."""
    source = plant.friction.values()
    viscous = {k.name: source[k.name] for k in VISCOUS_KEYS if k.name in source}
    fv_pos, fv_neg = viscous.get("fv_pos", viscous.get("fv")), viscous.get("fv_neg", viscous.get("fv"))

    def mean_level(sign: float) -> float | None:
        side = speeds[np.sign(speeds) == sign]
        if not side.size:
            return None
        # its quantiles stand for it; the curve less the viscous term, which the law keeps
        side = np.quantile(side, np.linspace(0.0, 1.0, min(side.size, SPEED_QUANTILES)))
        level = float(np.mean(sign * steady_friction(plant, side) - (fv_pos if sign > 0 else fv_neg) * np.abs(side)))
        return level if np.isfinite(level) and level > 0 else None

    levels = get_law(law).levels_from(source, mean_level)
    return replace(plant, friction=Friction.of(law, {**levels, **viscous}))


def without_cancelling(poles: tuple, zeros: tuple) -> tuple[tuple, tuple]:
    """Distinct roots (a complex pair once) less each zero that nearly cancels a pole (select.cancels) and that
    pole: the pair has no response of its own, and the fit without it is the smaller
    candidate's (its DC gain kept: the pair's is z/p ≈ 1).  A real zero beside a complex pair (two nearly equal
    poles the fit made complex) takes one of them: the pair becomes one real pole at its real part."""
    poles, kept = list(poles), []
    for z in zeros:
        match = next((p for p in poles if cancels(z, p) and (z.imag == 0 or p.imag != 0)), None)
        if match is None:
            kept.append(z)
            continue
        poles.remove(match)
        if match.imag != 0 and z.imag == 0:
            poles.append(complex(match.real, 0.0))
    return tuple(poles), tuple(kept)
