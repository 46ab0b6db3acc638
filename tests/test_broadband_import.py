"""A drive's log of a broadband signal: `import --excitation SIGNAL.csv` recovers the plan's periods, lines and levels
exactly and computes the BLA; a log of another length, rate or signal is refused in one line with nothing written;
without --excitation a periodic multisine is named as such and two tones are never taken for one sine."""
from __future__ import annotations

import numpy as np
import pytest
from clitools import assert_one_line_error, run

from servofmu.broadband.store import read_broadband, read_excitation_csv
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.records import analyse_record
from servofmu.model.plant import load_plant
from servofmu.simulation.batch import BatchSimulator

SMALL = ["--levels", "2.0,0.6", "--band", "0.5,40", "--period", "2", "--rate", "200", "--periods", "2",
         "--realisations", "2", "--seed", "5"]


def log_of(signal, path, scale=0.5, rate_factor=1.0, cut=0):
    """g1 driven by the signal file's force: columns t, cmd (force / scale, as a drive's current command), vel."""
    plan, t, force = read_excitation_csv(signal)
    plant = load_plant("g1")
    v = BatchSimulator(plant).simulate_record(plant.parameter_vector()[None], t, force, hold="zoh").v[0]
    rows = np.column_stack([t * rate_factor, force / scale, v])[:len(t) - cut]
    np.savetxt(path, rows, delimiter=",", header="t,cmd,vel", comments="")
    return plan


def test_import_excitation_recovers_the_plan_exactly_and_measures_the_bla(tmp_path):
    signal, log, out = tmp_path / "sig.csv", tmp_path / "log.csv", tmp_path / "bb.h5"
    assert run("excitation", "multisine", *SMALL, "-o", signal).returncode == 0
    plan = log_of(signal, log)
    proc = run("import", log, "--excitation", signal, "--time", "t", "--input", "cmd", "--input-scale", "0.5",
               "--output-variable", "vel", "-o", out)
    assert proc.returncode == 0, proc.stderr
    data = read_broadband(out)
    assert data.plan == plan
    assert [lv.level for lv in data.levels] == [2.0, 0.6]
    for lv in data.levels:
        assert np.array_equal(lv.bla.frequencies, plan.frequencies)  # the lines, exactly
        assert lv.bla.distortion_to_noise_db > 10  # g1's friction
    assert np.allclose(data.levels[0].u.ravel(), plan.signals()[0].ravel(), rtol=1e-9)
    assert read_data_file(out).kind == "broadband"


def test_a_log_of_another_length_rate_or_signal_is_refused_in_one_line_and_nothing_is_written(tmp_path):
    signal, other = tmp_path / "sig.csv", tmp_path / "other.csv"
    assert run("excitation", "multisine", *SMALL, "-o", signal).returncode == 0
    assert run("excitation", "multisine", *SMALL[:-1], "6", "-o", other).returncode == 0
    cases = [(dict(cut=3), ["4797 samples", "4800"]), (dict(rate_factor=2.0), ["steps by", "--rate"])]
    for i, (kw, fragments) in enumerate(cases):
        log = tmp_path / f"log{i}.csv"
        log_of(signal, log, **kw)
        proc = run("import", log, "--excitation", signal, "--time", "t", "--input", "cmd", "--output-variable",
                   "vel", "-o", tmp_path / "x.h5")
        assert_one_line_error(proc, str(log), *fragments)
    log = tmp_path / "log.csv"
    log_of(signal, log)
    proc = run("import", log, "--excitation", other, "--time", "t", "--input", "cmd", "--output-variable", "vel",
               "-o", tmp_path / "x.h5")
    assert_one_line_error(proc, "is not the excitation", "other.csv")
    assert not (tmp_path / "x.h5").exists()


def test_without_excitation_a_multisine_is_named_and_two_tones_are_never_one_sine(tmp_path):
    signal, log = tmp_path / "sig.csv", tmp_path / "log.csv"
    assert run("excitation", "multisine", *SMALL, "-o", signal).returncode == 0
    plan = log_of(signal, log)
    proc = run("import", log, "--time", "t", "--input", "cmd", "--output-variable", "vel", "-o", tmp_path / "r.h5")
    assert proc.returncode == 0, proc.stderr
    assert f"a periodic multisine of {plan.lines.size} lines, period 2 s" in proc.stdout
    assert read_data_file(tmp_path / "r.h5").records[0].analysis is None
    t = np.arange(20000) / 1000.0
    sine = 2 * np.sin(2 * np.pi * 3 * t)
    two = sine + 0.45 * np.sin(2 * np.pi * 7.3 * t)  # 95 % of the power at 3 Hz
    analysis, note = analyse_record(t, two, two)
    assert analysis is None and "7.3 Hz" in note and "not one sinusoid" in note
    harmonic = sine + 0.3 * np.sin(2 * np.pi * 9 * t)  # a distorted sine is still one sine
    assert analyse_record(t, harmonic, harmonic)[0].frequency == pytest.approx(3.0, rel=1e-4)

