"""Parameters the data does not separate (servofmu.identification.confounding), against references written here:

- a linear least-squares problem whose Jacobian sees only fc_pos − offset and fc_neg + offset, exactly (the
  pseudo-inverse's covariance) and nearly (a few samples tell them apart): the group is named, and the
  determined combinations are the ordinary least-squares estimates of a model written in those combinations;
- records of a plant with a constant load that never stops, fitted with the offset free: the group is named and
  its determined combinations match the true plant's to their own 95 % half-width;
- stepped sines of g1, which excite everything: no group;
- RESULT.h5 keeps the covariance, and a file without it reads as before.
"""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

import servofmu as sf
from servofmu.identification.confounding import confounded_groups, with_free_directions
from servofmu.identification.criterion import (RecordData, RecordSeries, SineData, covariance_from_jacobian,
                                               intervals_from_covariance)
from servofmu.identification.results import read_result, result_from_estimator, table_text, to_json, write_result
from servofmu.model.plant import load_plant, plant_from_dict
from servofmu.output.report import separation_html
from servofmu.output.report_entries import Entry
from servofmu.simulation.batch import BatchSimulator, SteadyStateOptions

NAMES = ["pole1", "fc_pos", "fc_neg", "offset"]
UNITS = {"pole1": "rad/s", "fc_pos": "N", "fc_neg": "N", "offset": "N"}
TRUTH = np.array([1.0, 0.5, 0.4, 0.15])


def linear_problem(separation: float, seed: int = 0):
    """y = X·θ + noise with the columns of pole1 (a regressor of its own), fc_pos (−1 while moving forward),
    fc_neg (+1 while moving back) and offset (+1 always); ``separation``: the offset's extra column at every
    50th sample (a standstill that sees it alone), 0 for none."""
    n = 400
    t = np.linspace(0.0, 1.0, n)
    forward = np.sin(2 * np.pi * 3 * t) > 0
    X = np.column_stack([np.sin(7 * t), -1.0 * forward, 1.0 * ~forward, np.ones(n)])
    X[::50, 3] += separation
    y = X @ TRUTH + 0.01 * np.random.default_rng(seed).standard_normal(n)
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = X @ theta - y
    cov, dof = covariance_from_jacobian(r, X)
    return X, y, theta, intervals_from_covariance(theta, cov, dof, X), with_free_directions(cov, X)


@pytest.mark.parametrize("separation", [0.0, 0.02])
def test_a_linear_problem_names_the_group_and_its_least_squares_combinations(separation):
    X, y, theta, intervals, cov = linear_problem(separation)
    (group,) = confounded_groups(NAMES, theta, cov, intervals, UNITS)
    assert set(group.names) == {"fc_pos", "fc_neg", "offset"} and abs(group.correlation) > 0.99
    (free,) = group.free
    assert free.coefficients[0][0] == "offset"  # the last of the group carries the free direction
    assert dict(free.coefficients)["fc_pos"] == pytest.approx(1.0, abs=1e-3)
    assert dict(free.coefficients)["fc_neg"] == pytest.approx(-1.0, abs=1e-3)
    combos = {c.coefficients[0][0]: c for c in group.determined}
    assert dict(combos["fc_pos"].coefficients)["offset"] == pytest.approx(-1.0, abs=1e-3)
    assert dict(combos["fc_neg"].coefficients)["offset"] == pytest.approx(1.0, abs=1e-3)
    # the reference: least squares, by lstsq without the package, on the model rewritten in a = fc_pos + k1·offset,
    # b = fc_neg + k2·offset (the printed combinations) and the offset alone, whose column is what the separation adds
    k1, k2 = dict(combos["fc_pos"].coefficients)["offset"], dict(combos["fc_neg"].coefficients)["offset"]
    Z = np.column_stack([X[:, 0], X[:, 1], X[:, 2], X[:, 3] - k1 * X[:, 1] - k2 * X[:, 2]])
    ref, *_ = np.linalg.lstsq(Z, y, rcond=None)
    assert combos["fc_pos"].value == pytest.approx(ref[1], abs=1e-9)
    assert combos["fc_neg"].value == pytest.approx(ref[2], abs=1e-9)
    # their standard errors, s·√((ZᵀZ)⁻¹) on the a, b block (without the offset's column when it is not seen)
    s2 = float(np.sum((Z @ ref - y) ** 2)) / (len(y) - 4)
    zz = np.linalg.pinv(Z[:, :3].T @ Z[:, :3]) if separation == 0 else np.linalg.inv(Z.T @ Z)
    se = np.sqrt(s2 * np.diag(zz)[1:3])
    assert combos["fc_pos"].half_width / se[0] == pytest.approx(1.97, rel=0.02)  # t(0.975, 396 or 397)
    assert combos["fc_neg"].half_width / se[1] == pytest.approx(1.97, rel=0.02)
    # the data's precision: the truth's combinations lie within a few standard errors
    assert abs(combos["fc_pos"].value - (TRUTH[1] - TRUTH[3])) < 4 * se[0]
    assert abs(combos["fc_neg"].value - (TRUTH[2] + TRUTH[3])) < 4 * se[1]
    assert "not separated by the data: fc_pos, fc_neg, offset" in group.line()


def test_a_well_separated_problem_names_no_group():
    X, y, theta, intervals, cov = linear_problem(separation=3.0)
    assert confounded_groups(NAMES, theta, cov, intervals, UNITS) == []


def test_three_parameters_whose_sum_alone_is_seen_form_one_group_though_no_pair_correlates():
    """a + b + c seen, each pair of estimates correlated only about −0.5: the pairs' rule would miss it."""
    rng = np.random.default_rng(1)
    x = rng.standard_normal(300)
    X = np.column_stack([x + 1e-3 * rng.standard_normal(300) for _ in range(3)] + [rng.standard_normal(300)])
    theta = np.array([1.0, 2.0, 3.0, 4.0])
    cov, dof = covariance_from_jacobian(0.01 * rng.standard_normal(300), X)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.abs(corr[:3, :3][~np.eye(3, dtype=bool)]).max() < 0.9
    (group,) = confounded_groups(["a", "b", "c", "d"], theta, cov, intervals_from_covariance(theta, cov, dof, X))
    assert group.names == ("a", "b", "c") and len(group.free) == 2 and len(group.determined) == 1
    (combo,) = group.determined
    coef = dict(combo.coefficients)
    assert coef["b"] == pytest.approx(coef["a"], rel=1e-2) and coef["c"] == pytest.approx(coef["a"], rel=1e-2)


def unstopping_fit(friction=(0.5, 0.4), symmetric=False, fixed=()):
    """Velocity records (1 % noise) of G = 10/(s + 10) with Coulomb friction ``friction`` (fc_pos, fc_neg) and a
    constant load 0.15 N, driven so that it never stops (it reverses through zero without sticking): only
    fc_pos − offset and fc_neg + offset act.  Fitted from a structure 1.2 × the truth (the offset 0 unless
    ``fixed``; the friction ``symmetric`` or not)."""
    def axis(values, symmetric=False, fixed=()):
        return plant_from_dict({"name": "t", "fixed": list(fixed),
                                "linear": {"poles": [[values["pole1"], 0.0]], "dc_gain": values["dc_gain"]},
                                "friction": {"model": "coulomb", "symmetric": symmetric, "fc_pos": values["fc_pos"],
                                             "fc_neg": values["fc_neg"]}, "load": {"offset": values["offset"]}})

    truth = axis({"pole1": -10.0, "dc_gain": 1.0, "fc_pos": friction[0], "fc_neg": friction[1], "offset": 0.15})
    t = np.arange(0.0, 6.0 + 0.005, 0.01)
    u = 2.0 * np.sin(2 * np.pi * 0.5 * t) + 0.8 * np.sin(2 * np.pi * 1.7 * t)
    v = BatchSimulator(truth).simulate_record(truth.parameter_vector()[None], t, u).v[0]
    assert np.abs(v[t >= 0.5]).min() > 1e-5 and np.sum(np.diff(np.sign(v[t >= 0.5])) != 0) >= 4
    y = v + 0.01 * np.std(v) * np.random.default_rng(0).standard_normal(v.size)
    data = RecordData((RecordSeries("v", t, u, y, "v", "zoh", t >= 0.5),), "records")
    start = {n: x if n in fixed else 0.0 if n == "offset" else 1.2 * x for n, x in truth.parameters().items()}
    start["fc_neg"] = start["fc_pos"] if symmetric else start["fc_neg"]
    structure = axis(start, symmetric, fixed)
    est = sf.PSOANNIdentifier(structure, method="pso", seed=1).fit(data)
    return result_from_estimator(est, "pso", {})


def test_a_load_that_never_stops_is_named_with_the_combinations_the_records_determine(tmp_path):
    result = unstopping_fit()
    (group,) = result.confounded()
    assert set(group.names) == {"fc_pos", "fc_neg", "offset"} and group.correlation < -0.99
    combos = {c.coefficients[0][0]: c for c in group.determined}
    assert abs(combos["fc_pos"].value - (0.5 - 0.15)) < combos["fc_pos"].half_width
    assert abs(combos["fc_neg"].value - (0.4 + 0.15)) < combos["fc_neg"].half_width
    widths = dict(zip(result.names, result.intervals[:, 1] - result.intervals[:, 0]))
    assert combos["fc_pos"].half_width < widths["fc_pos"] / 50  # each alone is known far worse
    text = table_text(result)
    assert "not separated by the data: fc_pos, fc_neg, offset" in text and "fc_pos − 1.00·offset = 0.35" in text
    doc = to_json(result)
    assert doc["not_separated"][0]["names"] == list(group.names)
    assert np.allclose(doc["covariance"], result.covariance)
    # RESULT.h5 keeps the covariance; a file without it (older, or edited) reads as before, with no groups
    path = write_result(tmp_path / "r.h5", result)
    back = read_result(path)
    np.testing.assert_array_equal(back.covariance, result.covariance)
    assert [g.line() for g in back.confounded()] == [group.line()]
    with h5py.File(path, "r+") as f:
        del f["covariance"]
        del f.attrs["content_sha256"]
    old = read_result(path)
    assert old.covariance is None and old.confounded() == [] and "not_separated" not in to_json(old)
    json.dumps(to_json(back))
    # the report's paragraph (servofmu report) says the same
    (html,) = separation_html([Entry("pso", back)])
    assert "Not separated by the data" in html and "fc_pos − 1.00·offset = 0.35" in html
    assert separation_html([Entry("pso", old)]) == []


@pytest.mark.parametrize("keys", [{"symmetric": True}, {"fixed": ("offset",)}])
def test_a_structure_that_says_more_separates_the_offset(keys):
    """The same records of an axis whose friction is the same both ways (0.45 N): fitted with a symmetric friction,
    or with the offset held at its known value, nothing is confounded and every estimate is as close to the truth as
    the combinations were; the asymmetric structure with a free offset names the group."""
    loose = unstopping_fit((0.45, 0.45))
    assert {"fc_pos", "fc_neg", "offset"} <= set(loose.confounded()[0].names)
    result = unstopping_fit((0.45, 0.45), **keys)
    assert result.confounded() == []
    truth = {"pole1": -10.0, "dc_gain": 1.0, "fc_pos": 0.45, "fc_neg": 0.45, "offset": 0.15}
    expected = [n for n in truth if not (n == "fc_neg" and "symmetric" in keys) and n not in keys.get("fixed", ())]
    assert list(result.names) == expected
    t = np.array([truth[n] for n in expected])
    assert np.all((result.intervals[:, 0] <= t) & (t <= result.intervals[:, 1])), (result.theta, result.intervals)
    widths = dict(zip(result.names, result.intervals[:, 1] - result.intervals[:, 0]))
    loose_widths = dict(zip(loose.names, loose.intervals[:, 1] - loose.intervals[:, 0]))
    assert widths["fc_pos"] < loose_widths["fc_pos"] / 50
    fitted = result.plant.parameters()
    assert fitted["fc_neg"] == fitted["fc_pos"] if "symmetric" in keys else fitted["offset"] == 0.15


def test_stepped_sines_of_g1_name_no_group():
    truth = load_plant("g1")
    amps, freqs = np.repeat([2.0, 0.6], 3), np.tile([0.5, 2.0, 10.0], 2)
    f = BatchSimulator(truth).steady_state(truth.parameter_vector()[None], amps, freqs, SteadyStateOptions(rtol=1e-9))
    rng = np.random.default_rng(2)
    H = f.H[0] * (1 + 0.005 * (rng.standard_normal(6) + 1j * rng.standard_normal(6)))
    dc = f.dc[0] + 0.005 * np.abs(f.H[0]) * amps * rng.standard_normal(6)
    data = SineData(amps, freqs, H, dc, True, "sines", 0, noise=np.full(6, 0.005))
    start = truth.with_parameters([1.2 * x if n != "v_smooth" else x for n, x in truth.parameters().items()])
    est = sf.PSOANNIdentifier(start, method="pso", seed=1).fit(data)
    result = result_from_estimator(est, "pso", {})
    assert result.covariance is not None and np.all(np.isfinite(result.intervals))
    assert result.confounded() == [] and "not separated" not in table_text(result)
