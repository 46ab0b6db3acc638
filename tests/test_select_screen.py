"""`servofmu select`'s bounds on a candidate's cost: the step budget of every record's simulation (a candidate that
chatters is stopped, scored and ranked, never integrated for minutes) and the screening (every candidate fitted
at SCREEN_RTOL, only those that could still win polished again at the identifier's tolerances)."""
import math
from dataclasses import replace

import h5py
import numpy as np
import pytest

import servofmu as sf
from servofmu.measurement.records import import_records
from servofmu.model.plant import plant_from_dict
from servofmu.runtime import RunOptions
from servofmu.selection.candidates import Candidate
from servofmu.selection.data import STEPS_PER_SAMPLE, BoundedSimulator, load_selection_data, steps_per_sample
from servofmu.selection.select import (SCREEN_MARGIN, SCREEN_POLISH_ITERATIONS, CandidateJob, CandidateScore,
                                       SelectOptions, could_win, fit_candidate, rank)
from servofmu.simulation.batch import BatchSimulator

DT = 0.01

# A trial step of a polish on scripts/bench_select.py's first record of coulomb1 (candidate coulomb/2z, started at
# STRUCTURE): a Coulomb level of 2.3e7 N against inputs of 2 N; the friction's tanh switches about zero velocity.
STRUCTURE = plant_from_dict({"name": "start", "linear": {"poles": [[-4.627, 2.403], [-4.627, -2.403]],
                                                          "zeros": [[-1.347, 0.0]], "dc_gain": 0.3758},
                             "friction": {"model": "coulomb", "fc_pos": 0.0323, "fc_neg": 0.647}})
CHATTERING = STRUCTURE.with_parameters(np.array([-4.0025, 0.17913, -1.13308, 0.57782, 2.25976e7, 0.19576, 0.0,
                                                 0.001]))


def _input(t, seed=1):
    """scripts/bench_select.py's excitation (its first record's phases with ``seed`` 1)."""
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, 4)
    return np.where(t < t[-1] / 2, 2 * np.sin(2 * np.pi * t + ph[0]) + 0.6 * np.sin(2 * np.pi * 3.1 * t + ph[1]),
                    0.7 * np.sin(2 * np.pi * 0.6 * t + ph[2]) + 0.3 * np.sin(2 * np.pi * 4.3 * t + ph[3]))


def _record(folder, name, plant, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 20, DT)
    u = _input(t, seed)
    v = BatchSimulator(plant).simulate_record(plant.parameter_vector()[None], t, u, rtol=1e-10).v[0]
    v = v + np.std(v) * 0.01 * rng.standard_normal(v.size)  # 40 dB
    csv = folder / f"{name}.csv"
    np.savetxt(csv, np.column_stack([t, u, v]), delimiter=",", header="t,u,v", comments="")
    import_records([csv], folder / f"{name}.h5", "t", "u", "v")
    return folder / f"{name}.h5"


@pytest.fixture(scope="module")
def g1_records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("screen")
    g1 = sf.load_plant("g1")
    return {"fit": _record(folder, "fit", g1, 1), "val": _record(folder, "val", g1, 2)}


def test_a_chattering_simulation_is_stopped_at_the_step_budget():
    """The plain simulator needs more than ten times the budget for the chattering plant (it gives NaN even
    then); the bounded one stops it and counts it, and runs a true plant's record as the plain one does."""
    t = np.arange(0, 20, DT)
    u = _input(t)
    p = CHATTERING.parameter_vector()[None]
    plain = BatchSimulator(STRUCTURE, threads=1).simulate_record(p, t, u, rtol=1e-10,
                                                                 max_steps=10 * STEPS_PER_SAMPLE * t.size)
    assert not np.all(np.isfinite(plain.v))
    bounded = BoundedSimulator(STRUCTURE, threads=1)
    assert not np.all(np.isfinite(bounded.simulate_record(p, t, u, rtol=1e-10).v))
    assert bounded.stopped == 1
    g1 = sf.load_plant("g1")
    q = g1.parameter_vector()[None]
    ok = BoundedSimulator(g1, threads=1)
    v = ok.simulate_record(q, t, u, rtol=1e-10).v
    assert ok.stopped == 0
    np.testing.assert_array_equal(v, BatchSimulator(g1, threads=1).simulate_record(q, t, u, rtol=1e-10).v)


@pytest.mark.parametrize("name", ["g1", "g2", "stribeck_servo", "lugre_servo"])
def test_the_step_budget_follows_the_tolerance_and_leaves_true_plants_a_margin(name):
    """At the swarm's 1e-4, the screening's 1e-7 and the polish's 1e-10 a shipped plant's record runs within a
    fifth of the budget; the budget at 1e-4 is under a tenth of the one at 1e-10, and stops the chattering plant."""
    t = np.arange(0, 20, DT)
    u = _input(t)
    plant = sf.load_plant(name)
    sim = BatchSimulator(plant, threads=1)
    for rtol in (1e-4, 1e-7, 1e-10):
        budget = int(steps_per_sample(rtol) * t.size / 5)
        assert np.all(np.isfinite(sim.simulate_record(plant.parameter_vector()[None], t, u, rtol=rtol,
                                                      max_steps=budget).v)), rtol
    assert steps_per_sample(1e-10) == STEPS_PER_SAMPLE and steps_per_sample(1e-4) < STEPS_PER_SAMPLE / 10
    bounded = BoundedSimulator(STRUCTURE, threads=1)
    assert not np.all(np.isfinite(bounded.simulate_record(CHATTERING.parameter_vector()[None], t, u, rtol=1e-4).v))
    assert bounded.stopped == 1


def test_a_candidate_that_chatters_is_stopped_scored_and_ranked(g1_records):
    """A polish started at the chattering plant returns (its runs stopped at the budget, said in its message),
    and the candidate is ranked: after a candidate fitted as usual."""
    data, _ = load_selection_data([g1_records["fit"]])
    validation, _ = load_selection_data([g1_records["val"]])
    options = SelectOptions(iterations=5)
    job = CandidateJob(Candidate("coulomb", 2, 1), CHATTERING, data, validation, options, 1, {}, mode="refit")
    stuck = fit_candidate(None, job)
    assert stuck.status in ("fitted", "failed")
    assert "step budget" in stuck.message
    g1 = sf.load_plant("g1")
    fine = fit_candidate(None, CandidateJob(Candidate("coulomb", 1), g1, data, validation, options, 1, {},
                                            mode="refit"))
    assert fine.status == "fitted" and not fine.message
    assert [s.name for s in rank([stuck, fine])] == ["coulomb/1", "coulomb/2z"]


def _screened(name, bic, bound, flags=()):
    law, order = name.split("/")
    return CandidateScore(Candidate(law, int(order[0]), int(order.endswith("z"))), "fitted", bic=bic,
                          screened=True, bic_bound=bound, flags=flags)


def test_a_screened_candidate_is_refitted_while_its_bound_could_beat_the_first():
    first = replace_flags(_screened("coulomb/1", -1000.0, -1001.0), ())
    assert could_win(first, first)  # the first itself, while screened
    assert could_win(_screened("stribeck/1", -900.0, -1000.0 + SCREEN_MARGIN), first)  # bound ties
    assert not could_win(_screened("stribeck/1", -990.0, -1000.0 + SCREEN_MARGIN + 0.1), first)
    assert could_win(_screened("lugre/1", -500.0, -math.inf), first)  # no bound: it could be anything
    assert could_win(_screened("lugre/2", -10.0, -20.0), replace_flags(first, ("undetermined",)))
    done = CandidateScore(Candidate("coulomb", 3), "fitted", bic=-2000.0)  # polished in full already
    assert not could_win(done, first)


def replace_flags(score, flags):
    return replace(score, flags=flags)


def test_screening_chooses_and_fits_as_the_full_selection(g1_records, tmp_path):
    """g1's records: a screened selection chooses what every candidate fitted in full chooses, its chosen fit is
    the full tolerance's (not screened, within its intervals of the full selection's), and no candidate left
    screened could have beaten it by the rule."""
    options = SelectOptions(candidates=("coulomb/1", "coulomb/2", "stribeck/1"), iterations=15)
    full = sf.select_files([g1_records["fit"]], g1_records["val"], tmp_path / "full.h5",
                           SelectOptions(**{**options.__dict__, "screen": False}), RunOptions(workers=0))
    fast = sf.select_files([g1_records["fit"]], g1_records["val"], tmp_path / "fast.h5", options,
                           RunOptions(workers=0))
    assert not any(s.screened for s in full.scores)
    assert fast.chosen.name == full.chosen.name == "coulomb/1"
    assert not fast.chosen.screened
    a, b = fast.chosen.result, full.chosen.result
    half = (b.intervals[:, 1] - b.intervals[:, 0]) / 2
    assert np.all(np.abs(a.theta - b.theta) <= half)
    assert abs(fast.chosen.bic - full.chosen.bic) < 1.0
    assert not any(could_win(s, fast.scores[0]) for s in fast.scores)
    with h5py.File(tmp_path / "fast.h5") as f:
        assert list(f["selection/screened"][()]) == [int(s.screened) for s in fast.scores]


def test_the_screening_polish_takes_at_most_its_steps_and_the_full_polish_the_identifiers(g1_records, monkeypatch):
    """A screened fit's polish is capped at SCREEN_POLISH_ITERATIONS Levenberg–Marquardt steps, a refit's at the
    identifier's MAX_POLISH_ITERATIONS: the cap each polish of the fit was given, recorded."""
    from servofmu.identification import identifier

    given = []
    real = identifier.polish
    monkeypatch.setattr(identifier, "polish", lambda *a, **k: given.append(a[3]) or real(*a, **k))
    data, _ = load_selection_data([g1_records["fit"]])
    validation, _ = load_selection_data([g1_records["val"]])
    g1 = sf.load_plant("g1")
    for mode, cap in (("screen", SCREEN_POLISH_ITERATIONS), ("refit", identifier.MAX_POLISH_ITERATIONS)):
        given.clear()
        score = fit_candidate(None, CandidateJob(Candidate("coulomb", 1), g1, data, validation,
                                                 SelectOptions(iterations=5), 1, {}, mode=mode))
        assert score.status == "fitted" and given and set(given) == {cap}, (mode, given)
    assert SCREEN_POLISH_ITERATIONS < identifier.MAX_POLISH_ITERATIONS


def test_a_start_that_is_the_structures_fit_is_polished_without_a_swarm(g1_records):
    """A polished job (a larger candidate's fit reduced to this structure) runs no swarm: its stages are the
    start and the polish; from a start a few per cent off g1 it ends where the swarm-and-polish fit ends (same
    BIC within a noise variance), screened as the first round's fits are."""
    data, _ = load_selection_data([g1_records["fit"]])
    validation, _ = load_selection_data([g1_records["val"]])
    g1 = sf.load_plant("g1")
    off = g1.with_parameters(g1.parameter_vector() * np.where(g1.parameter_vector() != 0, 1.04, 1.0))
    options = SelectOptions(iterations=10, seed=1)
    polished = fit_candidate(None, CandidateJob(Candidate("coulomb", 1), off, data, validation, options, 1, {},
                                                mode="screen", polished=True))
    searched = fit_candidate(None, CandidateJob(Candidate("coulomb", 1), off, data, validation, options, 1, {},
                                                mode="screen", seeded=True))
    assert [st.name for st in polished.result.stages] == ["start", "polish"]
    assert searched.result.stages[0].name == "pso"
    assert polished.screened and searched.screened
    assert abs(polished.bic - searched.bic) < 1.0, (polished.bic, searched.bic)


def test_a_ripple_search_or_a_fit_on_shares_takes_every_local_core(monkeypatch):
    """In a round of three fits on two local workers, the ripple's search and the fit polished on the records'
    shares first are sent with both cores' threads (each is its round's longest fit), the plain fit with one; on
    a Dask cluster every fit keeps one."""
    from types import SimpleNamespace

    from servofmu.selection import fitting

    monkeypatch.setattr(fitting, "available_cores", lambda: 2)
    g1 = sf.load_plant("g1")
    rippled = plant_from_dict({"name": "r", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
                               "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4},
                               "load": {"ripple_amplitude": 0.0, "ripple_period": 1.0, "ripple_phase": 0.0}})
    base = CandidateJob(Candidate("coulomb", 1), g1, None, None, SelectOptions(), 1, {})
    groups = [(base, {Candidate("coulomb", 1, 0, ("ripple",)): rippled}),
              (replace(base, mode="refit", continued=True), {Candidate("coulomb", 2): g1}),
              (base, {Candidate("stribeck", 1): g1})]
    for scheduler, expected in ((None, {"coulomb+ripple/1": 2, "coulomb/2": 2, "stribeck/1": 1}),
                                ("tcp://cluster:8786", {"coulomb+ripple/1": 1, "coulomb/2": 1, "stribeck/1": 1})):
        sent = {}

        def imap(_, jobs):
            for i, j in enumerate(jobs):
                sent[j.candidate.name] = j.threads
                yield i, CandidateScore(j.candidate, "failed")

        pool = SimpleNamespace(scheduler=scheduler, workers=2, imap=imap)
        fitting.fit_groups(pool, groups, RunOptions(), 0)
        assert sent == expected, scheduler


def test_a_fit_whose_stribeck_bump_collapsed_has_a_screening_bound(g1_records, monkeypatch):
    """A Stribeck fit of g1's Coulomb axis ends with a static level equal to its Coulomb level (no bump): the
    change of coordinates to the parameters has no derivative there (no finite intervals), but the polish's own
    Jacobian does, and the screening bound comes from it — finite, never above the fit's own BIC, equal to it
    where the polish converged, far below it where the polish was stopped after one step — instead of −inf, which
    sent every such fit to the full polish."""
    import servofmu.selection.select as select_module

    data, _ = load_selection_data([g1_records["fit"]])
    validation, _ = load_selection_data([g1_records["val"]])
    f = sf.load_plant("g1").friction
    start = plant_from_dict({"name": "s", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
                             "friction": {"model": "stribeck", "fc_pos": f.fc_pos, "fc_neg": f.fc_neg,
                                          "fs_pos": f.fc_pos, "fs_neg": f.fc_neg, "vs": 0.01}})
    gaps = []
    for iterations in (1, SCREEN_POLISH_ITERATIONS):
        monkeypatch.setattr(select_module, "SCREEN_POLISH_ITERATIONS", iterations)
        score = fit_candidate(None, CandidateJob(Candidate("stribeck", 1), start, data, validation,
                                                 SelectOptions(iterations=10, seed=1), 1, {}, mode="screen"))
        fit = dict(zip(score.result.names, score.result.theta))
        assert fit["fs_neg"] == fit["fc_neg"] and not np.all(np.isfinite(score.result.intervals))
        assert np.isfinite(score.bic_bound) and score.bic_bound <= score.bic + 1e-6
        gaps.append(score.bic - score.bic_bound)
    assert gaps[0] > 100 and gaps[1] < 1, gaps


def test_a_starts_log_likelihood_is_the_gaussian_one_of_its_own_simulation(g1_records):
    """start_neg2loglik at g1's values: N·(ln(2π·RSS/N) + 1) of a simulation written here against the record's
    velocities; larger at a start 10 % off; inf for a start that cannot be scored (no data)."""
    from servofmu.selection.select import start_neg2loglik

    data, _ = load_selection_data([g1_records["fit"]])
    g1 = sf.load_plant("g1")
    t = np.arange(0, 20, DT)
    v = BatchSimulator(g1).simulate_record(g1.parameter_vector()[None], t, _input(t, 1), rtol=1e-10).v[0]
    measured = np.loadtxt(g1_records["fit"].with_suffix(".csv"), delimiter=",", skiprows=1)[:, 2]
    rss = float(np.sum((v - measured) ** 2))
    job = CandidateJob(Candidate("coulomb", 1), g1, data, data, SelectOptions(), 1, {})
    assert start_neg2loglik(None, job) == pytest.approx(v.size * (math.log(2 * math.pi * rss / v.size) + 1),
                                                        abs=0.01)
    off = g1.with_parameters(g1.parameter_vector() * 1.1)
    assert start_neg2loglik(None, job) < start_neg2loglik(None, replace(job, start=off))
    assert start_neg2loglik(None, replace(job, data=None)) == math.inf
