"""The drive's friction feed-forward with the Stribeck curve's shape exponent δ and direction-dependent viscous
friction (docs/control.md, [compensation] delta, fv_pos, fv_neg): the C law, its numpy copy and the formula
written here agree; a δ-aware feed-forward tracks a δ ≠ 2 axis better than the Gaussian one; bad values are
refused in one line naming the key, nothing written; a controller without the keys is written as before."""
from __future__ import annotations

import re

import numpy as np
import pytest

from servofmu.cli import main
from servofmu.identification.law_check import feedforward_force, law_command
from servofmu.model.controller import (ControllerError, controller_from_dict, controller_toml, friction_feedforward,
                                       load_controller)
from servofmu.model.plant import plant_from_dict
from servofmu.simulation.closed_loop import LoopSimulator
from servofmu.text_digest import with_digest

# stribeck_axis (100 kg, 200 N·s/m in G's pole) with a shaped curve δ = 0.5 and direction-dependent viscous friction
PLANT = {"name": "shaped_axis", "linear": {"poles": [[-2.0, 0.0]], "zeros": [], "gain": 0.01},
         "friction": {"model": "stribeck", "fc_pos": 40.0, "fc_neg": 32.0, "fs_pos": 60.0, "fs_neg": 50.0,
                      "vs": 0.01, "delta": 0.5, "fv_pos": 20.0, "fv_neg": 35.0, "v_smooth": 1e-4}}
DRIVE = {"name": "drive", "sample_time": 1e-3, "velocity": {"kp": 18850.0},
         "compensation": {"share": 1.0, "fc_pos": 40.0, "fc_neg": 32.0, "fs_pos": 60.0, "fs_neg": 50.0, "vs": 0.01,
                          "fv": 7.0, "delta": 0.7, "fv_pos": 20.0, "fv_neg": 35.0, "v_smooth": 1e-3}}


def formula(v, c):
    """F_ff(v) as docs/control.md writes it, from the file's [compensation] keys."""
    g = {s: c[f"fc_{s}"] + (c[f"fs_{s}"] - c[f"fc_{s}"]) * np.exp(-np.abs(v / c["vs"]) ** c["delta"])
         for s in ("pos", "neg")}
    th = np.tanh(v / c["v_smooth"])
    return (g["pos"] * np.maximum(th, 0) + g["neg"] * np.minimum(th, 0) + c["fv"] * v
            + c["fv_pos"] * np.maximum(v, 0) + c["fv_neg"] * np.minimum(v, 0))


@pytest.fixture(scope="module")
def simulator():
    plant = plant_from_dict(PLANT)
    return plant, LoopSimulator(plant)


def _stroke(seconds=2.0, amplitude=0.01, hz=1.0, ts=1e-3):
    t = np.arange(0.0, seconds, ts)
    return t, amplitude * (1 - np.cos(2 * np.pi * hz * t))


def test_the_C_law_its_numpy_copy_and_the_formula_agree_on_the_new_keys(simulator):
    plant, sim = simulator
    section = DRIVE["compensation"]
    v = np.linspace(-0.2, 0.2, 4001)
    drive = controller_from_dict(DRIVE)
    np.testing.assert_allclose(feedforward_force(drive, v), formula(v, section), rtol=1e-12, atol=1e-12)
    # the C law alone: a velocity gain so small that the command is the feed-forward at the reference velocity
    bare = drive.with_values(kp_velocity=1e-12)
    t, r = _stroke()
    loop = sim.simulate_loop(plant.parameter_vector()[None], t, r, bare, rtol=1e-10)
    v_ref = np.diff(r, prepend=r[0]) / bare.sample_time
    scale = np.max(np.abs(loop.command[0]))
    np.testing.assert_allclose(loop.command[0][1:], formula(v_ref, section)[:-1], rtol=0, atol=1e-9 * scale)
    # and the whole law, in a loop that tracks: C against numpy, command by command
    loop = sim.simulate_loop(plant.parameter_vector()[None], t, r, drive, rtol=1e-10)
    own = loop.command[0]
    numpy_law = np.concatenate([[0.0], law_command(drive, r, loop.position[0])])[:own.size]
    np.testing.assert_allclose(numpy_law, own, rtol=0, atol=1e-9 * np.max(np.abs(own)))


def test_the_shape_aware_feedforward_tracks_a_shaped_axis_better(simulator):
    plant, sim = simulator
    aware = friction_feedforward(load_controller("axis_controller"), plant)
    assert (aware["ff_delta"], aware["ff_fv_pos"], aware["ff_fv_neg"]) == (0.5, 20.0, 35.0)
    assert aware["ff_fv"] == pytest.approx(200.0)  # G's pole: the damping common to both directions
    t, r = _stroke()
    rms = {}
    for label, c in (("aware", aware), ("gaussian", aware.with_values(ff_delta=2.0)),
                     ("symmetric", aware.with_values(ff_fv_pos=27.5, ff_fv_neg=27.5))):
        e = r - sim.simulate_loop(plant.parameter_vector()[None], t, r, c, rtol=1e-10).position[0]
        rms[label] = float(np.sqrt(np.mean(e ** 2)))
    assert rms["gaussian"] / rms["aware"] > 2.0, rms  # measured 2.7
    assert rms["symmetric"] > rms["aware"], rms


def test_the_keys_are_written_with_the_digest_and_read_back(tmp_path):
    aware = friction_feedforward(load_controller("axis_controller"), plant_from_dict(PLANT))
    path = tmp_path / "tuned.toml"
    path.write_text(with_digest(controller_toml(aware, "tuned")))
    again = load_controller(path)
    assert again.values == aware.values
    plain = controller_toml(load_controller("axis_controller"))
    assert "delta" not in plain and "fv_pos" not in plain  # a file without the keys is written as before


@pytest.mark.parametrize("changes, key, why", [
    ({"delta": 0.0}, "compensation.delta", "must be in (0, inf]"),
    ({"delta": -1.0}, "compensation.delta", "must be in (0, inf]"),
    ({"fv_pos": None, "fv_neg": 3.0}, "compensation.fv_neg", "needs fv_pos too"),
    ({"fv_neg": None, "fv_pos": 3.0}, "compensation.fv_pos", "needs fv_neg too"),
    ({"fv_pos": -1.0}, "compensation.fv_pos", "must be in [0, inf]"),
    ({"fv": -1.0}, "compensation.fv", "must be in [0, inf]"),
])
def test_bad_values_are_refused_in_one_line_naming_the_key(tmp_path, capsys, changes, key, why):
    section = {k: v for k, v in {**DRIVE["compensation"], **changes}.items() if v is not None}
    with pytest.raises(ControllerError, match=rf"^bad.toml: {key}: .*{re.escape(why)}"):
        controller_from_dict({**DRIVE, "compensation": section}, "bad.toml")
    if key != "compensation.delta" or changes["delta"] != 0.0:
        return  # the command line once: one line, exit 2, nothing written
    bad = tmp_path / "bad.toml"
    bad.write_text(f'sample_time = 0.001\n[velocity]\nkp = 100.0\n[compensation]\ndelta = 0.0\n')
    assert main(["controller", str(bad), "-o", str(tmp_path / "drive.fmu")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"servofmu controller: error: {bad}: compensation.delta: must be in (0, inf]", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]
