"""Every list a selection builds from its fits may be empty: no fit succeeded, or none has every parameter
determined (a real axis's log) — fault injection by a monkeypatched fit, and the helpers that take a first, a
minimum or an index called with such lists; and long records ranked on their first share, the chosen structure
polished on the whole of them."""
import math
from dataclasses import replace

import h5py
import numpy as np
import pytest

import servofmu as sf
from servofmu.runtime import RunOptions
from servofmu.selection import fitting
from servofmu.selection import run as select_run
from servofmu.selection.candidates import Candidate
from servofmu.selection.select import SCREEN_MARGIN, CandidateScore, could_win, rank
from servofmu.selection.starts import (from_winner, term_starts, nested_law_starts, reduced_starts, spring_starts,
                                       within_first)
from servofmu.selection.summary import selection_json, selection_text

from test_select import _record

CANDIDATES = ("coulomb/1", "stribeck/1")


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("empty")
    g1 = sf.load_plant("g1")
    return _record(folder, "fit", g1, 1), _record(folder, "val", g1, 2)


def _patched_fit(monkeypatch, change):
    real = fitting.fit_candidate

    def fit(worker, job):
        return change(real(worker, job))
    monkeypatch.setattr(fitting, "fit_candidate", fit)


def _select(records, tmp_path, **options):
    return sf.select_files([records[0]], records[1], tmp_path / "s.h5",
                           sf.SelectOptions(candidates=CANDIDATES, iterations=5, **options), RunOptions(workers=0))


def test_a_selection_where_no_fit_has_every_parameter_determined_ranks_and_chooses_by_bic(records, tmp_path,
                                                                                          monkeypatch):
    """Every fit's first parameter marked undetermined (as on a real axis's log, where the roughness check took
    the minimum BIC of an empty list): every candidate is ranked, flagged, and the lowest BIC chosen and written."""
    _patched_fit(monkeypatch, lambda s: replace(s, undetermined=s.result.names[:1]) if s.status == "fitted" else s)
    selection = _select(records, tmp_path)
    assert [s.status for s in selection.scores] == ["fitted", "fitted"]
    assert all("undetermined" in s.flags for s in selection.scores)
    assert selection.scores[0].bic == min(s.bic for s in selection.scores)
    assert selection.chosen is selection.scores[0] and (tmp_path / "s.toml").is_file()
    assert np.isfinite(selection.roughness)
    assert "chosen: " in selection_text(selection)


def test_a_selection_where_every_fit_fails_writes_its_ranking_and_chooses_none(records, tmp_path, monkeypatch):
    _patched_fit(monkeypatch, lambda s: CandidateScore(s.candidate, "failed", message="integrator gave up"))
    selection = _select(records, tmp_path)
    assert selection.chosen is None and all(s.flags == ("fit failed",) for s in selection.scores)
    assert "no candidate could be fitted" in selection_text(selection)
    assert selection_json(selection)["chosen"] is None
    assert (tmp_path / "s.h5").is_file() and not (tmp_path / "s.toml").exists()
    with h5py.File(tmp_path / "s.h5") as f:
        assert f["selection"].attrs["chosen"] == ""


def _score(name, status="fitted", bic=0.0, **kw):
    law, order = name.split("/")
    return CandidateScore(Candidate(law, int(order[0]), int(order.endswith("z"))), status, bic=bic, **kw)


@pytest.mark.parametrize("scores", [[], [_score("coulomb/1", "failed"), _score("stribeck/1", "failed")]],
                         ids=["empty", "all failed"])
def test_the_helpers_that_pick_from_fits_take_lists_without_a_fit(scores):
    failed = _score("coulomb/1", "failed")
    speeds = np.array([0.1, -0.1])
    assert rank(scores) == [] if not scores else all(s.flags == ("fit failed",) for s in rank(scores))
    assert reduced_starts(scores, [Candidate("coulomb", 1)], 10.0, speeds) == {}
    assert spring_starts(scores) == {} and term_starts(failed) == {}
    assert nested_law_starts(failed, scores, speeds) == {} and from_winner(failed, scores, speeds) == {}
    assert within_first(failed, scores, speeds) == {}
    assert math.isnan(select_run._roughness(None, None, scores))  # no fit to check: NaN, and the pool is not asked


def test_a_flagged_first_sends_only_unflagged_or_close_screened_candidates_to_the_full_polish():
    first = _score("coulomb/2z", bic=-1000.0, screened=True, bic_bound=-1001.0, flags=("validation",))
    far_flagged = _score("lugre/1", bic=-900.0, screened=True, bic_bound=-950.0, flags=("undetermined",))
    far_clean = _score("stribeck/1", bic=-900.0, screened=True, bic_bound=-950.0)
    close_flagged = _score("lugre/2", bic=-990.0, screened=True, bic_bound=-1000.0 + SCREEN_MARGIN,
                           flags=("undetermined",))
    assert could_win(first, first) and could_win(far_clean, first) and could_win(close_flagged, first)
    assert not could_win(far_flagged, first)


def test_long_records_are_ranked_on_their_first_share_and_the_chosen_polished_on_all(records, tmp_path,
                                                                                     monkeypatch):
    """With RANKED_SAMPLES below the records' 1000 samples the candidates are ranked on the first 40 %, and the
    chosen structure's written result is its fit on every sample (its own residuals: N = 1000)."""
    monkeypatch.setattr(select_run, "RANKED_SAMPLES", 400)
    selection = _select(records, tmp_path)
    assert selection.ranked_share == pytest.approx(0.4)
    assert selection.chosen.samples < 450 and selection.final.samples == 1000
    written = sf.read_result(tmp_path / "s-result.h5")
    assert np.allclose(written.theta, selection.final.result.theta)
    assert not np.allclose(written.theta, selection.chosen.result.theta)
    truth = sf.load_plant("g1")
    assert abs(written.plant.poles[0].real / truth.poles[0].real - 1) < 0.02
    assert "ranked on 0.4 of the records' fitted samples" in selection_text(selection)
    with h5py.File(tmp_path / "s.h5") as f:
        assert f["selection"].attrs["ranked_share"] == pytest.approx(0.4)


def test_a_candidate_whose_swarm_passes_its_time_budget_is_polished_from_its_best_and_says_so(records, tmp_path):
    selection = _select(records, tmp_path, budget=1e-9)
    assert selection.chosen is not None
    for s in selection.scores:
        assert "time budget: the swarm stopped after 0 of 5 iterations (1e-09 s)" in s.message
        assert s.result.stages[0].evaluations == 10  # the first particles only, then the polish
