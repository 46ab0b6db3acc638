"""`servofmu select`: candidate names, the linear estimate against scipy, the ranking, a small selection from
records end to end, and bad input refused in one line with nothing written."""
import json
import math
from dataclasses import replace

import h5py
import numpy as np
import pytest
from scipy import signal
from scipy.stats import chi2

import servofmu as sf
from servofmu.errors import UserError
from servofmu.measurement.records import import_records
from servofmu.runtime import RunOptions
from servofmu.selection.candidates import (Candidate, default_candidates, parse_candidates, supported_load_terms,
                                           term_candidates, with_second_stage)
from servofmu.selection.estimate import Series, estimate_linear
from servofmu.selection.select import STRONG_EVIDENCE, CandidateScore, rank, validation_allowance, validation_margin
from servofmu.simulation.batch import BatchSimulator

from clitools import assert_one_line_error, run

DT = 0.01


# ---------------------------------------------------------------------------------------------------------------
# Candidates
# ---------------------------------------------------------------------------------------------------------------
def test_candidate_names_expand_over_the_orders_with_and_without_a_zero():
    names = [c.name for c in parse_candidates(["coulomb", "lugre/2z"], orders=(1, 3))]
    assert names == ["coulomb/1", "coulomb/3", "coulomb/3z", "lugre/2z"]
    assert len(default_candidates((1, 2, 3))) == 3 * 5  # order 1 without a zero, 2 and 3 with and without
    loads = [t for t in supported_load_terms() if t != "offset"]  # an offset: the same force as other levels
    assert [c.name for c in term_candidates(Candidate("stribeck", 2, 1))] == \
        [f"stribeck+{t}/2z" for t in (*loads, "delta", "fv_asym")]
    assert [c.name for c in term_candidates(Candidate("coulomb", 1))] == \
        [f"coulomb+{t}/1" for t in (*loads, "fv_asym")]  # Coulomb friction has no Stribeck curve to shape
    assert [c.name for c in parse_candidates(None, (2,))][:2] == ["coulomb/2", "coulomb/2z"]
    assert [c.name for c in parse_candidates(["lugre+fv_asym+delta/2"])] == ["lugre+delta+fv_asym/2"]
    # laws named alone leave the structure to the data: the default set's second stage; a term or an order, none
    assert with_second_stage(None) and with_second_stage(["coulomb", "dahl"])
    assert not with_second_stage(["coulomb", "stribeck/1"]) and not with_second_stage(["coulomb+delta"])


def test_friction_terms_start_where_they_change_nothing_and_leave_again():
    """A friction term added to a fit starts at δ = 2 and fv_neg = fv_pos = fv (half of G's DC damping where fv is
    0, G taking the rest) — the same forces, so the same
    response to rounding — and taken away again gives the plant it was added to; the structures nested in a term's
    candidate keep the term where their law takes it."""
    from servofmu.selection.starts import nested_structures, with_terms, without_terms

    plant = sf.load_plant("lugre_servo")
    both = Candidate("lugre", 1, 0, ("delta", "fv_asym"))
    added = with_terms(plant, both)
    values = added.friction.values()
    assert values["delta"] == 2.0 and values["fv_pos"] == values["fv_neg"] == plant.friction.values()["fv"] != 0
    assert "fv" not in values
    t = np.arange(0.0, 3.0, 0.01)
    u = 2.0 * np.sin(2 * np.pi * t) + 0.5 * np.sin(2 * np.pi * 4.3 * t)
    runs = [BatchSimulator(p).simulate_record(p.parameter_vector()[None], t, u, rtol=1e-10).v[0]
            for p in (plant, added)]
    np.testing.assert_allclose(runs[1], runs[0], rtol=1e-12, atol=1e-15)
    assert without_terms(added, {"delta", "fv_asym"}).friction == plant.friction
    # without viscous friction, half of the damping G holds at DC moves into fv_pos = fv_neg: the same response
    g2 = sf.load_plant("g2")  # third order, a complex pair
    shared = with_terms(g2, Candidate("coulomb", 3, 0, ("fv_asym",)))
    num, den = g2.transfer_function()
    c = 0.5 * den[-1] / num[-1]
    assert shared.friction.values()["fv_pos"] == shared.friction.values()["fv_neg"] == pytest.approx(c, rel=1e-12)
    assert all(p.real < 0 for p in shared.all_poles()) and shared.zeros == g2.zeros
    runs = [BatchSimulator(p).simulate_record(p.parameter_vector()[None], t, u, rtol=1e-10).v[0]
            for p in (g2, shared)]
    np.testing.assert_allclose(runs[1], runs[0], rtol=0, atol=1e-7 * np.max(np.abs(runs[0])))
    assert [c.name for c in nested_structures(Candidate("lugre", 2, 1, ("delta", "fv_asym")))] == [
        "stribeck+delta+fv_asym/2z", "coulomb+fv_asym/2z", "lugre+delta+fv_asym/2", "stribeck+delta+fv_asym/2",
        "coulomb+fv_asym/2"]


@pytest.mark.parametrize("names, orders, fragment", [
    (["friction"], (1,), "unknown friction law 'friction'"),
    (["coulomb+fv"], (1,), "viscous friction fv is not told apart"),
    (["coulomb+bump"], (1,), "unknown term 'bump'"),
    (["coulomb+delta"], (1,), "the coulomb law has no delta"),
    (["coulomb/1z"], (1,), "a zero needs G of order 2"),
    (["coulomb/x"], (1,), "must be a whole number"),
    (["coulomb"], (0,), "order 0 of G(s)"),
    (["coulomb/9"], (1,), "order 9 of G(s)"),
])
def test_bad_candidates_are_refused(names, orders, fragment):
    with pytest.raises(UserError, match=None) as info:
        parse_candidates(names, orders)
    assert fragment in str(info.value)


# ---------------------------------------------------------------------------------------------------------------
# The linear estimate against scipy's simulation of a known G
# ---------------------------------------------------------------------------------------------------------------
def test_linear_estimate_recovers_a_g_with_a_zero_and_coulomb_friction_from_a_record():
    """v = G·(u − F) integrated by scipy (an independent reference): G = 60(s + 4)/((s + 2)(s² + 6s + 80)),
    F = 0.3·[v > 0] − 0.2·[v < 0] fed back through a fine fixed-step loop; the estimate finds G's roots and the
    Coulomb levels within a few per cent."""
    num, den = 60 * np.poly([-4.0]), np.poly([-2.0, -3 + 8.5440037j, -3 - 8.5440037j]).real
    ss = signal.StateSpace(*signal.tf2ss(num, den))
    fine = 1e-4
    t = np.arange(0, 20, fine)
    u = 2 * np.sin(2 * np.pi * 0.7 * t) + 0.8 * np.sin(2 * np.pi * 3.3 * t)
    d = signal.cont2discrete((ss.A, ss.B, ss.C, ss.D), fine, method="bilinear")
    x, v = np.zeros(3), np.empty(t.size)
    for k in range(t.size):
        v[k] = (d[2] @ x)[0]
        force = 0.3 if v[k] > 0 else (-0.2 if v[k] < 0 else 0.0)
        x = d[0] @ x + d[1][:, 0] * (u[k] - force)
    step = int(DT / fine)
    est = estimate_linear([Series(u=u[::step], v=v[::step], dt=DT, periodic=False)], order=3, zeros=1)
    poles = sorted(est.poles, key=lambda p: (p.real, p.imag))
    assert np.allclose(sorted(np.roots(den), key=lambda p: (p.real, p.imag)), poles, rtol=0.05, atol=0.1)
    assert abs(est.zeros[0] + 4) < 0.2
    assert abs(est.gain / 60 - 1) < 0.05
    assert abs(est.fc_pos - 0.3) < 0.03 and abs(est.fc_neg - 0.2) < 0.03


def test_a_resonant_axis_whose_first_order_fit_has_the_wrong_sign_gets_its_own_orders_start():
    """G = 83.2·(s + 6)/(s² + 8s + 416) (DC gain 1.2, a resonance at 3.2 Hz) with Coulomb 0.3/0.25 N, driven at 1
    and 3.1 Hz, then 0.6 and 4.3 Hz (phases as drawn, 1 % noise): the first-order least-squares fit has a negative DC gain.
    The sign the starts keep is the sign of the input's power (Σ u·v > 0 for a force into a damped mass), so the
    second-order estimate with a zero is kept and lands near the truth (it was replaced by the first order's, which
    led every candidate of a selection astray)."""
    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.estimate import start_estimates

    truth = plant_from_dict({"name": "r", "linear": {"poles": [[-4.0, 20.0], [-4.0, -20.0]], "zeros": [[-6.0, 0.0]],
                                                     "dc_gain": 1.2},
                             "friction": {"model": "coulomb", "fc_pos": 0.3, "fc_neg": 0.25}})
    rng = np.random.default_rng(6001)
    t = np.arange(0, 20.0, DT)
    ph = rng.uniform(0, 2 * np.pi, 4)
    u = np.where(t < t[-1] / 2, 2 * np.sin(2 * np.pi * t + ph[0]) + 0.6 * np.sin(2 * np.pi * 3.1 * t + ph[1]),
                 0.7 * np.sin(2 * np.pi * 0.6 * t + ph[2]) + 0.3 * np.sin(2 * np.pi * 4.3 * t + ph[3]))
    v = BatchSimulator(truth).simulate_record(truth.parameter_vector()[None], t, u, rtol=1e-10).v[0]
    v = v + 0.01 * np.std(v) * rng.standard_normal(v.size)
    series = [Series(u=u, v=v, dt=DT, periodic=False)]
    first = estimate_linear(series, 1, 0)
    assert first.gain / -first.poles[0].real < 0  # the wrong sign
    est = start_estimates(series, [(2, 1)])[(2, 1)]
    assert np.allclose(sorted(est.poles, key=lambda p: p.imag), [-4 - 20j, -4 + 20j], rtol=0.1)
    assert abs(est.zeros[0] + 6) < 1.5


def test_a_larger_fit_hands_its_nested_candidates_a_start():
    """A third-order fit whose real zero sits beside a complex pair of nearly equal poles reduces to the
    second-order candidate (the pair's real part stays a pole, the DC gain is kept); the best candidate's law
    hands its G and shared levels to the law it contains, when that law's own fit is worse."""
    from servofmu.model.plant import plant_from_dict
    from types import SimpleNamespace

    from servofmu.selection.starts import reduced_starts

    lugre = plant_from_dict({"name": "l", "linear": {"poles": [[-5.0, 0.0], [-43.0, 1.9], [-43.0, -1.9]],
                                                     "zeros": [[-46.7, 0.0]], "dc_gain": 2.0},
                             "friction": {"model": "lugre", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.45,
                                          "fs_neg": 0.35, "vs": 0.05, "sigma0": 1e4, "sigma1": 30.0}})
    fit = SimpleNamespace(plant=lugre)  # what reduced_starts reads of a result
    scores = [CandidateScore(Candidate("lugre", 3, 1), "fitted", result=fit, bic=-100.0),
              CandidateScore(Candidate("stribeck", 3, 1), "fitted", result=fit, bic=-90.0)]
    starts = reduced_starts(scores, default_candidates((1, 2, 3)), 300.0, np.array([-0.2, 0.1, 0.3]))
    reduced = starts[Candidate("lugre", 2)]
    assert reduced.poles == (-5 + 0j, -43 + 0j) and reduced.zeros == () and reduced.dc_gain == 2.0
    nested = starts[Candidate("stribeck", 3, 1)]
    assert nested.friction.model == "stribeck" and nested.poles == lugre.poles
    assert (nested.friction.fs_pos, nested.friction.vs) == (0.45, 0.05)


def test_a_load_term_winner_hands_its_fit_to_the_nested_laws_that_rank_below_it():
    """stribeck+ripple/1 ranked first: coulomb+ripple/1, fitted worse, gets the winner's G and ripple with Coulomb
    levels, to be polished again; a nested law that already fits better, or a winner without load terms, none."""
    from types import SimpleNamespace

    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.starts import from_winner

    ripple = {"ripple_amplitude": 0.2, "ripple_period": 0.05, "ripple_phase": 0.7}
    stribeck = plant_from_dict({"name": "s", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
                                "friction": {"model": "stribeck", "fc_pos": 0.47, "fc_neg": 0.37, "fs_pos": 0.5,
                                             "fs_neg": 0.4, "vs": 1.25}, "load": ripple})
    first = CandidateScore(Candidate("stribeck", 1, 0, ("ripple",)), "fitted", result=SimpleNamespace(plant=stribeck),
                           bic=-100.0)
    nested = Candidate("coulomb", 1, 0, ("ripple",))
    speeds = np.array([0.3, -0.3])
    starts = from_winner(first, [first, CandidateScore(nested, "fitted", bic=-90.0)], speeds)
    assert list(starts) == [nested]
    assert starts[nested].friction.model == "coulomb" and starts[nested].poles == stribeck.poles
    assert starts[nested].load == stribeck.load
    assert from_winner(first, [first, CandidateScore(nested, "fitted", bic=-110.0)], speeds) == {}
    plain = replace(first, candidate=Candidate("stribeck", 1))
    assert from_winner(plain, [plain, CandidateScore(Candidate("coulomb", 1), "fitted", bic=-90.0)], speeds) == {}


def test_the_first_hands_its_fit_to_the_fitted_candidates_nested_in_it():
    """lugre/3z ranked first, its zero cancelling its middle pole: the fitted candidates with its load terms (none),
    a law it contains, no higher order and no more zeros get starts from its fit — the cancelling pair dropped
    before the fastest poles are — and none of another load, richer, or not fitted."""
    from types import SimpleNamespace

    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.starts import with_law, with_terms, within_first

    lugre = plant_from_dict({"name": "l", "linear": {"poles": [[-5.0, 0.0], [-12.0, 0.0], [-40.0, 0.0]],
                                                     "zeros": [[-12.5, 0.0]], "dc_gain": 2.0},
                             "friction": {"model": "lugre", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.45,
                                          "fs_neg": 0.35, "vs": 0.05, "sigma0": 1e4, "sigma1": 100.0}})
    first = CandidateScore(Candidate("lugre", 3, 1), "fitted", result=SimpleNamespace(plant=lugre), parameters=12,
                           bic=-100.0)
    fitted = {c: CandidateScore(c, "fitted", parameters=p, bic=-90.0) for c, p in (
        (Candidate("stribeck", 2), 8), (Candidate("coulomb", 1), 4), (Candidate("lugre", 2), 10),
        (Candidate("stribeck", 2, 0, ("ripple",)), 11), (Candidate("lugre", 3, 1), 12))}
    failed = CandidateScore(Candidate("coulomb", 3), "failed")
    starts = within_first(first, [first, *fitted.values(), failed], np.array([0.4, -0.4]))
    assert set(starts) == {Candidate("stribeck", 2), Candidate("coulomb", 1), Candidate("lugre", 2)}
    stribeck = starts[Candidate("stribeck", 2)]
    assert stribeck.poles == (-5.0, -40.0) and stribeck.zeros == () and stribeck.dc_gain == 2.0
    assert stribeck.friction.model == "stribeck" and stribeck.friction.fs_pos == 0.45
    assert starts[Candidate("coulomb", 1)].poles == (-5.0,)
    assert within_first(failed, [failed, *fitted.values()], np.array([0.4])) == {}
    rippled = fitted[Candidate("stribeck", 2, 0, ("ripple",))]  # ranked first: the law and G without the ripple
    stribeck = with_law(replace(lugre, poles=(-5.0, -40.0), zeros=()), "stribeck", np.array([0.4, -0.4]))
    rippled = replace(rippled, result=SimpleNamespace(plant=with_terms(stribeck, rippled.candidate)))
    starts = within_first(rippled, [rippled, *fitted.values()], np.array([0.4, -0.4]))
    assert set(starts) == {Candidate("stribeck", 2), Candidate("coulomb", 1)}
    assert starts[Candidate("stribeck", 2)] == replace(stribeck, name="candidate")


def test_a_load_term_winner_with_a_zero_hands_its_fit_to_the_structures_without_it():
    """stribeck+ripple/2z ranked first: its nested structures are the Coulomb law with the zero, then both laws
    without it; started from its fit, the zero is dropped and the poles, DC gain and ripple kept.  A screened
    ripple candidate ranked below a structure without load terms leads the nesting when its full polish could
    reach a BIC below that structure's."""
    from types import SimpleNamespace

    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.starts import from_winner, term_leader, nested_structures

    winner = Candidate("stribeck", 2, 1, ("ripple",))
    assert [c.name for c in nested_structures(winner)] == ["coulomb+ripple/2z", "stribeck+ripple/2",
                                                             "coulomb+ripple/2"]
    assert [c.name for c in nested_structures(winner, orders=(1, 2, 3))][-1] == "stribeck+ripple/1"
    plant = plant_from_dict({"name": "s", "linear": {"poles": [[-5.0, 0.0], [-40.0, 0.0]], "zeros": [[-60.0, 0.0]],
                                                     "dc_gain": 2.0},
                             "friction": {"model": "stribeck", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.4,
                                          "fs_neg": 0.3, "vs": 0.05},
                             "load": {"ripple_amplitude": 0.15, "ripple_period": 0.04, "ripple_phase": -1.1}})
    first = CandidateScore(winner, "fitted", result=SimpleNamespace(plant=plant), bic=-100.0)
    nested = [CandidateScore(c, "fitted", bic=-90.0) for c in nested_structures(winner, (1, 2))]  # fitted worse
    starts = from_winner(first, [first, *nested], np.array([0.5, -0.5]))
    assert list(starts) == [s.candidate for s in nested]
    truth = starts[Candidate("coulomb", 2, 0, ("ripple",))]
    assert truth.zeros == () and truth.poles == plant.poles and truth.dc_gain == 2.0
    assert truth.friction.model == "coulomb" and truth.load == plant.load
    lower = starts[Candidate("stribeck", 1, 0, ("ripple",))]  # the fastest pole and the zero dropped
    assert lower.poles == (-5.0,) and lower.zeros == () and lower.dc_gain == 2.0 and lower.load == plant.load
    plain = CandidateScore(Candidate("stribeck", 2, 1), "fitted", result=SimpleNamespace(plant=plant), bic=-90.0)
    screened = replace(first, bic=-80.0, screened=True, bic_bound=-120.0)
    assert term_leader([plain, screened]).candidate == winner
    assert term_leader([plain, replace(screened, bic_bound=-60.0)]).candidate == plain.candidate


def test_a_load_term_winner_of_a_higher_order_hands_its_fit_to_the_order_below_never_fitted():
    """coulomb+ripple/2 ranked first (the first stage chose order 2 without the ripple, whose force a pole took
    up) and coulomb+ripple/1 never fitted: it is started from the winner's fit without its fastest root; a
    complex pair where one pole is left becomes a real pole at its magnitude."""
    from types import SimpleNamespace

    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.starts import from_winner, reduced_to

    load = {"ripple_amplitude": 0.2, "ripple_period": 0.05, "ripple_phase": 0.7}
    plant = plant_from_dict({"name": "c", "linear": {"poles": [[-400.0, 0.0], [-10.0, 0.0]], "dc_gain": 1.0},
                             "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}, "load": load})
    first = CandidateScore(Candidate("coulomb", 2, 0, ("ripple",)), "fitted", result=SimpleNamespace(plant=plant),
                           bic=-100.0)
    target = Candidate("coulomb", 1, 0, ("ripple",))
    starts = from_winner(first, [first], np.array([0.3, -0.3]))
    assert list(starts) == [target]
    assert starts[target].poles == (-10.0,) and starts[target].dc_gain == 1.0 and starts[target].load == plant.load
    assert from_winner(first, [first, CandidateScore(target, "fitted", bic=-110.0)], np.array([0.3])) == {}
    assert from_winner(first, [first], np.array([0.3]), orders=(2, 3)) == {}  # order 1 not among the selection's
    pair = plant_from_dict({"name": "c", "linear": {"poles": [[-3.0, 4.0], [-3.0, -4.0], [-1.0, 0.0]],
                                                    "dc_gain": 1.0},
                            "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}})
    assert reduced_to(pair, Candidate("coulomb", 2), np.array([0.3])).poles == (-1.0, -5.0)


def test_a_coulomb_law_nested_in_a_stribeck_fit_holds_its_curve_over_the_speeds():
    """A Stribeck fit reduced to Coulomb: each level the mean over the data's speeds on that side of the curve
    fc + (fs − fc)·exp(−(v/vs)²), its viscous term left to fv, which the nested law keeps — not fc: a fit may
    hold the axis's level in fs with vs above the speeds."""
    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.starts import with_law

    stribeck = plant_from_dict({"name": "s", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
                                "friction": {"model": "stribeck", "fc_pos": 0.47, "fc_neg": 0.37, "fs_pos": 0.5,
                                             "fs_neg": 0.4, "vs": 1.25, "fv": 0.1}})
    speeds = np.array([0.05, 0.2, 0.6, -0.1, -0.4])
    curve = lambda v, fc, fs: fc + (fs - fc) * np.exp(-(v / 1.25) ** 2)  # noqa: E731
    coulomb = with_law(stribeck, "coulomb", speeds)
    assert coulomb.friction.model == "coulomb" and coulomb.friction.fv == 0.1
    assert coulomb.friction.fc_pos == pytest.approx(np.mean(curve(speeds[:3], 0.47, 0.5)), rel=1e-3)
    assert coulomb.friction.fc_neg == pytest.approx(np.mean(curve(speeds[3:], 0.37, 0.4)), rel=1e-3)


def test_a_zero_at_the_origin_is_read_as_a_spring():
    """G' = s·N/(s·D + k·N) is G = N/D with a spring k on the position: a fit of G' (here of order 3 with two
    zeros, one at the origin) gives the candidate of order 2 with one zero and a stiffness, whose G with the
    spring has G's response (compared at 40 frequencies), and nothing where no zero lies near the origin."""
    from servofmu.model.plant import plant_from_dict
    from servofmu.selection.candidates import spring_form

    num, den, k = np.array([50.0]), np.polymul([1.0, 3.0], [1.0, 20.0]), 5.0
    num_s, den_s = np.polymul([1.0, 1e-6], num), np.polyadd(np.polymul([1.0, 0.0], den), k * num)
    pairs = lambda roots: [[r.real, r.imag] for r in roots]  # noqa: E731
    fitted = plant_from_dict({"name": "f", "linear": {"poles": pairs(np.roots(den_s)), "zeros": pairs(np.roots(num_s)),
                                                      "dc_gain": num_s[-1] / den_s[-1]},
                              "friction": {"model": "stribeck", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.45,
                                           "fs_neg": 0.35, "vs": 0.05}})
    target, spring = spring_form(Candidate("stribeck", 3, 1), fitted)
    assert target == Candidate("stribeck", 2, 0, ("stiffness",))
    assert sorted(spring.all_poles(), key=abs) == pytest.approx([-3.0, -20.0], rel=1e-4)
    assert spring.zeros == () and spring.load.stiffness == pytest.approx(k, rel=1e-4)
    s = 1j * np.logspace(-1, 3, 40)
    g = spring.frequency_response(s.imag)
    assert g / (1 + spring.load.stiffness * g / s) == pytest.approx(fitted.frequency_response(s.imag), rel=1e-5)
    assert spring.friction == fitted.friction and spring.load.x0 == 0.0
    from types import SimpleNamespace  # the ranking: the zero at the origin flagged once its spring is fitted

    hidden = CandidateScore(Candidate("stribeck", 3, 1), "fitted", result=SimpleNamespace(plant=fitted), bic=-101.0,
                            validation_neg2loglik=-50.0, parameters=9)
    named = CandidateScore(target, "fitted", result=SimpleNamespace(plant=spring), bic=-100.0,
                           validation_neg2loglik=-50.0, parameters=9)
    assert rank([hidden])[0].flags == ()
    assert [(s.name, s.flags) for s in rank([hidden, named])] == [(target.name, ()),
                                                                  (hidden.name, ("zero at the origin",))]
    no_spring = plant_from_dict({"name": "n", "linear": {"poles": [[-3.0, 0.0], [-20.0, 0.0]], "zeros": [[-8.0, 0.0]],
                                                         "dc_gain": 1.0}, "friction": {"model": "coulomb",
                                                                                        "fc_pos": 0.3, "fc_neg": 0.3}})
    assert spring_form(Candidate("coulomb", 2, 1), no_spring) is None


def _first_order(pole, gain, fc, load, gain_key="dc_gain"):
    """A plant of one pole with Coulomb friction (fc+, fc−) and the [load] ``load``."""
    from servofmu.model.plant import plant_from_dict

    return plant_from_dict({"name": "r", "linear": {"poles": [[pole, 0.0]], gain_key: gain},
                            "friction": {"model": "coulomb", "fc_pos": fc[0], "fc_neg": fc[1]}, "load": load})


NO_RIPPLE = {"ripple_amplitude": 0.0, "ripple_period": 1.0, "ripple_phase": 0.0}


def _ripple_searched(truth, parent, data):
    """The ripple search's start from ``parent`` on ``data``, and the residuals of the truth, the start and the
    parent on it."""
    from servofmu.identification.prior import identified_mask
    from servofmu.selection.data import criterion_for
    from servofmu.selection.period import ripple_start

    start = ripple_start(parent, data)
    crit = criterion_for(truth, data)
    return start, [float(np.sum(crit.residuals(p.parameter_vector()[identified_mask(p)][None], 1e-10) ** 2))
                   for p in (truth, start, parent)]


def test_a_ripple_is_found_from_the_residuals_over_position(tmp_path):
    """g1 with a 0.25 N ripple of period 37 mm (10 s record, 40 dB): from a fit without it — G and levels 3 % off,
    the ripple at zero force — the search finds its period within 1 %, its amplitude within 20 %, and a start
    whose output error is the truth's (the parent's is 60 times more), from which the polish ends at the truth
    within noise."""
    from servofmu.identification.prior import identified_mask
    from servofmu.selection.data import criterion_for, load_selection_data
    from servofmu.selection.period import ripple_start
    from servofmu.selection.select import CandidateJob, fit_candidate

    truth = _first_order(-10.0, 1.0, (0.5, 0.4),
                         {"ripple_amplitude": 0.25, "ripple_period": 0.037, "ripple_phase": -1.0})
    data, _ = load_selection_data([_record(tmp_path, "ripple", truth, 4)])
    start, rss = _ripple_searched(truth, _first_order(-10.3, 0.97, (0.515, 0.39), NO_RIPPLE), data)
    assert start.load.ripple_period == pytest.approx(0.037, rel=0.01)
    assert start.load.ripple_amplitude == pytest.approx(0.25, rel=0.2)
    assert rss[1] < 1.01 * rss[0] and rss[2] > 10 * rss[1]  # the search's polish on growing shares: the truth's
    assert ripple_start(start, data) is start  # a ripple of some force is the fit's to refine, not searched again
    polished = fit_candidate(None, CandidateJob(Candidate("coulomb", 1, 0, ("ripple",)), start, data, data,
                                                sf.SelectOptions(), None, {}, mode="refit"))
    fitted = polished.result.plant  # the polish from the start: the optimum, the truth within its noise
    crit = criterion_for(truth, data)
    assert float(np.sum(crit.residuals(fitted.parameter_vector()[identified_mask(fitted)][None], 1e-10) ** 2)) \
        <= rss[0]
    assert fitted.load.ripple_period == pytest.approx(0.037, rel=2e-3)


def test_a_search_that_cannot_pay_for_a_ripple_stops_at_the_coarse_grid(tmp_path):
    """On a record without a ripple the coarse grid's best drop is noise: the start is the parent's values with
    that ripple (no joint steps move them), and its ripple lowers −2·ln L by less than the ripple's BIC penalty.
    The grid's forces simulated side by side on threads give the residuals one simulation at a time gives."""
    from servofmu.identification.prior import identified_mask
    from servofmu.selection.data import criterion_for, load_selection_data
    from servofmu.selection.period import SEARCHED_PERIOD, _Forced, _ripple, ripple_start

    truth = _first_order(-10.0, 1.0, (0.5, 0.4), NO_RIPPLE)
    data, _ = load_selection_data([_record(tmp_path, "plain", truth, 5)])
    parent = _first_order(-10.0, 1.0, (0.5, 0.4), NO_RIPPLE)
    start = ripple_start(parent, data)
    mask = identified_mask(parent)
    moved = [n for n, a, b in zip(np.array(parent.parameter_names())[mask], parent.parameter_vector()[mask],
                                  start.parameter_vector()[mask]) if a != b]
    assert moved == ["ripple_amplitude", "ripple_period", "ripple_phase"]
    crit = criterion_for(start, data)
    rss = [float(np.sum(crit.residuals(p.parameter_vector()[mask][None], 1e-10) ** 2)) for p in (parent, start)]
    n = crit.residuals(parent.parameter_vector()[mask][None], 1e-10).size
    assert 0 < n * np.log(rss[0] / rss[1]) < (2 + SEARCHED_PERIOD) * np.log(n)
    forced = _Forced(parent, data, threads=2)
    theta = parent.parameter_vector()[mask]
    forces = [_ripple(k, (0.02, 0.01)) for k in (3.0, 17.0, 40.0)]
    together = forced.with_forces(theta, forces)
    assert all(np.array_equal(a, forced.residuals(theta, f)[0]) for a, f in zip(together, forces))
    assert not np.array_equal(together[0], together[1])


def test_a_shares_jacobian_is_scipys_own_differences_in_one_batch(tmp_path):
    """continued_start's polish of a share, its Jacobian's columns simulated in one batch call, takes the steps
    scipy's least_squares takes with its own forward differences (diff_step), to the last digit — at parameters
    of zero (the ripple's phase) too, and where the Jacobian is asked for away from the last residuals."""
    from scipy.optimize import least_squares

    from servofmu.identification.prior import identified_mask
    from servofmu.selection.data import criterion_for, first_share, load_selection_data
    from servofmu.selection.period import DIFFERENCE, RTOL, SHARE_TOL, _batched

    truth = _first_order(-10.0, 1.0, (0.5, 0.4),
                         {"ripple_amplitude": 0.25, "ripple_period": 0.037, "ripple_phase": -1.0})
    data, _ = load_selection_data([_record(tmp_path, "share", truth, 4)])
    start = _first_order(-10.3, 0.97, (0.515, 0.39),
                         {"ripple_amplitude": 0.2, "ripple_period": 0.0371, "ripple_phase": 0.0})
    crit = criterion_for(start, first_share(data, 0.2))
    theta = start.parameter_vector()[identified_mask(start)]
    assert np.any(theta == 0)
    residuals, jacobian = _batched(crit)
    scale = np.maximum(np.abs(theta), 1e-12)
    ours = least_squares(residuals, theta, jac=jacobian, x_scale=scale, xtol=SHARE_TOL, ftol=SHARE_TOL)
    theirs = least_squares(lambda th: crit.residuals(th[None], RTOL)[0], theta, x_scale=scale,
                           diff_step=DIFFERENCE, xtol=SHARE_TOL, ftol=SHARE_TOL)
    assert ours.nfev == theirs.nfev > 1 and np.array_equal(ours.x, theirs.x)
    away = jacobian(theta)  # the last residuals were at the end, not here
    residuals(theta)
    assert np.array_equal(away, jacobian(theta))


def test_a_ripple_is_found_in_closed_loop_records():
    """An axis with a 12 N cogging ripple of 32 mm (40/32 N Coulomb) following a 0.3 m stroke in the example
    drive's loop, 1 µm of position noise and 1 % of command noise: from a fit without the ripple (G and levels
    3 % off) the search finds the period within 1 % and the amplitude within 5 %, and the start's residuals are
    the truth's.  The ripple acts on the plant and not in the recorded command: a search that also added it to
    the model's command found twice the amplitude and halved the residuals only."""
    from servofmu.identification.closed_loop import ClosedLoopData, ClosedLoopSeries
    from servofmu.model.controller import load_controller
    from servofmu.simulation.closed_loop import LoopSimulator

    truth = _first_order(-2.0, 0.01, (40.0, 32.0),
                         {"ripple_amplitude": 12.0, "ripple_period": 0.032, "ripple_phase": 0.3}, gain_key="gain")
    law = load_controller("axis_controller").with_values(encoder_resolution=0.0, force_noise=0.0)
    t = np.arange(0.0, 4.0, law.sample_time)
    reference = 0.15 * (1 - np.cos(2 * np.pi * 0.5 * t)) + 0.01 * np.sin(2 * np.pi * 3.1 * t)
    loop = LoopSimulator(truth).simulate_loop(truth.parameter_vector()[None], t, reference, law, rtol=1e-10)
    rng = np.random.default_rng(3)
    position = loop.position[0] + 1e-6 * rng.standard_normal(t.size)
    command = loop.command[0] + 0.01 * np.std(loop.command[0]) * rng.standard_normal(t.size)
    data = ClosedLoopData((ClosedLoopSeries("r", t, reference, position, command, np.ones(t.size, bool)),), law,
                          "simulated")
    start, rss = _ripple_searched(truth, _first_order(-2.06, 0.0097, (41.2, 31.0), NO_RIPPLE, gain_key="gain"), data)
    assert start.load.ripple_period == pytest.approx(0.032, rel=0.01)
    assert start.load.ripple_amplitude == pytest.approx(12.0, rel=0.05)
    assert rss[1] < 1.1 * rss[0] and rss[2] > 10 * rss[1]


def test_a_rest_position_at_zero_is_not_undetermined():
    """An interval that reaches past zero flags a level or a gain (the data cannot tell it from none) but not a
    spring's rest position or a ripple's phase, whose zero is a value like any other."""
    from types import SimpleNamespace

    from servofmu.selection.select import _undetermined

    fit = SimpleNamespace(names=["pole1", "stiffness", "x0", "ripple_phase", "ripple_amplitude"],
                          theta=np.array([-10.0, 4.0, 1e-3, 0.01, 1e-5]),
                          intervals=np.array([[-10.1, -9.9], [3.9, 4.1], [-0.01, 0.012], [-0.5, 0.52], [-1e-3, 1e-3]]))
    assert _undetermined(fit) == ("ripple_amplitude",)


def test_the_coulomb_levels_are_undetermined_by_their_mean():
    """Levels that trade against each other (their difference shares a spring's rest position's force) are judged
    by their mean: one level's interval reaching zero along that valley flags nothing; a mean that could be zero
    flags both; without a covariance each level is judged alone."""
    from types import SimpleNamespace

    from servofmu.selection.select import _undetermined

    sd = np.array([0.0122, 0.0377, 0.0377, 0.0094])  # coulomb1_spring seed 7's fit of its own structure
    corr = np.eye(4)
    corr[1, 2] = corr[2, 1] = -0.9985  # the levels' estimates move against each other, with the rest position
    corr[1, 3] = corr[3, 1] = 0.99
    corr[2, 3] = corr[3, 2] = -0.99
    names = ["pole1", "fc_pos", "fc_neg", "x0"]

    def fit(theta, covariance=sd[:, None] * corr * sd[None, :]):
        return SimpleNamespace(names=names, theta=np.array(theta), covariance=covariance,
                               intervals=np.array(theta)[:, None] + 1.96 * sd[:, None] * np.array([-1.0, 1.0]))

    assert _undetermined(fit([-10.0, 0.889, 0.012, 0.097])) == ()
    assert _undetermined(fit([-10.0, 0.02, -0.0195, 0.097])) == ("fc_pos", "fc_neg")
    assert _undetermined(fit([-10.0, 0.889, 0.012, 0.097], covariance=None)) == ("fc_neg",)


def test_a_static_level_equal_to_its_coulomb_level_gets_a_finite_search_box():
    """A fit may end with fs = fc (no bump); the next candidate's box around it must still be finite."""
    from servofmu.identification.features import prior_box
    from servofmu.model.plant import plant_from_dict

    start = plant_from_dict({"name": "s", "linear": {"poles": [[-5.0, 0.0]], "dc_gain": 1.0},
                             "friction": {"model": "stribeck", "fc_pos": 0.3, "fc_neg": 0.2, "fs_pos": 0.3,
                                          "fs_neg": 0.25, "vs": 0.05}})
    lower, upper = prior_box(start, 0.8)
    assert np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.all(lower < upper)


# ---------------------------------------------------------------------------------------------------------------
# The ranking
# ---------------------------------------------------------------------------------------------------------------
def _score(name, bic, val, p, white=True, undetermined=(), status="fitted"):
    law, order = name.split("/")
    c = Candidate(law, int(order.rstrip("z")), int(order.endswith("z")))
    return CandidateScore(c, status, parameters=p, bic=bic, validation_neg2loglik=val, white=white,
                          undetermined=undetermined)


def test_ranking_puts_flags_after_clean_candidates_and_failures_last():
    scores = [_score("coulomb/1", -100.0, -50.0, 4),
              _score("stribeck/1", -120.0, -52.0, 7, undetermined=("vs",)),   # lower BIC, but vs undetermined
              _score("coulomb/2", -90.0, -20.0, 5),                           # validation 32 worse: flagged
              _score("coulomb/3", -99.0, -49.0, 6, white=False),               # residuals not white: flagged
              _score("lugre/1", float("nan"), float("nan"), 0, status="failed")]
    ranked = rank(scores)
    assert [s.name for s in ranked] == ["coulomb/1", "stribeck/1", "coulomb/3", "coulomb/2", "lugre/1"]
    assert [s.rank for s in ranked] == [1, 2, 3, 4, 5]
    assert ranked[1].flags == ("undetermined",) and ranked[2].flags == ("residuals",)
    assert ranked[3].flags == ("validation",) and ranked[4].flags == ("fit failed",)


def test_the_validation_allowance_is_the_quantile_of_the_estimation_errors_cost_on_the_validation_record():
    """With linear residuals: where the validation record informs as the fitted one does, the allowance is
    validation_margin(p); where it informs a hundred times more on one parameter (a ripple's period over a longer
    travel), it is the 99.9 % quantile of (θ̂ − θ)ᵀ F_v (θ̂ − θ) that a Monte Carlo of θ̂ ~ N(θ, F⁻¹) gives.  It
    spares the flag only a candidate within STRONG_EVIDENCE of the best BIC."""
    rng = np.random.default_rng(5)
    jac = rng.standard_normal((400, 3))
    theta = np.array([1.0, 2.0, 3.0])
    noise = [rng.standard_normal(400)]

    class Linear:  # validation output errors linear in θ, noise of unit variance
        def __init__(self, a):
            self.a = a

        def errors(self, rows, rtol):
            return [(rows - theta) @ self.a.T + noise[0]]

    same = validation_allowance(jac, np.ones(1), [noise[0]], Linear(jac), theta, noise)
    assert same == pytest.approx(validation_margin(3), rel=1e-3)
    sharper = jac.copy()
    sharper[:, 0] *= 10
    allowance = validation_allowance(jac, np.ones(1), [noise[0]], Linear(sharper), theta, noise)
    fisher, fisher_v = jac.T @ jac, sharper.T @ sharper
    draws = rng.multivariate_normal(np.zeros(3), np.linalg.inv(fisher), 400_000)
    cost = np.einsum("ij,jk,ik->i", draws, fisher_v, draws)
    assert allowance == pytest.approx(np.quantile(cost, 0.999), rel=0.1)
    assert allowance > 4 * validation_margin(3)
    assert math.isnan(validation_allowance(jac, np.ones(1), [noise[0]], object(), theta, noise))  # sine data
    worse_val = -50.0 + validation_margin(4) + 1
    for bic, flagged in ((-120.0 + STRONG_EVIDENCE - 1, ()), (-120.0 + STRONG_EVIDENCE + 1, ("validation",))):
        ranked = rank([replace(_score("coulomb/1", bic, worse_val, 4), validation_allowance=allowance),
                       _score("coulomb/2", -120.0, -50.0, 5)])
        assert next(s for s in ranked if s.name == "coulomb/1").flags == flagged


def test_a_failed_residual_test_flags_only_beside_a_passing_candidate_of_competitive_bic():
    """The residual flag needs a passing candidate without another flag within STRONG_EVIDENCE by BIC: one 24
    worse (odds of 10⁵ against it) does not outrank the structure that fails the tests by chance, one 5 worse
    does, one 5 worse with an undetermined parameter (it passes by fitting the noise) does not."""
    far = rank([_score("coulomb/1", -124.0, -50.0, 4, white=False), _score("coulomb/2z", -100.0, -50.0, 7)])
    assert [s.name for s in far] == ["coulomb/1", "coulomb/2z"] and far[0].flags == ()
    near = rank([_score("coulomb/1", -105.0, -50.0, 4, white=False), _score("coulomb/2z", -100.0, -50.0, 7)])
    assert [s.name for s in near] == ["coulomb/2z", "coulomb/1"] and near[1].flags == ("residuals",)
    undetermined = rank([_score("coulomb/1", -105.0, -50.0, 4, white=False),
                         _score("coulomb/2z", -100.0, -50.0, 7, undetermined=("b0",))])
    assert [s.name for s in undetermined] == ["coulomb/1", "coulomb/2z"] and undetermined[0].flags == ()


def test_the_validation_margin_is_the_estimation_error_of_all_parameters():
    """A right structure of p parameters predicts new data worse than its true values by a χ²(p) amount: the flag's
    margin is χ²(p)'s 99.9 % quantile (scipy's as the reference), so 22 worse flags a 4-parameter candidate but
    not an 8-parameter one."""
    for p in (4, 8, 13):
        assert validation_margin(p) == pytest.approx(chi2.ppf(0.999, p), rel=0.02)
    ranked = {s.name: s for s in rank([_score("lugre/2", -100.0, -60.0, 10), _score("stribeck/2", -110.0, -38.0, 8),
                                       _score("coulomb/2", -105.0, -38.0, 4)])}
    assert ranked["stribeck/2"].flags == () and ranked["stribeck/2"].rank == 1
    assert ranked["coulomb/2"].flags == ("validation",)


# ---------------------------------------------------------------------------------------------------------------
# End to end on records
# ---------------------------------------------------------------------------------------------------------------
def _record(folder, name, plant, seed, output="v", snr_db=40.0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 10, DT)
    u = np.where(t < 5, 2 * np.sin(2 * np.pi * t) + 0.6 * np.sin(2 * np.pi * 3.1 * t),
                 0.7 * np.sin(2 * np.pi * 0.6 * t) + 0.3 * np.sin(2 * np.pi * 4.3 * t))
    response = BatchSimulator(plant).simulate_record(plant.parameter_vector()[None], t, u, rtol=1e-10)
    y = response.v[0] if output == "v" else response.position[0]
    y = y + np.std(y) * 10 ** (-snr_db / 20) * rng.standard_normal(y.size)
    csv = folder / f"{name}.csv"
    np.savetxt(csv, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    import_records([csv], folder / f"{name}.h5", "t", "u", "y", kind="velocity" if output == "v" else "position")
    return folder / f"{name}.h5"


@pytest.fixture(scope="module")
def g1_records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("select")
    g1 = sf.load_plant("g1")
    return {"fit": _record(folder, "fit", g1, 1), "val": _record(folder, "val", g1, 2),
            "position": _record(folder, "pos", g1, 3, output="position"), "folder": folder}


def test_select_ranks_g1s_structure_first_and_writes_every_output(g1_records, tmp_path, monkeypatch):
    """g1 (first order, Coulomb) at 40 dB: coulomb/1 is chosen over the larger candidates; a candidate whose fit
    raises is reported and ranked last while the others go on; SELECT.h5 holds every fitted candidate's result and
    the ranking, the plant file and the result file are the chosen one's."""
    from servofmu.identification.identifier import PSOANNIdentifier

    fit = PSOANNIdentifier.fit

    def failing_for_lugre(self, data):
        if self.structure.friction.model == "lugre":
            raise RuntimeError("integrator gave up")
        return fit(self, data)

    monkeypatch.setattr(PSOANNIdentifier, "fit", failing_for_lugre)
    out = tmp_path / "select.h5"
    selection = sf.select_with_report(
        [g1_records["fit"]], g1_records["val"], out,
        sf.SelectOptions(candidates=("coulomb/1", "coulomb/2", "stribeck/1", "lugre/1"), iterations=15),
        RunOptions(workers=0), report=tmp_path / "select.html")
    names = [s.name for s in selection.scores]
    assert names[0] == "coulomb/1" and names[-1] == "lugre/1"
    assert selection.scores[-1].status == "failed" and "integrator gave up" in selection.scores[-1].message
    chosen = sf.load_plant(tmp_path / "select.toml")
    truth = sf.load_plant("g1")
    assert chosen.friction.model == "coulomb" and chosen.order == 1 and not chosen.zeros
    assert abs(chosen.poles[0].real / truth.poles[0].real - 1) < 0.02
    assert sf.read_result(tmp_path / "select-result.h5").structure.order == 1
    with h5py.File(out) as f:
        ranking = f["selection"]
        assert [n.decode() for n in ranking["name"][()]] == names
        assert ranking.attrs["chosen"] == "coulomb/1"
        assert [s.decode() for s in ranking["status"][()]][-1] == "failed"
        assert set(f["methods"]) == {"coulomb_1", "coulomb_2", "stribeck_1"}
        bic = ranking["bic"][()]
        neg2, n, p = ranking["neg2loglik"][()], ranking["samples"][()], ranking["parameters"][()]
        assert np.allclose(bic[:3], neg2[:3] + p[:3] * np.log(n[:3]))
        # a regular fit: −2·ln L rises by about 1 at a standard error (select.response_roughness)
        assert ranking.attrs["roughness"] == selection.roughness and 0.5 < selection.roughness < 2
    page = (tmp_path / "select.html").read_text()
    assert 'id="chosen"' in page and "coulomb/1" in page and "<img" in page
    assert not selection.rough and 'id="rough"' not in page


def test_the_load_terms_are_fitted_beside_the_refits_when_the_first_structure_stays_first(g1_records, tmp_path,
                                                                                           monkeypatch):
    """A default selection at order 1 on g1: the load terms of the structure the first round ranks first are
    fitted in the round of the refits (two rounds and the screened candidates' polish, not three), each candidate
    once, and coulomb/1 is chosen; the round's costliest fits are sent first."""
    import servofmu.selection.fitting as fitting
    import servofmu.selection.run as selection_run

    rounds, polished = [], []
    fit_groups = fitting.fit_groups

    def spy(pool, groups, run, done):
        rounds.append([c.name for _, g in groups for c in g])
        polished.append([job.polished for job, _ in groups])
        return fit_groups(pool, groups, run, done)

    monkeypatch.setattr(selection_run, "fit_groups", spy)  # the first rounds'
    monkeypatch.setattr(fitting, "fit_groups", spy)  # every later one's (fit_all)
    selection = sf.select_files([g1_records["fit"]], g1_records["val"], tmp_path / "s.h5",
                                sf.SelectOptions(orders=(1,), iterations=15), RunOptions(workers=0))
    names = [s.name for s in selection.scores]
    assert selection.chosen.name == "coulomb/1"
    assert len(names) == len(set(names))
    assert {f"coulomb+{term}/1" for term in ("stiffness", "ripple")} <= set(names)
    assert len(rounds) == 3 and "coulomb+ripple/1" in rounds[1], rounds
    # the smaller candidates' starts from larger fits are polished alone, the load terms searched
    assert polished == [[False], [True, False], [False]], polished


def test_fits_are_sent_costliest_first():
    """A ripple's search first, then the higher order and zero, then the richer law."""
    from servofmu.selection.fitting import expected_cost
    from servofmu.selection.select import CandidateJob

    g1 = sf.load_plant("g1")
    searched = replace(g1, load=replace(g1.load, ripple_amplitude=0.0))  # a ripple at zero force: searched
    jobs = [CandidateJob(c, searched if c.terms else g1, None, None, sf.SelectOptions(), None, {})
            for c in parse_candidates(["coulomb/1", "lugre/1", "coulomb/3z", "stribeck/2", "coulomb+ripple/1"])]
    order = [j.candidate.name for j in sorted(jobs, key=expected_cost, reverse=True)]
    assert order == ["coulomb+ripple/1", "coulomb/3z", "stribeck/2", "lugre/1", "coulomb/1"]


@pytest.mark.parametrize("case", ["unknown candidate", "order 0", "validation of other signals",
                                  "validation on the fitted data"])
def test_bad_input_is_one_line_and_nothing_is_written(g1_records, tmp_path, case):
    validation, extra = g1_records["val"], []
    if case == "unknown candidate":
        extra, fragment = ["--candidates", "coulomb,sticky"], "unknown friction law 'sticky'"
    elif case == "order 0":
        extra, fragment = ["--orders", "0,1"], "order 0 of G(s)"
    elif case == "validation on the fitted data":
        validation, fragment = g1_records["fit"], "is one of the fitted data files"
    else:  # the position of an encoder where the fitted records measure the velocity
        validation, fragment = g1_records["position"], "holds records of position"
    proc = run("select", g1_records["fit"], "--validate", validation, *extra, "--workers", "0",
               "-o", tmp_path / "s.h5", "--report", tmp_path / "s.html")
    assert_one_line_error(proc, fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_json_of_a_selection_names_the_chosen_candidate(g1_records, tmp_path):
    proc = run("select", g1_records["fit"], "--validate", g1_records["val"], "--candidates", "coulomb/1,coulomb/2",
               "--iterations", "10", "--workers", "0", "--json", "-o", tmp_path / "s.h5")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["chosen"] == "coulomb/1" and [c["rank"] for c in out["candidates"]] == [1, 2]


def test_docs_selection_example_runs_on_stepped_sine_data(tmp_path):
    """docs/selection.md's console block, in order, in an empty folder: g1 measured at 40 dB at six frequencies
    per magnitude, a validation at other magnitudes and frequencies; coulomb/1 is chosen."""
    import shlex
    from pathlib import Path

    text = (Path(__file__).resolve().parent.parent / "docs" / "selection.md").read_text()
    block = text.split("```console", 1)[1].split("```", 1)[0]
    commands = [shlex.split(line[2:]) for line in block.strip().splitlines() if line.startswith("$ ")]
    assert [c[1] for c in commands] == ["build", "measure", "measure", "select"]
    for command in commands:
        proc = run(*command[1:], cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
    assert "chosen: coulomb/1" in proc.stdout
    chosen = sf.load_plant(tmp_path / "select.toml")
    assert chosen.friction.model == "coulomb" and chosen.order == 1
    assert abs(chosen.friction.fc_pos / 0.5 - 1) < 0.05 and abs(chosen.friction.fc_neg / 0.4 - 1) < 0.05
    assert (tmp_path / "select.html").is_file() and (tmp_path / "select-result.h5").is_file()


def test_a_round_of_fewer_fits_than_local_workers_gives_each_fit_the_idle_cores(monkeypatch):
    """Two local workers on two cores: one fit gets both cores' threads, two fits one each; a Dask cluster's or
    this process's fits keep theirs (a remote worker's cores are not this machine's)."""
    from servofmu.selection import fitting
    from servofmu.simulation.parallel import Workers

    monkeypatch.setattr(fitting, "available_cores", lambda: 2)
    per_job = fitting.threads_per_job
    assert [per_job(Workers(workers=2), n) for n in (1, 2, 5)] == [2, 1, 1]
    assert per_job(Workers(workers=8), 1) == 2  # no more threads than cores
    assert per_job(Workers(workers=0), 1) == 1
    assert per_job(Workers(scheduler="tcp://127.0.0.1:1", workers=2), 1) == 1
