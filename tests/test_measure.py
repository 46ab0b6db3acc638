"""Stepped-sine measurement of FMUs (servofmu.measurement.measure) against independent references:
a Radau integration of the plant equations, the linear G(jw), the describing function of Coulomb friction,
and the same measurement run elsewhere (FMI 2 vs 3, input port vs built-in excitation, Dask vs local)."""
from __future__ import annotations

import math
import os
import re
import zipfile

import numpy as np
import pytest
from reference import simulate_reference
from scipy.optimize import fsolve

from servofmu.errors import UserError
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.excitation import ExperimentSpec, default_frequencies
from servofmu.measurement.excitation import estimate_bandwidth
from servofmu.measurement.measure import Job, MeasureOptions, measure, run_experiment
from servofmu.model.plant import load_plant
from servofmu.simulation.fmu_runner import FmuRunnerFactory
from servofmu.simulation.parallel import WorkerResource, Workers
from servofmu.runtime import RunOptions

FC_POS, FC_NEG = 0.5, 0.4  # g1 and g2 (fmu_models/*.toml)


@pytest.fixture(scope="module")
def runner(built_fmu):
    """runner(name, version=3, input="u", output="v"): an FmuRunner of the plant's FMU, made once."""
    cache = {}

    def get(name, version=3, path=None, input="u", output="v"):
        path = path or built_fmu(name, version)
        key = (str(path), input, output)
        if key not in cache:
            cache[key] = FmuRunnerFactory(path.read_bytes(), path.name, input, output)()
        return cache[key]

    yield get
    for r in cache.values():
        r.close()


def run(runner_, m, f, **options):
    return run_experiment(runner_, Job(ExperimentSpec(0, m, f), MeasureOptions(**options)))


def G(name, f):
    return load_plant(name).frequency_response([2 * np.pi * f])[0]


# ---------------------------------------------------------------------------
# Accuracy against an independent integration
# ---------------------------------------------------------------------------
def test_first_harmonic_in_stick_slip_matches_a_radau_reference(runner):
    """g1 at m = 0.6 (< 4·Fc: sticking every half period) — the hard case for accuracy."""
    m, f = 0.6, 5.0
    res = run(runner("g1"), m, f)
    assert res.converged and res.last_change < 1e-10 and res.excitation == "builtin"
    t = res.window.time
    v_ref = simulate_reference([-10.0], [], 10.0, {"model": "coulomb", "fc_pos": FC_POS, "fc_neg": FC_NEG}, m, f,
                               np.concatenate([[0.0], t]), rtol=1e-11, atol=1e-13)[1:]
    # first harmonic by the trapezoid rule, written out independently of servofmu.measurement.frf
    w = np.gradient(t) * 0 + (t[1] - t[0])
    w[0] = w[-1] = (t[1] - t[0]) / 2
    s1_ref = 1j * 2 / (t[-1] - t[0]) * np.sum(w * v_ref * np.exp(-2j * np.pi * f * t))
    assert abs(res.H - s1_ref / m) < 1e-8 * abs(s1_ref / m)
    assert np.max(np.abs(res.window.v - v_ref)) < 1e-9
    assert res.U1 == m and res.hold_error == 0.0
    defaults = MeasureOptions()
    assert res.window_periods == defaults.window_periods and t[0] == res.window_start
    assert len(t) == defaults.window_periods * defaults.samples_per_period + 1


def test_fmi2_and_fmi3_fmus_give_the_same_first_harmonic(runner):
    a, b = run(runner("g1", 3), 2.0, 2.0), run(runner("g1", 2), 2.0, 2.0)
    assert abs(a.H - b.H) < 1e-12 * abs(a.H) and a.settling_time == b.settling_time


# ---------------------------------------------------------------------------
# Physics: large amplitude -> G(jw); the paper's magnitudes -> describing function
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["g1", "g2"])
def test_first_harmonic_approaches_G_at_large_amplitude(runner, name):
    for f in (1.0, 5.0):
        g = G(name, f)
        err = {m: abs(run(runner(name), m, f).H - g) / abs(g) for m in (50.0, 500.0)}
        assert err[500.0] < 2e-3
        # the friction's share falls as 1/m (describing function 4F/(pi A) with A ~ |G| m)
        assert 8 < err[50.0] / err[500.0] < 12


def describing_function_response(g: complex, g0: float, m: float) -> tuple[complex, float]:
    """Harmonic balance of G with asymmetric Coulomb friction under u = m sin(wt): the dual-input describing
    function with velocity v = B + A sin(.): sinusoid gain (4F/(pi A))·sqrt(1 - B²/A²), DC term
    Fd + (2F/pi)·asin(B/A), F = (Fc+ + Fc-)/2, Fd = (Fc+ - Fc-)/2.  Returns (H = V1/m, B)."""
    fbar, fd = (FC_POS + FC_NEG) / 2, (FC_POS - FC_NEG) / 2

    def gain(a, b):
        return 4 * fbar / (math.pi * a) * math.sqrt(max(0.0, 1 - (b / a) ** 2))

    def equations(x):
        a, b = x
        v1 = g * m / (1 + g * gain(a, b))
        return [abs(v1) - a, b + g0 * (fd + 2 * fbar / math.pi * math.asin(max(-1.0, min(1.0, b / a))))]

    (a, b), info, ok, msg = fsolve(equations, [abs(g) * m, 0.0], xtol=1e-13, full_output=True)
    assert ok == 1, msg
    return g / (1 + g * gain(a, b)), b


@pytest.mark.parametrize("name, frequencies", [("g1", (0.5, 2.0, 10.0)), ("g2", (1.0, 2.0, 5.0))])
def test_first_harmonic_matches_the_describing_function(runner, name, frequencies):
    """At m = 2.0 (the paper's m1 = 4·Fc+) the describing function is within 5 % — the response there still
    has 4-20 % harmonic distortion, which the describing function neglects; at m = 4.0 (8·Fc+) within 2 %."""
    for f in frequencies:
        g = G(name, f)
        errors = {}
        for m, tolerance in ((2.0, 0.05), (4.0, 0.02)):
            res = run(runner(name), m, f)
            h_df, bias = describing_function_response(g, 1.0, m)
            assert res.converged, (name, m, f)
            errors[m] = abs(res.H - h_df) / abs(h_df)
            assert errors[m] < tolerance, (name, m, f, errors[m])
            assert abs(res.dc - bias) < 0.1 * abs(bias), (name, m, f, res.dc, bias)
            # and the friction is far from negligible here: H is not G
            assert abs(res.H - g) / abs(g) > 0.1
        assert errors[4.0] < errors[2.0]


def test_friction_lowers_the_response_at_the_lower_magnitude(runner):
    for f in (0.5, 5.0):
        assert abs(run(runner("g1"), 0.6, f).H) < 0.5 * abs(run(runner("g1"), 2.0, f).H)


def test_a_response_without_steady_state_is_flagged(runner):
    """g2 with Coulomb friction has a friction-induced limit cycle near 5 Hz (relay feedback through G2's
    -180 degree crossing): at m = 0.6, 1 Hz it never becomes periodic with the excitation."""
    res = run(runner("g2"), 0.6, 1.0, max_time=4.0)
    assert not res.converged and res.last_change > 1e-4 and res.remaining_error == math.inf
    assert res.settling_time == pytest.approx(4.0)


# ---------------------------------------------------------------------------
# Any FMU: named variables, input-port drive with a held input
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def foreign_fmu(built_fmu, tmp_path_factory):
    """g1 with its variables renamed (force -> speed) and without the built-in excitation parameters."""
    path = tmp_path_factory.mktemp("foreign") / "foreign.fmu"
    with zipfile.ZipFile(built_fmu("g1", 3)) as zin, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                text = re.sub(r'\s*<Float64 name="excitation_(amplitude|frequency)"[^>]*/>', "", data.decode())
                data = text.replace('name="u"', 'name="force"').replace('name="v"', 'name="speed"').encode()
            zout.writestr(item, data)
    return path


def test_fmu_without_builtin_excitation_is_driven_through_its_input(runner, foreign_fmu):
    for m, f in ((2.0, 5.0), (0.6, 1.0)):
        held = run(runner(None, path=foreign_fmu, input="force", output="speed"), m, f, input="force",
                   output="speed")
        exact = run(runner("g1"), m, f)
        assert held.excitation == "input"
        n = MeasureOptions().samples_per_period
        assert held.hold_error == pytest.approx(math.pi / (math.sqrt(3) * n), rel=1e-6)
        assert held.U1 == pytest.approx(m * np.sinc(1 / n), rel=1e-15)
        # the held staircase's first harmonic is U1 exactly; what remains is far below the stored estimate
        assert abs(held.H - exact.H) / abs(exact.H) < min(1e-5, held.hold_error)


def test_measure_checks_the_fmu_and_the_plan_before_writing(built_fmu, foreign_fmu, tmp_path):
    out = tmp_path / "d.h5"
    cases = [
        (dict(fmu=foreign_fmu), "no variable named 'u'.*force"),
        (dict(fmu=foreign_fmu, options=MeasureOptions(input="force", output="nosuch")), "no variable named 'nosuch'"),
        (dict(fmu=built_fmu("g1"), options=MeasureOptions(input="v")), "'v' has causality output, not input"),
        (dict(fmu=built_fmu("g1"), amplitudes=[2.0, 0.0]), "amplitude must be a positive"),
        (dict(fmu=built_fmu("g1"), amplitudes=[-1.0]), "amplitude must be a positive"),
        (dict(fmu=built_fmu("g1"), frequencies=[1.0, -2.0]), "frequency must be a positive"),
        (dict(fmu=built_fmu("g1"), frequencies=[0.0]), "frequency must be a positive"),
        (dict(fmu=built_fmu("g1"), frequencies=[float("nan")]), "frequency must be a positive"),
        (dict(fmu=tmp_path / "none.fmu"), "no such FMU file"),
    ]
    for kwargs, message in cases:
        kwargs.setdefault("frequencies", [1.0])
        with pytest.raises(UserError, match=message):
            measure(output=out, run=RunOptions(workers=0), **kwargs)
        assert not out.exists()


def test_default_frequency_grid_comes_from_the_bandwidth(built_fmu):
    factory = FmuRunnerFactory(built_fmu("g1").read_bytes(), "g1", "u", "v")
    bandwidth = estimate_bandwidth(factory, 2.0, 1e-10)
    assert bandwidth == pytest.approx(10 / (2 * math.pi), rel=1e-3)  # first order: exactly the corner
    assert default_frequencies(bandwidth) == (0.5, 1.0, 2.0, 5.0, 10.0, 20.0)


# ---------------------------------------------------------------------------
# Parallel runs and noise
# ---------------------------------------------------------------------------
def same_results(a, b):
    assert [e.index for e in a.experiments] == [e.index for e in b.experiments]
    for x, y in zip(a.experiments, b.experiments):
        for name in ("H", "V1", "U1", "dc", "distortion", "converged", "settling_time", "window_start",
                     "last_change", "noise_sigma", "H_noisy"):
            assert getattr(x, name) == getattr(y, name), name
        np.testing.assert_array_equal(x.harmonics, y.harmonics)
        for series in ("transient", "window"):
            for signal in ("time", "u", "v", "v_noisy"):
                np.testing.assert_array_equal(getattr(getattr(x, series), signal), getattr(getattr(y, series), signal))


def test_local_processes_and_a_dask_cluster_give_exactly_the_in_process_numbers(built_fmu, tmp_path):
    from distributed import LocalCluster

    fmu = built_fmu("g1")
    kwargs = dict(amplitudes=[2.0, 0.6], frequencies=[1.0, 5.0], options=MeasureOptions(noise_snr_db=30, seed=4))
    serial = measure(fmu, tmp_path / "serial.h5", run=RunOptions(workers=0), **kwargs)
    local = measure(fmu, tmp_path / "local.h5", run=RunOptions(workers=2), **kwargs)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, worker_dashboard_address=None) as cluster:
        dask = measure(fmu, tmp_path / "dask.h5", run=RunOptions(scheduler=cluster.scheduler_address), **kwargs)
    assert len(serial.experiments) == 4 and serial.complete
    same_results(serial, local)
    same_results(serial, dask)


class CountingFactory:
    """A worker resource whose creations can be told apart."""

    key = "counting"

    def __call__(self):
        return object()


def whoami(obj, item):
    return os.getpid(), id(obj), item


def test_each_worker_makes_its_resource_once():
    with Workers(workers=2) as pool:
        seen = list(pool.imap(whoami, list(range(12)), resource=WorkerResource("counting", CountingFactory())))
    assert sorted(i for i, _ in seen) == list(range(12)) and all(i == r[2] for i, r in seen)
    per_process = {}
    for _, (pid, obj, _) in seen:
        per_process.setdefault(pid, set()).add(obj)
    assert 1 <= len(per_process) <= 2 and all(len(objs) == 1 for objs in per_process.values())
    assert os.getpid() not in per_process


def test_noise_has_the_requested_snr_and_depends_only_on_the_seed(runner):
    a = run(runner("g1"), 2.0, 2.0, noise_snr_db=20.0, seed=7)
    b = run(runner("g1"), 2.0, 2.0, noise_snr_db=20.0, seed=7)
    c = run(runner("g1"), 2.0, 2.0, noise_snr_db=20.0, seed=8)
    clean = run(runner("g1"), 2.0, 2.0)
    np.testing.assert_array_equal(a.window.v_noisy, b.window.v_noisy)
    assert not np.array_equal(a.window.v_noisy, c.window.v_noisy)
    np.testing.assert_array_equal(a.window.v, clean.window.v)  # the clean signal is kept as it was
    assert a.H == clean.H and clean.window.v_noisy is None
    noise = a.window.v_noisy - a.window.v
    assert a.noise_sigma ** 2 == pytest.approx(np.var(a.window.v) / 100, rel=1e-12)
    assert np.std(noise) == pytest.approx(a.noise_sigma, rel=0.05)  # 8193 samples: ±0.8 % (1 sigma)
    # the noisy first harmonic is off by about sigma·sqrt(2/N): small, but not zero
    assert 0 < abs(a.H_noisy - a.H) * 2.0 < 10 * a.noise_sigma * math.sqrt(2 / len(noise))


def test_resume_refuses_a_different_fmu_or_plan(built_fmu, tmp_path):
    out = tmp_path / "d.h5"
    measure(built_fmu("g1"), out, amplitudes=[2.0], frequencies=[5.0], run=RunOptions(workers=0))
    before = out.read_bytes()
    with pytest.raises(UserError, match=r"exists already \(give overwrite=True to replace it, or resume=True to continue it\)"):
        measure(built_fmu("g1"), out, amplitudes=[2.0], frequencies=[5.0], run=RunOptions(workers=0))
    with pytest.raises(UserError, match="cannot resume: it was measured with a different FMU"):
        measure(built_fmu("g2"), out, amplitudes=[2.0], frequencies=[5.0], run=RunOptions(workers=0, resume=True))
    with pytest.raises(UserError, match="cannot resume: its plan"):
        measure(built_fmu("g1"), out, amplitudes=[2.0], frequencies=[5.0, 10.0],
                run=RunOptions(workers=0, resume=True))
    with pytest.raises(UserError, match="tolerance"):
        measure(built_fmu("g1"), out, amplitudes=[2.0], frequencies=[5.0], run=RunOptions(workers=0, resume=True),
                options=MeasureOptions(tolerance=1e-10))
    assert out.read_bytes() == before
    # a complete file resumed: nothing to do, nothing changes
    data = measure(built_fmu("g1"), out, run=RunOptions(workers=0, resume=True))
    assert len(data.experiments) == 1 and read_data_file(out).complete
