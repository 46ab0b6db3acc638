"""Friction laws as objects in one registry: a law written here, registered at test time, runs through every stage
with no other change to the package; no module outside servofmu/model/laws compares a law's name; bad friction
keys are refused naming the key."""
import os
import re
import subprocess
from pathlib import Path

import fmpy
from fmpy.validation import validate_fmu
import numpy as np
import pytest

import servofmu as sf
from servofmu.identification.criterion import sine_data
from servofmu.identification.prior import identified_mask
from servofmu.measurement.measure import MeasureOptions
from servofmu.model.laws.base import FrictionLaw
from servofmu.model.laws.coulomb import LEVEL_KEYS
from servofmu.model.laws.keys import LawKey
from servofmu.model.laws.registry import law_names, register, unregister
from servofmu.model.plant import PlantError, plant_from_dict
from servofmu.runtime import RunOptions
from servofmu.selection.select import SelectOptions

ROOT = Path(__file__).resolve().parent.parent


class Saturating(FrictionLaw):
    """A law of this test only: levels reached exponentially, F = fc±·(1 − exp(−|v|/vc))·sign(v)."""

    name = "saturating"
    title = "Coulomb levels reached exponentially over the velocity vc"
    keys = LEVEL_KEYS + (LawKey("vc", "m/s", "velocity over which the level is reached", positive=True),)
    smoothing = False
    cost = 1
    equations = "F = fc+*(1 - exp(-max(v, 0)/vc)) - fc-*(1 - exp(min(v, 0)/vc)) + viscous"

    def force(self, par, v, states):
        import casadi as ca

        return (par["fc_pos"] * (1 - ca.exp(-ca.fmax(v, 0) / par["vc"]))
                - par["fc_neg"] * (1 - ca.exp(ca.fmin(v, 0) / par["vc"]))), []

    def start_values(self, fc_pos, fc_neg, v_rms, mass):
        return {"vc": 0.1 * v_rms}


@pytest.fixture
def saturating():
    law = register(Saturating())
    yield law
    unregister(law.name)


PLANT = {"name": "sat1", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
         "friction": {"model": "saturating", "fc_pos": 0.5, "fc_neg": 0.4, "vc": 0.02}}


def test_a_law_written_here_has_its_keys_states_and_equations(saturating, tmp_path):
    """The fast part of the next test, in the default suite: the plant file round trip, the CasADi model's
    friction force, the value rules and the units, with no compiler."""
    from servofmu.model.friction import steady_friction
    from servofmu.model.plant import parameter_rules

    plant = plant_from_dict(PLANT)
    assert sf.load_plant(_written(tmp_path, plant)) == plant
    v = np.array([-0.1, -0.01, 0.01, 0.1])
    expected = np.where(v > 0, 0.5 * (1 - np.exp(-v / 0.02)), -0.4 * (1 - np.exp(v / 0.02)))
    assert np.allclose(steady_friction(plant, v), expected, rtol=1e-14)
    rules = parameter_rules(plant)
    names = plant.parameter_names()
    assert rules.low_open[names.index("vc")] and not rules.low_open[names.index("fc_pos")]
    assert sf.Plant.parameter_names(plant) == names and "vc" in plant.parameters()
    with pytest.raises(PlantError, match=r"friction.vc: must be positive"):
        plant_from_dict({**PLANT, "friction": {**PLANT["friction"], "vc": 0.0}})


def _written(folder, plant):
    path = folder / f"{plant.name}.toml"
    path.write_text(plant.to_toml())
    return path


@pytest.mark.long
@pytest.mark.skipif(os.environ.get("SERVOFMU_FAULTS") != "all", reason="long: SERVOFMU_FAULTS=all runs it")
def test_a_law_written_here_runs_plant_file_to_export_and_back(saturating, tmp_path):
    """plant file → CasADi model → FMU (FMI 2 and 3, validate_fmu clean) → measure → identify (noise-free, 1e-6)
    → select (ranked) → export and back, for a law the package does not ship.  About 20 s with the compiled
    simulators cached, 40 s without: marked long."""
    path = tmp_path / "sat1.toml"
    path.write_text(plant_from_dict(PLANT).to_toml())
    plant = sf.load_plant(path)
    assert plant.parameter_names()[-4:] == ["fc_pos", "fc_neg", "vc", "fv"] and plant.friction.vc == 0.02
    fmus = {v: sf.build_fmu(plant, tmp_path / f"sat{v}.fmu", fmi_version=v) for v in (2, 3)}
    for fmu in fmus.values():
        assert validate_fmu(str(fmu)) == []
        names = {v.name for v in fmpy.read_model_description(str(fmu)).modelVariables}
        assert {"vc", "fc_pos", "friction_force"} <= names
    data = {}
    for name, amplitudes in (("fit", [2.0, 0.6]), ("val", [1.5, 0.8])):
        data[name] = tmp_path / f"{name}.h5"
        sf.measure(fmus[3 if name == "fit" else 2], data[name], options=MeasureOptions(),
                   run=RunOptions(workers=0), amplitudes=amplitudes, frequencies=[0.5, 2.0, 8.0])
    est = sf.PSOANNIdentifier(plant, method="pso", seed=1).fit(sine_data(sf.read_data_file(data["fit"])))
    truth = plant.parameter_vector()[identified_mask(plant)]
    assert np.max(np.abs(est.theta_ / truth - 1)) < 1e-6
    result = tmp_path / "result.h5"
    sf.write_result(result, est.result())
    selection = sf.select_files([data["fit"]], data["val"], tmp_path / "s.h5",
                                SelectOptions(candidates=("saturating/1", "coulomb/1"), iterations=10),
                                RunOptions(workers=0))
    assert [s.name for s in selection.scores][0] == "saturating/1" and len(selection.scores) == 2
    back, _ = sf.export_result(result, tmp_path / "back.toml")
    again = sf.load_plant(back)
    assert again.friction.model == "saturating"
    assert np.allclose(again.parameter_vector(), est.result().plant.parameter_vector(), rtol=1e-15)
    exported, _ = sf.export_result(result, tmp_path / "back.fmu", fmi_version=2)
    assert validate_fmu(str(exported)) == []


# A comparison with a law's name: a string literal of one, or the law/model attribute compared with anything
NAME_PATTERNS = [r"""["'](coulomb|stribeck|lugre|dahl|gms)["']""",
                 r"""\.(model|law)\s*(==|!=|\bin\b|\bnot in\b)""", r"""(==|!=)\s*\w+\.(friction\.model|law)\b"""]


def test_no_module_outside_the_laws_package_compares_a_laws_name():
    """git grep over servofmu/: a law's name appears as a string only in its own module and the registry; no
    module tests a friction's law or a candidate's law against a name.  Comparing two structures' laws with each
    other (compare.py, starts.py) is no test of a name."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    hits = []
    for pattern in NAME_PATTERNS:
        proc = subprocess.run(["git", "grep", "-nE", pattern, "--", "servofmu/*.py", ":!servofmu/model/laws/*"],
                              cwd=ROOT, capture_output=True, text=True)
        hits += proc.stdout.splitlines()
    allowed = ("truth.friction.model == structure.friction.model", "target.law != plant.friction.model",
               "c.law in laws")
    assert [h for h in hits if not any(a in h for a in allowed)] == []
    # and the patterns do find what they are meant to find
    assert re.search(NAME_PATTERNS[0], 'if fr.model == "lugre":') and re.search(NAME_PATTERNS[1], "fr.model == x")


@pytest.mark.parametrize("friction, key, fragment", [
    ({"model": "sticky", "fc_pos": 1.0, "fc_neg": 1.0}, "friction.model", "must be one of"),
    ({"model": "coulomb", "fc_pos": 1.0, "fc_neg": 1.0, "sigma0": 1e4}, "friction.sigma0", "unknown key"),
    ({"model": "stribeck", "fc_pos": 1.0, "fc_neg": 1.0, "fs_pos": 2.0, "fs_neg": 2.0, "vs": 0.1, "delta": 0.0},
     "friction.delta", "must be positive"),
    ({"model": "lugre", "fc_pos": 1.0, "fc_neg": 1.0, "fs_pos": 2.0, "fs_neg": 2.0, "vs": 0.1, "sigma0": 1e4,
      "sigma1": 1.0, "delta": -1.0}, "friction.delta", "must not be negative"),
    ({"model": "coulomb", "fc_pos": 1.0, "fc_neg": 1.0, "fv_neg": 0.1}, "friction.fv_neg", "needs fv_pos"),
    ({"model": "coulomb", "fc_pos": 1.0, "fc_neg": 1.0, "fv_pos": 0.1}, "friction.fv_pos", "needs fv_neg"),
    ({"model": "coulomb", "fc_pos": 1.0, "fc_neg": 1.0, "fv": 0.1, "fv_pos": 0.1, "fv_neg": 0.2}, "friction.fv",
     "not both"),
    ({"model": "dahl", "fc_pos": 1.0, "fc_neg": 0.0, "sigma0": 1e4}, "friction.fc_neg", "positive Coulomb"),
])
def test_bad_friction_keys_are_refused_naming_the_key(friction, key, fragment):
    with pytest.raises(PlantError) as info:
        plant_from_dict({"name": "bad", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0}, "friction": friction},
                        source="bad.toml")
    message = str(info.value)
    assert message.startswith(f"bad.toml: {key}: ") and fragment in message and "\n" not in message


def test_the_registry_lists_the_shipped_laws_and_refuses_a_second_law_of_a_name():
    assert law_names()[:5] == ("coulomb", "stribeck", "lugre", "dahl", "gms")
    with pytest.raises(ValueError, match="registered already"):
        register(type("Other", (Saturating,), {"name": "stribeck"})())


def test_the_docs_name_every_key_of_every_shipped_law():
    """docs/plant-format.md's table and docs/friction.md's table hold every law and every key the registry has."""
    from servofmu.model.laws.registry import get_law

    table = (ROOT / "docs" / "plant-format.md").read_text()
    laws = (ROOT / "docs" / "friction.md").read_text()
    for name in ("coulomb", "stribeck", "lugre", "dahl", "gms"):
        assert f"`{name}`" in laws and f"`{name}`" in table.split("| `friction.model` |")[1].split("\n")[0]
        for key in get_law(name).all_keys():
            assert f"`friction.{key.name}`" in table, key.name
            assert f"`{key.name}`" in laws, key.name


@pytest.mark.parametrize("friction, fragment", [
    ('model = "maxwell"\nfc_pos = 1.0\nfc_neg = 1.0',
     "friction.model: must be one of coulomb, stribeck, lugre, dahl, gms"),
    ('model = "coulomb"\nfc_pos = 1.0\nfc_neg = 1.0\nfv_neg = 0.2', "friction.fv_neg: direction-dependent"),
])  # (the library refuses the other bad keys: test_bad_friction_keys_are_refused_naming_the_key)
def test_the_cli_refuses_a_bad_friction_in_one_line_and_writes_nothing(tmp_path, friction, fragment):
    from clitools import assert_one_line_error, run

    plant = tmp_path / "axis.toml"
    plant.write_text(f'name = "axis"\n[linear]\npoles = [[-10.0, 0.0]]\ndc_gain = 1.0\n[friction]\n{friction}\n')
    proc = run("build", plant, "-o", tmp_path / "axis.fmu")
    assert_one_line_error(proc, "servofmu build: error:", fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["axis.toml"]


def test_the_select_help_lists_the_registered_laws():
    from clitools import run

    proc = run("select", "--help")
    text = " ".join(proc.stdout.split())
    assert proc.returncode == 0 and "coulomb, stribeck, lugre, dahl" in text
    assert "default: the laws coulomb, stribeck, lugre at every order" in text
