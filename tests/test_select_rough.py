"""A chaotic response is told from a regular one (select.response_roughness): at one standard error from a fit a
locally quadratic cost rises by 1; on a record where a mass moves through a ripple's wells under a force (a forced
pendulum: G of second order with a position ripple) the truth's own fit rises by thousands there, and the
selection says so."""
from __future__ import annotations

import numpy as np
import pytest

from servofmu.model.plant import plant_from_dict
from servofmu.identification.criterion import RecordData, RecordSeries
from servofmu.selection.candidates import parse_candidates
from servofmu.identification.roughness import ROUGH_RISE
from servofmu.selection.select import CandidateJob, SelectOptions, fit_candidate, response_roughness
from servofmu.simulation.batch import BatchSimulator

DT, DURATION = 0.01, 20.0


def ripple_axis(poles, dc_gain, levels, ripple):
    amplitude, period, phase = ripple
    return plant_from_dict({"name": "axis", "linear": {"poles": [[p, 0.0] for p in poles], "dc_gain": dc_gain},
                            "friction": {"model": "coulomb", "fc_pos": levels[0], "fc_neg": levels[1]},
                            "load": {"ripple_amplitude": amplitude, "ripple_period": period,
                                     "ripple_phase": phase}})


def record(plant, seed: int, duration: float = DURATION) -> RecordData:
    """20 s (``duration``) at 100 Hz: 2 N at 1 Hz with 0.6 N at 3.1 Hz, then 0.7 N at 0.6 Hz with 0.3 N at 4.3 Hz,
    40 dB of white noise on the velocity."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration, DT)
    ph = rng.uniform(0, 2 * np.pi, 4)
    u = np.where(t < duration / 2, 2 * np.sin(2 * np.pi * t + ph[0]) + 0.6 * np.sin(2 * np.pi * 3.1 * t + ph[1]),
                 0.7 * np.sin(2 * np.pi * 0.6 * t + ph[2]) + 0.3 * np.sin(2 * np.pi * 4.3 * t + ph[3]))
    v = BatchSimulator(plant).simulate_record(plant.parameter_vector()[None], t, u, rtol=1e-10).v[0]
    v = v + 0.01 * np.std(v) * rng.standard_normal(v.size)
    return RecordData((RecordSeries("v", t, u, v, "v", "zoh", np.ones(t.size, bool)),), "records")


def roughness_of_truths_fit(plant, truth: str, seed: int) -> float:
    """The truth's structure polished from the true values (select's refit), and its roughness."""
    data = record(plant, seed)
    job = CandidateJob(parse_candidates([truth])[0], plant, data, data, SelectOptions(seed=seed), 2, {},
                       mode="refit")
    fit = fit_candidate(None, job)
    assert fit.status == "fitted", fit.message
    check = CandidateJob(job.candidate, fit.result.plant, data, data, job.options, 2, {},
                         covariance=fit.result.covariance)
    return response_roughness(None, check)


@pytest.mark.parametrize("seed", [3, 6])
def test_a_first_order_ripple_axis_is_regular_and_a_second_order_one_chaotic(seed):
    # first order: velocity follows the force, the position cannot run away from the record's — the cost is about
    # quadratic at a standard error, as the covariance promises: a rise of 1, 3 on seed 6, 31 on seed 3 along the
    # ripple phase's curving valley
    regular = roughness_of_truths_fit(ripple_axis([-10.0], 1.0, (0.5, 0.4), (0.2, 0.05, 0.7)), "coulomb+ripple/1",
                                      seed)
    assert 0.5 < regular < ROUGH_RISE / 4
    # second order (bench_select's coulomb2_ripple): a standard error from the truth's own fit the response has
    # slipped wells along the way (2000–3600)
    chaotic = roughness_of_truths_fit(ripple_axis([-5.0, -40.0], 2.0, (0.3, 0.25), (0.15, 0.04, -1.1)),
                                      "coulomb+ripple/2", seed)
    assert chaotic > 5 * ROUGH_RISE


def test_roughness_is_not_checked_without_a_covariance():
    plant = ripple_axis([-10.0], 1.0, (0.5, 0.4), (0.2, 0.05, 0.7))
    data = record(plant, 0)
    job = CandidateJob(parse_candidates(["coulomb+ripple/1"])[0], plant, data, data, SelectOptions(), 1, {})
    assert np.isnan(response_roughness(None, job))


def test_identify_says_when_its_intervals_do_not_hold():
    from servofmu.identification.identifier import PSOANNIdentifier
    from servofmu.identification.results import table_text

    for plant, rough in ((ripple_axis([-10.0], 1.0, (0.5, 0.4), (0.2, 0.05, 0.7)), False),
                         (ripple_axis([-5.0, -40.0], 2.0, (0.3, 0.25), (0.15, 0.04, -1.1)), True)):
        est = PSOANNIdentifier(plant, method="pso", seed=0, threads=2).fit(record(plant, 3))
        result = est.result({})
        assert (est.roughness_ > ROUGH_RISE) == rough, est.roughness_
        assert result.provenance["roughness"] == est.roughness_
        assert ("chaotic in the parameters" in table_text(result)) == rough


def _imported(tmp_path, plant, duration: float = DURATION):
    """A fit and a validation record of ``plant`` (rngs 1001, 1002) imported as records files."""
    from servofmu.measurement.records import import_records

    files = []
    for role, seed in (("fit", 1001), ("val", 1002)):
        r = record(plant, seed, duration).records[0]
        csv = tmp_path / f"{role}.csv"
        np.savetxt(csv, np.column_stack([r.time, r.u, r.y]), delimiter=",", header="t,u,v", comments="")
        import_records([csv], tmp_path / f"{role}.h5", "t", "u", "v")
        files.append(tmp_path / f"{role}.h5")
    return files


def test_a_selection_on_chaotic_records_is_made_again_on_their_predictable_start(tmp_path):
    import h5py

    import servofmu as sf
    from servofmu.runtime import RunOptions
    from servofmu.selection.summary import selection_text

    plant = ripple_axis([-5.0, -40.0], 2.0, (0.3, 0.25), (0.15, 0.04, -1.1))
    fit, val = _imported(tmp_path, plant)  # bench_select.py's coulomb2_ripple, seed 0
    out = tmp_path / "select.h5"
    selection = sf.select_files([fit], val, out,
                                sf.SelectOptions(candidates=("coulomb+ripple/2", "coulomb/2")), RunOptions(workers=0))
    # the whole 20 s are chaotic for the fit ranked first; their first half (the larger force) is not, and there
    # the truth's structure is chosen, near the true values
    assert selection.roughness_whole > ROUGH_RISE and selection.roughness < ROUGH_RISE
    assert selection.horizon == 0.5 and selection.horizon_seconds == pytest.approx(10.0, abs=0.02)
    assert selection.chosen.name == "coulomb+ripple/2"
    fitted = selection.chosen.result.plant
    assert fitted.load.ripple_period == pytest.approx(0.04, rel=1e-3)
    assert sorted(p.real for p in fitted.poles) == pytest.approx([-40.0, -5.0], rel=0.02)
    assert selection.chosen.result.provenance["horizon"] == 0.5
    assert "fitted and ranked on the first 0.5 of every record" in selection_text(selection)
    with h5py.File(out) as f:
        assert f["selection"].attrs["horizon"] == 0.5
        assert f["selection"].attrs["roughness_whole"] == selection.roughness_whole


def _counting(monkeypatch, roughness):
    """select_files' rounds recorded as (samples, stop_if_rough), the winners' fits handed on as their samples,
    and every roughness check made to return ``roughness(samples)``."""
    from servofmu.selection import run as selection_run

    rounds, handed, from_winner, original = [], [], selection_run.from_winner, selection_run._rounds

    def counted(pool, job, candidates, files, run, stop_if_rough=False):
        rounds.append((job.data.records[0].time.size, stop_if_rough))
        return original(pool, job, candidates, files, run, stop_if_rough)

    monkeypatch.setattr(selection_run, "_rounds", counted)
    monkeypatch.setattr(selection_run, "from_winner", lambda first, *args: (
        handed.append(first.samples) or from_winner(first, *args)))
    monkeypatch.setattr(selection_run, "_roughness",
                        lambda pool, job, scores, checked=None: roughness(job.data.records[0].time.size))
    return rounds, handed


FIRST_ORDER_RIPPLE = ((-10.0,), 1.0, (0.5, 0.4), (0.2, 0.05, 0.7))


@pytest.mark.parametrize("chaotic", ["whole records", "every start"])
def test_a_selections_rounds_stop_where_its_ripple_fits_are_chaotic(tmp_path, monkeypatch, chaotic):
    import servofmu as sf
    from servofmu.runtime import RunOptions
    from servofmu.selection.run import EARLY_ROUGH_RISE

    # the check made once the ripple terms and the laws nested in them are fitted: above EARLY_ROUGH_RISE no fit
    # of the whole records follows it (none handed on from the winner) and the selection goes on with their first
    # half, whose rounds run to their end; where no start is regular, the whole records' rounds are run in full
    rough = 2 * EARLY_ROUGH_RISE
    rounds, handed = _counting(monkeypatch, lambda n: rough if n == 800 or chaotic == "every start" else 1.0)
    fit, val = _imported(tmp_path, ripple_axis(*FIRST_ORDER_RIPPLE), duration=8.0)
    selection = sf.select_files([fit], val, tmp_path / "select.h5", sf.SelectOptions(orders=(1,)),
                                RunOptions(workers=0))
    assert selection.roughness_whole == rough
    if chaotic == "whole records":
        assert rounds == [(800, True), (400, False)] and 800 not in handed and 400 in handed
        assert selection.horizon == 0.5 and selection.roughness == 1.0
        assert {s.samples for s in selection.scores} == {400}
    else:
        assert rounds == [(800, True), (400, False), (200, False), (100, False), (800, False)]
        assert handed[-1] == 800  # the whole records' rounds made again, to their end
        assert selection.horizon == 1.0 and selection.roughness == rough
        assert {s.samples for s in selection.scores} == {800}
    assert selection.chosen.name == "coulomb+ripple/1"


def test_a_selection_of_named_candidates_is_not_stopped_early(tmp_path, monkeypatch):
    import servofmu as sf
    from servofmu.runtime import RunOptions

    # named candidates have no second stage and no early check: chaotic everywhere, the whole records' selection
    # stands as its rounds ended
    rounds, _ = _counting(monkeypatch, lambda n: 1e4)
    fit, val = _imported(tmp_path, ripple_axis(*FIRST_ORDER_RIPPLE), duration=8.0)
    selection = sf.select_files([fit], val, tmp_path / "select.h5",
                                sf.SelectOptions(candidates=("coulomb/1", "coulomb+ripple/1")), RunOptions(workers=0))
    assert rounds == [(800, True), (400, False), (200, False), (100, False)]
    assert selection.horizon == 1.0 and selection.roughness == selection.roughness_whole == 1e4
    assert {s.samples for s in selection.scores} == {800}
    assert "horizon" not in selection.chosen.result.provenance
