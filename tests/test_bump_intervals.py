"""A Stribeck fit whose bump has collapsed (fs = fc: an axis with Coulomb friction only) still has intervals for
what the data determines.  The search's coordinate log(fs − fc) is −∞ there, so the parameters' Jacobian cannot
be taken through it: the identifier takes the columns it cannot by differences in the parameters themselves
(criterion.with_finite_columns), one-sided at the edge of fs ≥ fc."""
from __future__ import annotations

import tomllib

import numpy as np
import pytest

import servofmu as sf
from servofmu.identification.criterion import (JACOBIAN_RTOL, RecordCriterion, RecordData, RecordSeries,
                                               undetermined, with_finite_columns)
from servofmu.identification.features import target_jacobian, to_targets
from servofmu.identification.identifier import PSOANNIdentifier
from servofmu.identification.prior import identified_mask, identified_names
from servofmu.model.plant import plant_from_dict
from servofmu.simulation.batch import BatchSimulator

DT, DURATION = 0.01, 20.0


def stribeck_on_g1(fs_pos: float, fs_neg: float, vs: float = 0.05):
    """g1 (Coulomb friction 0.5/0.4 N) written as a Stribeck plant."""
    data = tomllib.loads(sf.load_plant("g1").to_toml())
    data["friction"].update(model="stribeck", fs_pos=fs_pos, fs_neg=fs_neg, vs=vs)
    return plant_from_dict(data)


@pytest.fixture(scope="module")
def g1_record():
    """A 20 s record of g1 at 100 Hz (two tones per half), white noise 40 dB below the velocity."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, DURATION, DT)
    u = np.where(t < DURATION / 2, 2 * np.sin(2 * np.pi * t) + 0.6 * np.sin(2 * np.pi * 3.1 * t),
                 0.7 * np.sin(2 * np.pi * 0.6 * t) + 0.3 * np.sin(2 * np.pi * 4.3 * t))
    g1 = sf.load_plant("g1")
    v = BatchSimulator(g1).simulate_record(g1.parameter_vector()[None], t, u, rtol=1e-10).v[0]
    v = v + 0.01 * np.std(v) * rng.standard_normal(v.size)
    return RecordData((RecordSeries("v", t, u, v, "v", "zoh", np.ones(t.size, bool)),), "records")


def test_a_collapsed_bump_has_no_search_coordinate_derivative_but_the_others_stay_finite():
    plant = stribeck_on_g1(0.5, 0.45)  # the bump gone on the positive side
    theta = plant.parameter_vector()[identified_mask(plant)]
    names = identified_names(plant)
    jac = target_jacobian(plant, to_targets(plant, theta[None])[0])
    row = names.index("fs_pos")
    bad = ~np.isfinite(jac)
    # log(fs+ − fc+) has no derivative in fs+ or fc+ (one side of each is no plant); every other entry is finite —
    # a step of another parameter leaves the target at −∞, a change of 0 (not ∞ − ∞)
    assert set(zip(*np.nonzero(bad))) == {(row, names.index("fs_pos")), (row, names.index("fc_pos"))}
    assert np.all(jac[row, ~bad[row]] == 0)


def test_columns_at_the_edge_of_fs_at_least_fc_are_one_sided_differences(g1_record):
    plant = stribeck_on_g1(0.5, 0.45)
    crit = RecordCriterion(plant, g1_record, BatchSimulator(plant))
    names = identified_names(plant)
    theta = plant.parameter_vector()[identified_mask(plant)]
    k, c = names.index("fs_pos"), names.index("fc_pos")
    jac = np.ones((crit.residuals(theta[None], JACOBIAN_RTOL).shape[1], theta.size))
    jac[:, [k, c]] = np.nan
    out = with_finite_columns(crit, theta, jac)
    assert np.all(np.isfinite(out))
    assert np.all(np.delete(out, [k, c], axis=1) == 1)  # finite columns untouched
    # the independent reference: central differences with a larger step, just inside the domain (fs+ above fc+
    # by more than the step, fc+ below fs+), where the residuals are as smooth as at the edge
    for col, side in ((k, 1.0), (c, -1.0)):
        h = 1e-4 * abs(theta[col])
        inside = theta.copy()
        inside[col] += side * 2 * h
        r = crit.residuals(np.array([inside + h * np.eye(theta.size)[col], inside - h * np.eye(theta.size)[col]]),
                           JACOBIAN_RTOL)
        reference = (r[0] - r[1]) / (2 * h)
        assert np.linalg.norm(out[:, col] - reference) < 2e-3 * np.linalg.norm(reference)


def test_a_level_without_effect_is_undetermined_not_exact():
    jac = np.array([[1.0, 0.0, 2e-12], [0.0, 1.0, 1e-12], [1.0, 1.0, 0.0]])
    theta = np.array([1.0, 1.0, 0.5])
    # a column that moves the residuals by 1e-12 of the others per its whole value: the pseudo-inverse would give
    # it a variance of 0 (known exactly) — it is undetermined; a parameter at 0 is not judged by its value
    assert list(undetermined(jac, theta=theta)) == [False, False, True]
    assert list(undetermined(jac)) == [False, False, False]
    assert list(undetermined(jac, theta=np.array([1.0, 1.0, 0.0]))) == [False, False, False]


def test_a_stribeck_fit_of_a_coulomb_axis_has_the_intervals_of_its_coulomb_fit(g1_record):
    stribeck = PSOANNIdentifier(stribeck_on_g1(0.75, 0.6), method="pso", seed=1, threads=2).fit(g1_record)
    names = list(stribeck.result({}).names)
    theta = dict(zip(names, stribeck.theta_))
    # the premise: the fit's bump has collapsed on one side (the search coordinate there is −∞)
    assert not np.all(np.isfinite(to_targets(stribeck.structure, stribeck.theta_[None])))
    assert min(theta["fs_pos"] - theta["fc_pos"], theta["fs_neg"] - theta["fc_neg"]) == 0
    coulomb = PSOANNIdentifier(sf.load_plant("g1"), method="pso", seed=0, threads=2).fit(g1_record)
    shared = list(coulomb.result({}).names)  # pole1, dc_gain, fc_pos, fc_neg
    half = (stribeck.intervals_[:, 1] - stribeck.intervals_[:, 0]) / 2
    own = dict(zip(shared, (coulomb.intervals_[:, 1] - coulomb.intervals_[:, 0]) / 2))
    truth = dict(zip(shared, sf.load_plant("g1").parameter_vector()[identified_mask(sf.load_plant("g1"))]))
    for name in shared:
        i = names.index(name)
        assert np.isfinite(half[i])
        assert stribeck.intervals_[i, 0] <= truth[name] <= stribeck.intervals_[i, 1], name
        # no narrower than the Coulomb fit's (a Stribeck law has more to explain the same data with)
        assert 0.9 * own[name] <= half[i] <= 10 * own[name], (name, half[i], own[name])
