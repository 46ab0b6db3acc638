"""`select` on broadband data: the candidates ranked on every level's first realisation (each simulated from rest,
fitted after its transient periods), their starts from the BLA's G where that fits better, and the summary's line
on what the ranked records were."""
from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from test_display import selection as display_selection

from servofmu.broadband import BroadbandPlan
from servofmu.broadband.simulate import write_simulated
from servofmu.broadband.store import read_broadband
from servofmu.errors import ServofmuWarning
from servofmu.identification.broadband_identify import level_pieces
from servofmu.model.plant import load_plant
from servofmu.selection.candidates import parse_candidates
from servofmu.selection.data import load_selection_data, ranked_data
from servofmu.selection.run import frequency_starts, linear_starts
from servofmu.selection.select import CandidateJob, SelectOptions
from servofmu.selection.summary import rough_warning, selection_json, selection_text
from servofmu.simulation.batch import BatchSimulator
from servofmu.simulation.parallel import Workers

PLAN = BroadbandPlan("multisine", (2.0, 0.8), (0.5, 20.0), 200.0, period=2.0, periods=2, transient_periods=1,
                     realisations=2, seed=3)


@pytest.mark.parametrize("name", ["g1", "stribeck_servo"])
def test_every_level_s_first_realisation_from_rest_is_the_run_once_its_transient_periods_are_past(name, tmp_path):
    """The pieces hold each level's first realisation as it was played; the true plant simulated from rest on a
    piece misses the run where the piece starts (the run was not at rest there) and reproduces it to 1e-8 after
    the transient periods, where the piece is fitted."""
    plant = load_plant(name)
    write_simulated(tmp_path / "bb.h5", plant, PLAN)
    data = read_broadband(tmp_path / "bb.h5")
    pieces = level_pieces(data, 1000)
    assert [r.name for r in pieces.records] == ["2 N", "0.8 N"]
    sim = BatchSimulator(plant)
    for lv, r in zip(data.levels, pieces.records):
        n = r.time.size
        assert n == PLAN.samples + 500 and np.array_equal(r.u, lv.u[0, :n])
        assert not r.fitted[:PLAN.samples].any() and r.fitted[PLAN.samples:].all()
        v = sim.simulate_record(plant.parameter_vector()[None], r.time, r.u, rtol=1e-10).v[0]
        scale = np.std(r.y[r.fitted])
        assert np.max(np.abs(v[r.fitted] - r.y[r.fitted])) < 1e-8 * scale
    later = pieces.records[1]
    v = sim.simulate_record(plant.parameter_vector()[None], later.time, later.u, rtol=1e-10).v[0]
    assert np.max(np.abs(v[:50] - later.y[:50])) > 1e-3 * np.std(later.y)


def test_no_pieces_where_a_piece_s_start_would_be_fitted_or_a_level_is_not_periodic(tmp_path):
    """Without transient periods, and on g2 (a limit cycle whose phase remembers the state a piece started in),
    select ranks on the run's own start instead; of a response not periodic it warns in one line."""
    write_simulated(tmp_path / "g2.h5", load_plant("g2"), PLAN, 40.0)
    assert level_pieces(read_broadband(tmp_path / "g2.h5"), 1000) is None
    with pytest.warns(ServofmuWarning, match=r"g2.h5: the response at 2, 0.8 N is not periodic"):
        load_selection_data([tmp_path / "g2.h5"])
    plan = replace(PLAN, transient_periods=0)
    write_simulated(tmp_path / "t0.h5", load_plant("g1"), plan, 40.0)
    assert level_pieces(read_broadband(tmp_path / "t0.h5"), 1000) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error", ServofmuWarning)  # g1's response is periodic: no warning
        data, files = load_selection_data([tmp_path / "t0.h5"])
    ranked, by_levels = ranked_data(data, files, 1000)
    assert not by_levels and [r.name for r in ranked.records] == ["broadband"]


def _starts(plant, tmp_path):
    write_simulated(tmp_path / "bb.h5", plant, PLAN, 40.0)
    data, files = load_selection_data([tmp_path / "bb.h5"])
    ranked, by_levels = ranked_data(data, files, 1000)
    assert by_levels
    candidates = parse_candidates(["coulomb"], orders=(1,))
    linear = linear_starts(candidates, ranked, files)
    job = CandidateJob(candidates[0], None, ranked, ranked, SelectOptions(), 1, {})
    with Workers(workers=0) as pool:
        return linear[candidates[0]], frequency_starts(pool, job, linear, files)[candidates[0]]


def test_a_candidate_starts_from_the_bla_s_g_where_that_fits_the_ranked_records_better(tmp_path):
    """g1 without friction: the linear estimate's pole is 20 % off on the ranked records at 40 dB, the BLA's G
    within 1 %; with g1's friction the BLA's G is a compromise of the levels, and the linear estimate's start, which
    has the friction in it, stands."""
    truth = load_plant("g1")
    linear_axis = replace(truth, friction=replace(truth.friction, fc_pos=0.0, fc_neg=0.0))
    linear, start = _starts(linear_axis, tmp_path)
    assert abs(linear.poles[0].real / -10.0 - 1) > 0.1
    assert start.poles[0].real == pytest.approx(-10.0, rel=0.01)
    linear, start = _starts(truth, tmp_path)
    assert start is linear


def test_the_summary_says_what_the_candidates_were_ranked_on_and_that_chaotic_records_were_not_polished_whole():
    sel = replace(display_selection(), kind="records", ranked_share=0.05, ranked_levels=True, horizon=0.25,
                  horizon_seconds=0.5, roughness=1.1, roughness_whole=900.0)
    text = selection_text(sel)
    assert "every level's first realisation after its transient periods" in text
    assert "not polished on the whole records" in text and "failed" not in text
    assert "over the ranked records" in rough_warning(sel)
    assert selection_json(sel)["ranked_levels"] is True
    text = selection_text(replace(sel, horizon=1.0, roughness=1.0))
    assert "its polish on the whole records failed" in text
