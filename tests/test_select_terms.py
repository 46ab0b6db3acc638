"""The friction-term steps of a selection's second stage (servofmu.selection.terms) on a scripted landscape: the
fits are replaced by a table of BICs written here, so that what is asserted is the steps' logic — which
structures they fit, in which order, and when they stop — not a search's luck."""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest

import servofmu as sf
from servofmu.identification.criterion import RecordData, RecordSeries
from servofmu.identification.residuals import EXACT
from servofmu.runtime import RunOptions
from servofmu.selection import terms
from servofmu.selection.candidates import parse_candidates
from servofmu.selection.select import CandidateScore, rank

RECORDS = RecordData((RecordSeries("v", np.arange(3.0), np.zeros(3), np.zeros(3), "v", "zoh", np.ones(3, bool)),),
                     "records")


def _score(name: str, bic: float, fitness: float = 1e-2, screened: bool = False,
           undetermined: tuple = ()) -> CandidateScore:
    candidate = parse_candidates([name])[0]
    plant = sf.load_plant("stribeck_servo")  # a Stribeck plant: the law whose terms are scripted here
    return CandidateScore(candidate, "fitted", result=SimpleNamespace(plant=plant, fitness=fitness),
                          parameters=10, samples=2000, neg2loglik=bic, bic=bic, validation_neg2loglik=bic,
                          screened=screened, undetermined=undetermined)


@pytest.fixture
def landscape(monkeypatch):
    """A table name → BIC that the scripted fits return, and the names fitted in each call, in order."""
    table, rounds = {}, []

    def fit_all(pool, job, starts, run, done):
        rounds.append(sorted(c.name for c in starts))
        return list(done) + [_score(c.name, table[c.name]) for c in starts]

    monkeypatch.setattr(terms, "fit_all", fit_all)
    return table, rounds


@dataclass(frozen=True)
class _Job:
    """What the steps read of a selection's job: whether a fit is the polish alone (the backward step's)."""
    polished: bool = False


def _job():
    return _Job()


def test_forward_steps_add_each_missing_friction_term_while_a_structure_with_terms_ranks_first(landscape):
    table, rounds = landscape
    table.update({"stribeck+delta+fv_asym/2": -30.0})
    scores = [_score("stribeck/2", 0.0), _score("stribeck+delta/2", -10.0), _score("stribeck+fv_asym/2", -5.0)]
    out = terms.more_friction_terms(None, _job(), scores, RECORDS, RunOptions())
    assert rounds == [["stribeck+delta+fv_asym/2"]]  # from the first, the one term it lacks; then none is left
    assert rank(out)[0].name == "stribeck+delta+fv_asym/2"


def test_forward_steps_stop_where_a_structure_without_friction_terms_ranks_first(landscape):
    table, rounds = landscape
    scores = [_score("stribeck/2", -20.0), _score("stribeck+delta/2", -10.0)]
    assert terms.more_friction_terms(None, _job(), scores, RECORDS, RunOptions()) == scores
    assert rounds == []


def test_the_backward_step_tries_the_first_without_each_of_its_friction_terms(landscape, monkeypatch):
    table, rounds = landscape
    monkeypatch.setattr(terms, "without_terms", lambda plant, removed: plant)
    table.update({"stribeck+delta/2": -40.0, "stribeck+fv_asym/2": -12.0})
    scores = [_score("stribeck/2", 0.0), _score("stribeck+delta+fv_asym/2", -30.0)]
    out = terms.fewer_friction_terms(None, _job(), scores, RunOptions())
    assert rounds == [["stribeck+delta/2", "stribeck+fv_asym/2"]]
    assert rank(out)[0].name == "stribeck+delta/2"  # the term added first stood in for the one added after it


def test_the_backward_step_leaves_a_first_with_one_term(landscape):
    table, rounds = landscape
    scores = [_score("stribeck/2", 0.0), _score("stribeck+delta/2", -30.0)]
    assert terms.fewer_friction_terms(None, _job(), scores, RunOptions()) == scores
    assert rounds == []


@pytest.mark.parametrize("fitness, screened, friction_terms", [
    (0.5 * EXACT, False, False),    # noise-free: the first reproduces the data
    (50 * EXACT, False, True),      # a full polish's error 50·EXACT is no exact fit
    (50 * EXACT, True, False),      # a screened fit's polish stops at a coarser tolerance (SCREENED_EXACT)
    (200 * EXACT, True, True),
    (1e-2, False, True),            # 40 dB of noise
])
def test_friction_terms_are_ranked_only_where_the_first_does_not_reproduce_the_data(fitness, screened,
                                                                                    friction_terms):
    first = _score("stribeck/2", 0.0, fitness=fitness, screened=screened)
    names = {c.name for c in terms.ranked_term_starts(first, RECORDS)}
    assert {"stribeck+stiffness/2", "stribeck+ripple/2"} <= names  # the load terms either way
    assert ({"stribeck+delta/2", "stribeck+fv_asym/2"} <= names) == friction_terms
    assert not any("+delta+" in n or "+fv_asym+" in n or n.count("+") > 1 for n in names)  # never combined


def test_the_structures_nested_in_the_lowest_bic_are_started_where_it_ranks_below_the_first():
    # the structure with every term fits best, but its bump is undetermined: the Coulomb law with its viscous
    # term is nested in it, and is not nested in the first (coulomb/2 is, and is fitted)
    scores = [_score("coulomb/2", 0.0), _score("stribeck+delta/2", -20.0),
              _score("stribeck+delta+fv_asym/2", -30.0, undetermined=("vs",))]
    assert rank(scores)[0].name == "stribeck+delta/2"
    starts = terms.nested_in_leaders(scores, np.linspace(-0.5, 0.5, 101))
    assert sorted(c.name for c in starts) == ["coulomb+fv_asym/2"]


def test_nothing_is_nested_in_leaders_without_friction_terms():
    scores = [_score("coulomb/2", -5.0), _score("stribeck/2", 0.0)]
    assert terms.nested_in_leaders(scores, np.linspace(-0.5, 0.5, 101)) == {}


def test_the_backward_step_refits_a_structure_whose_earlier_fit_ranks_below_the_first(landscape, monkeypatch):
    table, rounds = landscape
    monkeypatch.setattr(terms, "without_terms", lambda plant, removed: plant)
    table.update({"stribeck+delta/2": -40.0, "stribeck+fv_asym/2": -12.0})
    scores = [_score("stribeck/2", 0.0), _score("stribeck+delta/2", -10.0),  # fitted before fv_asym was added
              _score("stribeck+delta+fv_asym/2", -30.0)]
    out = terms.fewer_friction_terms(None, _job(), scores, RunOptions())
    assert rounds == [["stribeck+delta/2", "stribeck+fv_asym/2"]]
    assert [s.name for s in out].count("stribeck+delta/2") == 1  # its better fit kept, not a second row
    assert rank(out)[0].name == "stribeck+delta/2" and rank(out)[0].bic == -40.0


def test_the_friction_terms_go_on_the_laws_nested_in_the_first_too(landscape):
    # LuGre's bristle dynamics lent lugre/1 the shape of the curve, and the shape exponent added to it changed
    # nothing; the Stribeck law it contains takes the exponent, ranks first, and is extended in turn
    table, rounds = landscape
    table.update({"stribeck+delta/1": -80.0, "stribeck+fv_asym/1": -28.0, "coulomb+fv_asym/1": -1.0,
                  "stribeck+delta+fv_asym/1": -72.0, "lugre+delta/1": -45.0, "lugre+fv_asym/1": -44.0})
    scores = [_score("lugre/1", -50.0), _score("lugre+delta/1", -45.0), _score("lugre+fv_asym/1", -44.0),
              _score("stribeck/1", -30.0), _score("coulomb/1", 0.0)]
    out = terms.friction_terms_on_final(None, _job(), scores, RECORDS, np.linspace(-0.5, 0.5, 101), RunOptions())
    # the first's own terms fitted again (their fits lie above the first's), the nested laws' first, then the
    # forward step on the one that ranks first
    assert rounds == [["coulomb+fv_asym/1", "lugre+delta/1", "lugre+fv_asym/1", "stribeck+delta/1",
                       "stribeck+fv_asym/1"], ["stribeck+delta+fv_asym/1"]]
    assert rank(out)[0].name == "stribeck+delta/1"


def test_the_nested_laws_are_not_extended_at_another_order(landscape):
    table, rounds = landscape
    table.update({"lugre+delta/1": -45.0, "lugre+fv_asym/1": -44.0})
    scores = [_score("lugre/1", -50.0), _score("stribeck/2", -30.0)]
    terms.friction_terms_on_final(None, _job(), scores, RECORDS, np.linspace(-0.5, 0.5, 101), RunOptions())
    assert rounds == [["lugre+delta/1", "lugre+fv_asym/1"]]
