"""Broadband through files and FMUs: the signal file's round trip, `measure --excitation` on a friction-free g2 FMU
(the BLA equals its zero-order-hold G at every line) and on g1 with friction, `frf`'s outputs, and one-line errors
with nothing written."""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from clitools import assert_one_line_error, run
from scipy import signal

from servofmu.broadband import BroadbandPlan
from servofmu.broadband.measure import measure_broadband
from servofmu.broadband.store import read_broadband, read_excitation_csv
from servofmu.fmu import build_fmu
from servofmu.measurement.datafile import read_data_file
from servofmu.model.plant import load_plant

ROOT = Path(__file__).resolve().parent.parent
SMALL = ["--band", "0.5,40", "--period", "2", "--rate", "200", "--periods", "2", "--realisations", "2"]


def test_the_signal_file_holds_its_plan_and_reads_back_exactly(tmp_path):
    out = tmp_path / "sig.csv"
    proc = run("excitation", "multisine", "--levels", "2.0,0.6", *SMALL, "--seed", "7", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "crest factor" in proc.stdout
    plan, time, force = read_excitation_csv(out)
    assert plan == BroadbandPlan("multisine", (2.0, 0.6), (0.5, 40.0), 200.0, period=2.0, periods=2,
                                 realisations=2, seed=7)
    assert time.size == 2 * 2 * 3 * 400 and time[1] == pytest.approx(1 / 200)
    assert np.allclose(force, plan.signals().ravel(), rtol=1e-9)
    out.write_text(out.read_text().rsplit("\n", 2)[0] + "\n")  # the last sample cut off
    with pytest.raises(ValueError, match="not those of the plan"):
        read_excitation_csv(out)


@pytest.mark.parametrize("argv, fragments", [
    (["multisine", "--band", "1,600", "--rate", "1000"], ["--band: f_max 600 Hz", "Nyquist"]),
    (["chirp", "--band", "1,40", "--levels", "2,0"], ["--levels: must be a positive number"]),
    (["prbs", "--band", "1,40", "--levels", "-1"], ["--levels"]),
    (["multisine", "--band", "1.2,1.8", "--period", "1"], ["--band: no line"]),
    (["multisine", "--band", "1,40", "--period", "0.0123", "--rate", "100"], ["--period: 0.0123 s"]),
    (["multisine", "--levels", "1"], ["--band: give the band"]),
])
def test_bad_plans_are_one_line_errors_naming_the_option_and_nothing_is_written(tmp_path, argv, fragments):
    out = tmp_path / "sig.csv"
    proc = run("excitation", *argv, "-o", out)
    assert_one_line_error(proc, "servofmu excitation: error:", *fragments)
    assert not out.exists()


def zoh_response(rate: float, f: np.ndarray) -> np.ndarray:
    """G2(s) = K/((s + 10)(s² + 5s + 2.5² + 31.52²)), DC gain 1, discretised for a held input."""
    den = np.polymul([1, 10], [1, 5, 2.5 ** 2 + 31.52 ** 2])
    a, b, c, d, _ = signal.cont2discrete(signal.tf2ss([den[-1]], den), 1 / rate, "zoh")
    z = np.exp(2j * np.pi * f / rate)
    return np.array([(c @ np.linalg.solve(zi * np.eye(3) - a, b))[0, 0] + d[0, 0] for zi in z])


def test_on_a_friction_free_fmu_the_bla_is_the_plants_response_at_every_line_to_1e_6(tmp_path):
    text = (ROOT / "fmu_models" / "g2.toml").read_text()
    text = text.replace('name = "g2"', 'name = "g2lin"').replace("fc_pos = 0.5", "fc_pos = 0.0") \
        .replace("fc_neg = 0.4", "fc_neg = 0.0")
    (tmp_path / "g2lin.toml").write_text(text)
    fmu = build_fmu(load_plant(tmp_path / "g2lin.toml"), tmp_path / "g2lin.fmu")
    plan = BroadbandPlan("multisine", (1.0,), (0.5, 40.0), 200.0, period=2.0, periods=2, transient_periods=4,
                         realisations=2)
    data = measure_broadband(fmu, tmp_path / "lin.h5", plan)
    b = data.levels[0].bla
    g = zoh_response(200.0, b.frequencies)
    assert b.frequencies.size > 20
    assert np.max(np.abs(b.G - g) / np.abs(g)) <= 1e-6


def test_measure_excitation_on_g1_stores_records_and_bla_and_frf_reads_them(tmp_path, built_fmu):
    fmu, data = built_fmu("g1"), tmp_path / "g1.h5"
    proc = run("measure", fmu, "--excitation", "multisine", "--levels", "2.0,0.6", *SMALL, "--noise-snr", "40",
               "-o", data)
    assert proc.returncode == 0, proc.stderr
    assert read_data_file(data).kind == "broadband"  # the data file's reader takes the new kind
    stored = read_broadband(data)
    assert [lv.level for lv in stored.levels] == [2.0, 0.6]
    assert stored.levels[0].u.shape == (2, 3 * 400) and stored.levels[0].v_noisy is not None
    proc = run("frf", data, "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["format"] == "servofmu-frf" and len(doc["levels"]) == 2
    high, low = doc["levels"]
    for key in ("frequency", "re", "im", "std_noise", "std_distortion", "std_total", "coherence"):
        assert len(high[key]) == len(stored.plan.lines)
    # Coulomb friction: distortions far above the 40 dB noise, relatively larger at the lower level
    assert low["distortion_to_noise_db"] > 10 and high["distortion_to_noise_db"] > 10
    assert low["relative_distortion_db"] > high["relative_distortion_db"]
    figure, frf = tmp_path / "bla.png", tmp_path / "frf.h5"
    assert run("frf", data, "-o", figure).returncode == 0 and figure.stat().st_size > 10_000
    assert run("frf", data, "-o", frf).returncode == 0
    with h5py.File(frf) as f:
        assert f.attrs["format"] == "servofmu-frf" and sorted(f) == ["level_00", "level_01"]
        assert np.allclose(f["level_00/G"][()], np.asarray(high["re"]) + 1j * np.asarray(high["im"]))


def test_frf_and_measure_refuse_what_they_cannot_use_in_one_line(tmp_path, built_fmu):
    csv = tmp_path / "sig.csv"
    assert run("excitation", "prbs", "--band", "1,40", "--rate", "200", "-o", csv).returncode == 0
    assert_one_line_error(run("frf", csv), "sig.csv: not a readable data file")
    assert_one_line_error(run("frf", csv, "-o", tmp_path / "x.txt"), "-o", "x.txt", "give an FRF file")
    out = tmp_path / "m.h5"
    proc = run("measure", built_fmu("g1"), "--excitation", "multisine", "--band", "1,40", "--frequencies", "1",
               "-o", out)
    assert_one_line_error(proc, "--frequencies: a stepped-sine option")
    proc = run("measure", built_fmu("g1"), "--excitation", "chirp", "--band", "1,150", "--rate", "200", "-o", out)
    assert_one_line_error(proc, "servofmu measure: error: --band: f_max 150 Hz")
    assert not out.exists()
