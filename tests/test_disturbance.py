"""A known disturbance in the co-simulated loop: a disturbance source FMU in the SSP, both engines agreeing on
every recorded signal (the quantised encoder included), the records carrying the disturbance as an imported
drive log does, and the loop simulator replaying them."""
from __future__ import annotations

import numpy as np
import pytest
from clitools import assert_one_line_error, run

import servofmu as sf
from servofmu.control.cosim import cosimulate, write_cosim_records
from servofmu.model.controller import load_controller
from servofmu.simulation.closed_loop import LoopSimulator

TS = 1e-3


@pytest.fixture(scope="module")
def axis(tmp_path_factory):
    """stribeck_axis with the example drive (a 1 µm encoder) on a 2 s reference, 300 N pulses injected."""
    folder = tmp_path_factory.mktemp("dist")
    t = np.arange(0.0, 2.0 + TS / 2, TS)
    x = 0.03 * (1 - np.cos(2 * np.pi * 0.5 * t)) + 0.01 * (1 - np.cos(2 * np.pi * 2.3 * t))
    np.savetxt(folder / "ref.csv", np.column_stack([t, x]), delimiter=",", header="time,position", comments="")
    force = np.where((t % 0.2 > 0.05) & (t % 0.2 < 0.06), 300.0, 0.0) - np.where(t % 0.35 > 0.3, 120.0, 0.0)
    force[:2] = 0.0
    np.savetxt(folder / "dist.csv", np.column_stack([t, force]), delimiter=",", header="time,force", comments="")
    for args in (("build", "stribeck_axis", "--fmi-version", "2", "-o", folder / "plant.fmu"),
                 ("controller", "axis_controller", "--fmi-version", "2", "-o", folder / "ctrl.fmu"),
                 ("system", folder / "plant.fmu", folder / "ctrl.fmu", "--reference", folder / "ref.csv",
                  "--disturbance", folder / "dist.csv", "-o", folder / "axis.ssp")):
        proc = run(*args)
        assert proc.returncode == 0, proc.stderr
    return {"folder": folder, "ssp": folder / "axis.ssp", "force": force}


def test_engines_agree_on_every_signal_with_a_disturbance_and_an_encoder(axis):
    runs = {engine: cosimulate(axis["ssp"], engine=engine) for engine in ("libcosim", "fmpy")}
    a, b = runs["libcosim"], runs["fmpy"]
    assert set(a.signals) == set(b.signals) >= {"disturbance", "position_measured", "force_command"}
    for name in a.signals:
        assert np.max(np.abs(a[name] - b[name])) <= 1e-12 * max(1.0, np.max(np.abs(a[name]))), name
    # the encoder quantises: its readings are whole micrometres, and the pulses moved the axis
    assert np.allclose(a["position_measured"] * 1e6, np.round(a["position_measured"] * 1e6), atol=1e-6)
    assert np.max(np.abs(a["force"])) > 300


def test_cosim_records_carry_the_disturbance_and_replay_exactly(axis, tmp_path):
    proc = run("cosim", axis["ssp"], "--engine", "fmpy", "-o", tmp_path / "rec.h5")
    assert proc.returncode == 0, proc.stderr
    rec = sf.read_data_file(tmp_path / "rec.h5").records[0]
    s = rec.series
    # the force of the table's time t_k is applied from t_k on, as an imported log's disturbance column
    np.testing.assert_array_equal(s.disturbance, axis["force"][:-1])
    assert rec.columns["disturbance"].startswith("disturbance.")
    # the loop simulator, the quantiser switched on, replays the record: the law and the injection are the same
    plant = sf.load_plant("stribeck_axis")
    loop = LoopSimulator(plant).simulate_loop(plant.parameter_vector()[None], s.time, s.reference,
                                              load_controller("axis_controller"), rtol=1e-10,
                                              disturbance=s.disturbance)
    assert np.max(np.abs(loop.command[0] - s.u)) <= 1e-9 * np.max(np.abs(s.u))
    assert np.max(np.abs(loop.position[0] - s.position)) <= 1e-6  # the encoder's quantum
    # without the disturbance the replay is far off: the test sees the injection
    bare = LoopSimulator(plant).simulate_loop(plant.parameter_vector()[None], s.time, s.reference,
                                              load_controller("axis_controller"), rtol=1e-10)
    assert np.max(np.abs(bare.command[0] - s.u)) > 100


@pytest.mark.parametrize("rows, fragment", [
    ("time,force\n0,0\n0.001,5\n0.002,0\n", "a disturbance is 0 at the first two samples"),
    ("time,newton\n0,0\n0.001,0\n", "no column 'force'"),
    ("time,force\n0,0\n0.001,nan\n", "column 'force' is nan"),
])
def test_bad_disturbances_are_one_line_errors(axis, tmp_path, rows, fragment):
    (tmp_path / "d.csv").write_text(rows + "".join(f"{k * TS},0\n" for k in range(3, 20)))
    folder = axis["folder"]
    proc = run("system", folder / "plant.fmu", folder / "ctrl.fmu", "--reference", folder / "ref.csv",
               "--disturbance", tmp_path / "d.csv", "-o", tmp_path / "a.ssp")
    assert_one_line_error(proc, fragment)
    assert not (tmp_path / "a.ssp").exists()
