"""The network on broadband data: the BLA's bands as the features (exact against scipy's zero-order-hold response on
a linear plant), one function of the records whether measured or simulated for the training set, and `dataset`,
`train` and `identify --ann` on a broadband file, with one-line refusals."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from scipy import signal

from servofmu.broadband import BroadbandPlan
from servofmu.broadband.simulate import write_simulated
from servofmu.broadband.store import read_broadband
from servofmu.errors import ServofmuWarning
from servofmu.identification.broadband_ann import BINS, band_edges, broadband_sine_data, simulate_chunk
from servofmu.identification.results import read_result
from servofmu.model.plant import load_plant
from servofmu.simulation.batch import BatchSimulator

PLAN = BroadbandPlan("multisine", (2.0, 0.8), (0.5, 20.0), 200.0, period=2.0, periods=2, transient_periods=1,
                     realisations=2, seed=3)


def test_the_bands_of_a_linear_plant_are_its_zero_order_hold_response_averaged_over_their_lines(tmp_path):
    g1 = load_plant("g1")
    plant = replace(g1, friction=replace(g1.friction, fc_pos=0.0, fc_neg=0.0))
    write_simulated(tmp_path / "bb.h5", plant, PLAN)
    sd = broadband_sine_data(read_broadband(tmp_path / "bb.h5"))
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss(*plant.transfer_function()), 1 / PLAN.rate, "zoh")
    f = PLAN.lines / PLAN.period
    z = np.exp(2j * np.pi * f / PLAN.rate)
    H = np.array([(c @ np.linalg.solve(zk * np.eye(a.shape[0]) - a, b) + d)[0, 0] for zk in z])
    edges = band_edges(f)
    bands = [k for k in range(BINS) if np.any((f >= edges[k]) & (f < edges[k + 1]))]  # an empty band left out
    assert edges.size == BINS + 1 and len(bands) >= BINS - 1
    assert sd.amplitudes.tolist() == [2.0] * len(bands) + [0.8] * len(bands)
    for i, k in enumerate(bands):
        inside = (f >= edges[k]) & (f < edges[k + 1])
        for level in range(2):
            j = level * len(bands) + i
            assert sd.frequencies[j] == pytest.approx(np.exp(np.mean(np.log(f[inside]))), rel=1e-12)
            assert abs(sd.H[j] - np.mean(H[inside])) < 1e-7 * abs(np.mean(H[inside]))
    assert np.all(np.abs(sd.dc) < 1e-6)  # no friction: no mean velocity


def test_the_training_set_simulates_the_features_the_measurement_gives(tmp_path):
    """g1 with its asymmetric friction, noise-free: the training set's features of the true plant are the data
    file's (one function of the records: the same bands of the same BLA), its mean velocity not zero."""
    plant = load_plant("g1")
    write_simulated(tmp_path / "bb.h5", plant, PLAN)
    measured = broadband_sine_data(read_broadband(tmp_path / "bb.h5"))
    H, dc, ok = simulate_chunk(BatchSimulator(plant), (plant.parameter_vector()[None], PLAN, 1e-10))
    assert ok.all() and np.max(np.abs(H[0] - measured.H) / np.abs(measured.H)) < 1e-8
    assert np.allclose(dc[0], measured.dc, rtol=1e-8, atol=1e-12) and np.all(np.abs(measured.dc) > 1e-4)


# long (SERVOFMU_FAULTS=all): 10-19 s of the default suite's 15 minutes; scripts/bench_broadband_ann.py measures the
# same on the default plan; the refusal without a network stays in tests/test_frequency_fit.py
@pytest.mark.long
def test_dataset_train_and_identify_with_the_network_on_a_broadband_file(tmp_path):
    """The paper's hybrid on broadband data: the network trained on the file's plan reads an estimate near the truth,
    the swarm and polish end with intervals that hold g1's truth; a network of another plan, and pso-ann without
    one, are refused in one line."""
    from servofmu.identification.run import identify_to_file
    from servofmu.identification.train import train_from_file
    from servofmu.identification.training_set import make_training_set, training_data

    data = tmp_path / "bb.h5"
    write_simulated(data, load_plant("g1"), PLAN, 40.0)
    ts = make_training_set(load_plant("g1"), training_data(data), 100, tmp_path / "ds.h5")
    assert ts.attributes["broadband_plan"] == PLAN.to_json() and ts.usable().all()
    train_from_file(tmp_path / "ds.h5", tmp_path / "net.h5")
    result = identify_to_file(data, "g1", tmp_path / "r.h5", tmp_path / "net.h5")
    assert read_result(tmp_path / "r.h5").method == "pso-ann" and result.stages[1].name == "ann"
    truth = load_plant("g1").parameters()
    ann = dict(zip(result.names, result.stages[1].theta))
    assert all(abs(ann[n] / truth[n] - 1) < 0.15 for n in result.names), ann  # the prior spans factors 1/1.5…1.5
    for name, (lo, hi) in zip(result.names, result.intervals):
        assert lo <= truth[name] <= hi, name
    other = tmp_path / "other.h5"
    write_simulated(other, load_plant("g1"), replace(PLAN, band=(0.5, 30.0)), 40.0)
    proc = run("identify", other, "--structure", "g1", "--ann", tmp_path / "net.h5", "-o", tmp_path / "o.h5")
    assert_one_line_error(proc, "net.h5 was trained on plan")
    proc = run("identify", data, "--structure", "g1", "--method", "pso-ann", "-o", tmp_path / "o.h5")
    assert_one_line_error(proc, "needs a network trained on this broadband plan")
    assert not (tmp_path / "o.h5").exists()


def test_identify_of_a_broadband_file_without_an_output_writes_nothing(tmp_path):
    from servofmu.identification.run import IdentifyOptions, identify_to_file

    write_simulated(tmp_path / "bb.h5", load_plant("g1"), PLAN, 40.0)
    with pytest.warns(ServofmuWarning, match="times the noise of the periods"):  # two iterations, no polish
        result = identify_to_file(tmp_path / "bb.h5", "g1", None, options=IdentifyOptions(method="pso", iterations=2,
                                                                                         polish=False))
    assert result.method == "pso" and result.provenance["data_kind"] == "broadband"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bb.h5"]
