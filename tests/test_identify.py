"""The identifier end to end on FMU data: dataset → train → identify, and its refusals of bad input."""
import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from clitools import assert_one_line_error, run

from servofmu.identification.ann import AnnModel, load_network
from servofmu.identification.criterion import sine_data
from servofmu.identification.features import from_targets, to_targets
from servofmu.identification.identifier import PSOANNIdentifier, polish
from servofmu.identification.prior import full_vectors, identified_mask, sample_identified
from servofmu.identification.train import train_from_file
from servofmu.identification.training_set import make_training_set
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.measure import MeasureOptions, measure
from servofmu.model.plant import load_plant
from servofmu.runtime import RunOptions
from hdf5edit import edit_hdf5

PLAN = {"amplitudes": [2.0, 0.6], "frequencies": [0.5, 2.0, 10.0]}


@pytest.fixture(scope="module")
def g1_files(tmp_path_factory, built_fmu):
    """g1 measured through its FMU, a small training set under that plan and a network trained on it."""
    folder = tmp_path_factory.mktemp("identify")
    data = folder / "g1.h5"
    measure(built_fmu("g1", 3), data, options=MeasureOptions(), run=RunOptions(workers=0), **PLAN)
    ds = folder / "ds.h5"
    make_training_set(load_plant("g1"), sine_data(read_data_file(data)), 400, ds, seed=3)
    ann = folder / "ann.h5"
    train_from_file(ds, ann, seed=0)
    return {"data": data, "ds": ds, "ann": ann, "folder": folder}


def truth(name):
    plant = load_plant(name)
    return plant.parameter_vector()[identified_mask(plant)]


def test_targets_round_trip():
    for name in ("g1", "g2", "stribeck_servo", "lugre_servo"):
        plant = load_plant(name)
        theta = sample_identified(plant, 50, 0.5, np.random.default_rng(0))
        assert np.allclose(from_targets(plant, to_targets(plant, theta)), theta, rtol=1e-12)


def test_pso_ann_identifies_g1_from_fmu_data(g1_files):
    net, layout = load_network(g1_files["ann"])
    data = sine_data(read_data_file(g1_files["data"]))
    est = PSOANNIdentifier(load_plant("g1"), ann=AnnModel(net, layout, "ann.h5"), seed=0).fit(data)
    assert [s.name for s in est.stages_] == ["ann", "pso", "polish"]
    assert np.max(np.abs(est.theta_ / truth("g1") - 1)) < 1e-6
    # each stage improves on the one before
    fitness = [s.fitness for s in est.stages_]
    assert fitness[2] < fitness[1] <= fitness[0] and fitness[2] < 1e-8
    # the intervals contain the truth and are narrow
    lo, hi = est.intervals_.T
    assert np.all((lo <= truth("g1") + 1e-9) & (truth("g1") - 1e-9 <= hi))


@pytest.mark.parametrize("method, search", [("ga-ann", "ga"), ("aga-ann", "aga")])
def test_ga_comparators_share_the_budget(g1_files, method, search):
    net, layout = load_network(g1_files["ann"])
    data = sine_data(read_data_file(g1_files["data"]))
    est = PSOANNIdentifier(load_plant("g1"), ann=AnnModel(net, layout, "ann.h5"), method=method, seed=0).fit(data)
    assert [s.name for s in est.stages_] == ["ann", search, "polish"]
    assert est.stages_[1].evaluations == 510  # PSO-ANN's 10 particles x (50 + 1)
    assert np.max(np.abs(est.theta_ / truth("g1") - 1)) < 1e-6


def test_search_tolerance_sets_the_floor_of_the_swarm_not_of_the_result(g1_files):
    """On noise-free data the swarm's best cost can only fall to about its simulations' error: at search_rtol 1e-4
    it stops an order of magnitude above where it stops at the default 1e-5; the polish (1e-10) still finds the
    truth."""
    net, layout = load_network(g1_files["ann"])
    data = sine_data(read_data_file(g1_files["data"]))
    fits = {rtol: PSOANNIdentifier(load_plant("g1"), ann=AnnModel(net, layout, "ann.h5"), search_rtol=rtol).fit(data)
            for rtol in (1e-5, 1e-4)}
    assert fits[1e-4].stages_[1].fitness > 3 * fits[1e-5].stages_[1].fitness
    for est in fits.values():
        assert np.max(np.abs(est.theta_ / truth("g1") - 1)) < 1e-6


def test_pso_alone_from_the_prior_box(g1_files):
    data = sine_data(read_data_file(g1_files["data"]))
    est = PSOANNIdentifier(load_plant("g1"), method="pso", seed=1).fit(data)
    assert [s.name for s in est.stages_] == ["pso", "polish"]
    assert np.max(np.abs(est.theta_ / truth("g1") - 1)) < 1e-6


def test_identify_cli_json(g1_files):
    out = g1_files["folder"] / "result.h5"
    proc = run("identify", g1_files["data"], "--structure", "g1", "--ann", g1_files["ann"], "--json", "-o", out)
    assert proc.returncode == 0, proc.stderr
    obj = json.loads(proc.stdout)  # exactly one JSON object on stdout
    assert obj["method"] == "pso-ann"
    assert np.allclose(obj["parameters"]["poles"], [[-10.0, 0.0]], rtol=1e-6)
    assert np.isclose(obj["parameters"]["gain"], 10.0, rtol=1e-6)
    assert np.isclose(obj["parameters"]["friction"]["fc_neg"], 0.4, rtol=1e-6)
    assert set(obj["intervals"]) == {"pole1", "dc_gain", "fc_pos", "fc_neg"}
    assert obj["fitness"] < 1e-8 and obj["seconds"] > 0
    with h5py.File(out) as f:
        assert f.attrs["format"] == "servofmu-result"


def test_identify_cli_with_a_shorter_swarm(g1_files, tmp_path):
    """--iterations: the swarm runs that many iterations (0: the first particles, then the polish), the result
    says so, and the answer is still the truth; a negative count is one line naming the option."""
    from servofmu.identification.results import read_result

    out = tmp_path / "short.h5"
    proc = run("identify", g1_files["data"], "--structure", "g1", "--ann", g1_files["ann"], "--iterations", "0",
               "--seed", "2", "--json", "-o", out)
    assert proc.returncode == 0, proc.stderr
    stages = {s["stage"]: s for s in json.loads(proc.stdout)["stages"]}
    assert stages["pso"]["evaluations"] == 10  # the ten first particles only
    result = read_result(out)
    assert (result.provenance["iterations"], result.provenance["seed"], result.provenance["polish"]) == (0, 2, True)
    assert np.max(np.abs(result.theta / truth("g1") - 1)) < 1e-6
    assert_one_line_error(run("identify", g1_files["data"], "--structure", "g1", "--ann", g1_files["ann"],
                              "--iterations", "-1", "-o", tmp_path / "bad.h5"), "--iterations")
    assert not (tmp_path / "bad.h5").exists()


def test_refuses_plan_that_does_not_match_the_ann(g1_files, built_fmu, tmp_path):
    other = tmp_path / "other.h5"
    measure(built_fmu("g1", 3), other, amplitudes=[2.0, 0.6], frequencies=[1.0, 3.0], run=RunOptions(workers=0))
    out = tmp_path / "r.h5"
    proc = run("identify", other, "--structure", "g1", "--ann", g1_files["ann"], "-o", out)
    assert_one_line_error(proc, "trained on plan")
    assert not out.exists()


def test_refuses_structure_that_does_not_match_the_data(g1_files, tmp_path):
    out = tmp_path / "r.h5"
    proc = run("identify", g1_files["data"], "--structure", "g2", "--method", "pso", "-o", out)
    assert_one_line_error(proc, "does not match")
    assert not out.exists()


def spoil_nan(f):
    next(g for g in f["experiments"].values()).attrs["H"] = complex(np.nan, 0.0)


def spoil_empty(f):
    for name in list(f["experiments"]):
        del f["experiments"][name]


@pytest.mark.parametrize("spoil, message", [(spoil_nan, "NaN"), (spoil_empty, "no experiments")])
def test_refuses_nan_or_empty_data(g1_files, tmp_path, spoil, message):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(g1_files["data"].read_bytes())
    edit_hdf5(bad, spoil)
    out = tmp_path / "r.h5"
    assert_one_line_error(run("identify", bad, "--structure", "g1", "--method", "pso", "-o", out), message)
    assert not out.exists()


def test_pso_ann_without_network_says_so(g1_files, tmp_path):
    proc = run("identify", g1_files["data"], "--structure", "g1", "--method", "pso-ann", "-o", tmp_path / "r.h5")
    assert_one_line_error(proc, "needs a trained network")


def test_train_refuses_a_file_that_is_not_a_training_set(g1_files, tmp_path):
    proc = run("train", g1_files["data"], "-o", tmp_path / "ann.h5")
    assert_one_line_error(proc, "not a servofmu training set")
    assert not (tmp_path / "ann.h5").exists()


def test_a_missing_network_file_is_named(tmp_path, g1_files):
    assert_one_line_error(run("identify", g1_files["data"], "--structure", "g1", "--ann", tmp_path / "x.h5",
                              "-o", tmp_path / "r2.h5"), "x.h5")


class _LinearCriterion:
    """Residuals A·θ − b, with no steady state (NaN) where θ[0] > edge: a stand-in for the batch simulator."""

    def __init__(self, a, b, edge):
        self.a, self.b, self.edge, self.evaluations = a, b, edge, 0

    def residuals(self, theta, rtol):
        theta = np.atleast_2d(theta)
        r = theta @ self.a.T - self.b
        r[theta[:, 0] > self.edge] = np.nan
        return r


def test_polish_steps_back_where_a_forward_step_has_no_steady_state():
    rng = np.random.default_rng(3)
    a, truth = rng.standard_normal((9, 3)), np.array([1.0, -2.0, 0.5])
    b = a @ truth + 1e-3 * rng.standard_normal(9)
    # the least-squares optimum sits just below the edge: forward steps in θ[0] from there have no steady state
    best = np.linalg.lstsq(a, b, rcond=None)[0]
    crit = _LinearCriterion(a, b, edge=best[0] * (1 + 1e-7))
    y, jac = polish(crit, lambda y: np.atleast_2d(y), best + [-0.05, 0.03, 0.02])
    np.testing.assert_allclose(y, best, rtol=1e-8)
    np.testing.assert_allclose(jac, a, rtol=1e-6)


def test_polish_tolerance_does_not_give_up_on_a_slowly_settling_experiment():
    # a g2-like plant near the swarm's best for it: at 2 N, 4 Hz its response settles slowly, and giving up early
    # (right for the search) called it unsettled, which stalled the polish
    from servofmu.identification.criterion import POLISH_RTOL, SineCriterion, SineData, steady_state_options
    from servofmu.simulation.batch import BatchSimulator, SteadyStateOptions

    plant = load_plant("g2")
    theta = np.array([-2.13696222, 38.87697534, -11.04557933, 1.39954763, 0.6566386, 0.46513884])
    sim = BatchSimulator(plant)
    amps, freqs = np.array([2.0]), np.array([4.0])
    hasty = sim.steady_state(full_vectors(plant, theta), amps, freqs,  # (Newton's method settles it sooner)
                             SteadyStateOptions(rtol=POLISH_RTOL, tol=1e-10, accelerate=False, give_up_early=True))
    plain = sim.steady_state(full_vectors(plant, theta), amps, freqs,
                             SteadyStateOptions(rtol=1e-11, tol=1e-10, accelerate=False, give_up_early=False))
    assert not hasty.converged[0, 0] and plain.converged[0, 0]  # the case this guards against
    assert not steady_state_options(POLISH_RTOL).give_up_early
    data = SineData(amplitudes=amps, frequencies=freqs, H=plain.H[0], dc=plain.dc[0], noisy=False, source="test",
                    skipped=0)
    r = SineCriterion(plant, data, sim).residuals(theta, POLISH_RTOL)
    assert np.all(np.isfinite(r)) and np.max(np.abs(r)) < 1e-8


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 7, 30, 31, 999, 1001, 123456])
def test_student_t_quantile_matches_scipy(dof):
    from scipy.stats import t

    from servofmu.identification.student_t import t_quantile

    for level in (0.5, 0.9, 0.95, 0.99, 0.999):
        assert t_quantile(level, dof) == pytest.approx(t.ppf(0.5 + level / 2, dof), rel=1e-12)


def test_identify_loads_neither_torch_nor_scipy_nor_casadi(g1_files, tmp_path):
    """The network's inference is numpy; the intervals need no scipy; the compiled simulator comes from the cache
    (the fixture's training set put it there), so nothing generates code."""
    code = ("import json, sys; from servofmu.cli import main; "
            f"rc = main(['identify', {str(g1_files['data'])!r}, '--structure', 'g1', '--ann', "
            f"{str(g1_files['ann'])!r}, '--json', '-o', {str(tmp_path / 'r.h5')!r}]); "
            "print(json.dumps([rc, sorted({m.split('.')[0] for m in sys.modules} & "
            "{'torch', 'scipy', 'casadi', 'dask', 'distributed', 'matplotlib', 'fmpy'})]), file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert json.loads(proc.stderr.strip().splitlines()[-1]) == [0, []], proc.stderr


# ---------------------------------------------------------------------------
# Many data files at once (a fleet of axes)
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fleet(g1_files, built_fmu):
    """Three g1 axes: the fixture's measurement and two noisy remeasurements."""
    folder = g1_files["folder"] / "fleet"
    folder.mkdir()
    files = [folder / "axis0.h5"]
    files[0].write_bytes(g1_files["data"].read_bytes())
    for seed in (1, 2):
        files.append(folder / f"axis{seed}.h5")
        measure(built_fmu("g1", 3), files[-1], options=MeasureOptions(noise_snr_db=40.0, seed=seed),
                run=RunOptions(workers=0),
                **PLAN)
    return files


def test_many_files_give_the_one_file_results_on_processes_and_on_a_dask_cluster(g1_files, fleet, tmp_path):
    from distributed import LocalCluster

    from servofmu.identification.fleet import identify_files
    from servofmu.identification.results import parameters_json, read_result

    ann = g1_files["ann"]
    one = {}
    for f in fleet:  # the single-file command, one after the other
        proc = run("identify", f, "--structure", "g1", "--ann", ann, "--json", "-o", tmp_path / f"{f.stem}.h5")
        one[str(f)] = json.loads(proc.stdout)["parameters"]
    runs = {}
    for label in ("local", "dask"):
        out = tmp_path / label
        out.mkdir()
        if label == "local":
            runs[label] = identify_files(fleet, "g1", out, ann_file=ann, run=RunOptions(workers=2))
        else:
            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None, worker_dashboard_address=None) as cluster:
                runs[label] = identify_files(fleet, "g1", out, ann_file=ann,
                                             run=RunOptions(scheduler=cluster.scheduler_address))
    for label, outcomes in runs.items():
        assert [o.status for o in outcomes] == ["identified"] * 3, label
        for o in outcomes:
            assert parameters_json(read_result(o.result_file).plant) == one[o.data_file], (label, o.data_file)


def test_an_interrupted_many_files_run_resumes_with_only_the_unfinished_files(g1_files, fleet, tmp_path):
    import signal
    import time

    inputs = tmp_path / "in"
    inputs.mkdir()
    files = list(fleet)
    for i, f in enumerate(fleet):  # three files more, so that the signal finds the run with work left
        files.append(inputs / f"copy{i}.h5")
        files[-1].write_bytes(f.read_bytes())
    args = [*map(str, files), "--structure", "g1", "--ann", str(g1_files["ann"]), "--output-dir", str(tmp_path),
            "--workers", "0"]
    for _ in range(3):  # again when the run finished every file before the signal reached it (a busy machine)
        for p in tmp_path.glob("*-result.h5"):
            p.unlink()
        proc = subprocess.Popen([sys.executable, "-m", "servofmu", "identify", *args], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True,  # Ctrl-C as in a terminal, also under nohup
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("*-result.h5")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        finished = {p.name: p.read_bytes() for p in tmp_path.glob("*-result.h5")}
        if not (proc.returncode == 0 and len(finished) == len(files)):
            break
    assert proc.returncode == 130 and "interrupted" in err, err
    assert 1 <= len(finished) < len(files) and not list(tmp_path.glob(".*part"))

    again = run("identify", *args, "--resume", "--json")
    assert again.returncode == 0, again.stderr
    status = {Path(o["result_file"]).name: o["status"] for o in json.loads(again.stdout)}
    assert {n for n, s in status.items() if s == "kept"} == set(finished)
    assert {n for n, s in status.items() if s == "identified"} == {f"{f.stem}-result.h5" for f in files} - set(finished)
    assert all((tmp_path / n).read_bytes() == b for n, b in finished.items())  # kept as they were


def test_many_files_refusals_and_a_failing_file(g1_files, fleet, tmp_path):
    ann = g1_files["ann"]
    assert_one_line_error(run("identify", *fleet, "--structure", "g1", "--ann", ann, "-o", tmp_path / "r.h5"),
                          "--output-dir")
    assert_one_line_error(run("identify", fleet[0], "--structure", "g1", "--ann", ann, "--resume", "-o",
                              tmp_path / "r.h5"), "--output-dir")
    assert_one_line_error(run("identify", *fleet, "--structure", "g1", "--ann", ann, "--output-dir",
                              tmp_path / "missing"), "no such folder")
    broken = tmp_path / "broken.h5"
    broken.write_bytes(b"not HDF5")
    proc = run("identify", fleet[0], broken, "--structure", "g1", "--ann", ann, "--output-dir", tmp_path,
               "--workers", "0", "--json")
    assert_one_line_error(proc, "1 of 2 data files not identified", str(broken))
    assert [o["status"] for o in json.loads(proc.stdout)] == ["identified", "failed"]
    assert (tmp_path / "axis0-result.h5").exists() and not (tmp_path / "broken-result.h5").exists()
    # the finished result is not overwritten without --resume, nor kept for other settings with it
    again = run("identify", fleet[0], "--structure", "g1", "--ann", ann, "--output-dir", tmp_path)
    assert_one_line_error(again, "axis0-result.h5", "exists already")
    other = run("identify", fleet[0], "--structure", "g1", "--ann", ann, "--seed", "7", "--output-dir", tmp_path,
                "--resume")
    assert_one_line_error(other, "axis0-result.h5", "other settings")
    shorter = run("identify", fleet[0], "--structure", "g1", "--ann", ann, "--iterations", "5", "--output-dir",
                  tmp_path, "--resume")
    assert_one_line_error(shorter, "axis0-result.h5", "other settings")
