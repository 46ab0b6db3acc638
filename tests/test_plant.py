"""Plant files: the paper's plants read correctly, every malformed file is refused naming file and key."""
import tomllib

import numpy as np
import pytest

from servofmu.model.plant import PlantError, load_plant, plant_from_dict
from servofmu.model.symbolic import build_model

G1 = {"name": "p", "linear": {"poles": [[-10.0, 0.0]], "zeros": [], "dc_gain": 1.0},
      "friction": {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}}


def with_changes(section, **changes):
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in G1.items()}
    if section:
        data[section].update(changes)
    else:
        data.update(changes)
    return data


def test_g1_and_g2_are_the_papers_plants():
    g1, g2 = load_plant("g1"), load_plant("g2")
    num, den = g1.transfer_function()
    assert np.allclose(num, [10.0]) and np.allclose(den, [1.0, 10.0])  # G1 = 10/(s+10)
    num, den = g2.transfer_function()
    # (s+10)(s^2+5s+1000.5504) with DC gain 1
    assert np.allclose(den, [1.0, 15.0, 50 + 2.5**2 + 31.52**2, 10 * (2.5**2 + 31.52**2)])
    assert np.isclose(num[-1] / den[-1], 1.0)
    assert g2.parameter_names()[:3] == ["pole1_re", "pole1_im", "pole2"]
    assert g1.friction.fc_pos == 0.5 and g1.friction.fc_neg == 0.4


def test_parameter_vector_round_trip():
    g2 = load_plant("g2")
    vec = g2.parameter_vector() * 1.1
    again = g2.with_parameters(vec)
    assert np.allclose(again.parameter_vector(), vec)
    assert again.poles[0] == complex(-2.75, 31.52 * 1.1)


def test_toml_round_trip(tmp_path):
    for name in ("g1", "g2", "stribeck_servo", "lugre_servo"):
        plant = load_plant(name)
        path = tmp_path / f"{name}.toml"
        path.write_text(plant.to_toml())
        assert load_plant(path) == plant


def test_model_realises_g_exactly():
    """The linearised CasADi model without friction has G(s)'s frequency response."""
    import casadi as ca

    for name in ("g1", "g2", "stribeck_servo"):
        plant = load_plant(name)
        model = build_model(plant)
        p = model.parameter_start()
        for key in ("fc_pos", "fc_neg", "fs_pos", "fs_neg", "fv"):
            if key in model.parameter_names:
                p[model.parameter_names.index(key)] = 0.0
        jac = ca.Function("j", [model.x, model.u, model.p],
                          [ca.jacobian(model.xdot, model.x), ca.jacobian(model.xdot, model.u)])
        a, b = (np.array(m) for m in jac(np.zeros(model.nx), 0.0, p))
        n = plant.order
        w = np.array([0.3, 3.0, 31.0, 300.0])
        h = [np.linalg.solve(1j * wi * np.eye(n) - a[:n, :n], b[:n, 0])[0] for wi in w]
        assert np.allclose(h, plant.frequency_response(w), rtol=1e-12, atol=0)


@pytest.mark.parametrize("data, key", [
    (with_changes("linear", extra=1), "linear.extra"),
    (with_changes(None, color="red"), "color"),
    (with_changes("friction", mu=0.1), "friction.mu"),
    (with_changes("linear", poles=[[-2.0, 3.0]]), "linear.poles"),            # missing conjugate
    (with_changes("linear", poles=[[1.0, 0.0]]), "linear.poles"),             # unstable
    (with_changes("linear", zeros=[[-1.0, 0.0]]), "linear.zeros"),            # not strictly proper
    (with_changes("friction", fc_pos=-0.5), "friction.fc_pos"),               # negative friction
    (with_changes("friction", model="stribeck", fs_pos=0.3, fs_neg=0.5, vs=0.1), "friction.fs_pos"),  # fs < fc
    (with_changes("friction", model="viscous"), "friction.model"),
    (with_changes("linear", gain=10.0), "linear.dc_gain"),                    # both gains
    (with_changes("linear", poles=[[0.0, 0.0]]), "linear.dc_gain"),           # pole at 0 needs gain
    (with_changes("friction", model="lugre", fs_pos=0.6, fs_neg=0.5, vs=0.1), "friction.sigma0"),
    (with_changes("linear", poles="oops"), "linear.poles"),
    (with_changes("friction", fc_neg="big"), "friction.fc_neg"),
    (with_changes("friction", symmetric="yes"), "friction.symmetric"),
    (with_changes("friction", symmetric=True), "friction.fc_neg"),           # 0.4, not fc_pos's 0.5
    (with_changes(None, fixed="offset"), "fixed"),
    (with_changes(None, fixed=["offset"]), "fixed"),                          # g1 has no offset
    (with_changes(None, fixed=["fc_pos", "fc_pos"]), "fixed"),
])
def test_bad_plant_names_file_and_key(data, key):
    with pytest.raises(PlantError) as err:
        plant_from_dict(data, source="bad.toml")
    message = str(err.value)
    assert message.startswith(f"bad.toml: {key}:"), message
    assert "\n" not in message


def test_a_symmetric_friction_and_fixed_parameters_read_back_and_hold():
    """`symmetric = true` fills the levels for v < 0 from those for v > 0 and keeps them equal in any parameter
    vector; `fixed` names parameters; both survive the plant file's round trip."""
    data = with_changes("friction", model="stribeck", symmetric=True, fs_pos=0.7, vs=0.1)
    del data["friction"]["fc_neg"]
    data["fixed"] = ["fs_pos"]
    plant = plant_from_dict(data)
    p = plant.parameters()
    assert (p["fc_neg"], p["fs_neg"]) == (p["fc_pos"], p["fs_pos"]) == (0.5, 0.7) and plant.fixed == ("fs_pos",)
    assert plant_from_dict(tomllib.loads(plant.to_toml())) == plant
    names = plant.parameter_names()
    vector = plant.parameter_vector()
    vector[names.index("fc_pos")], vector[names.index("fc_neg")] = 0.9, 0.1
    moved = plant.with_parameters(vector).parameters()
    assert moved["fc_pos"] == moved["fc_neg"] == 0.9


def test_not_toml(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("name = [unclosed\n")
    with pytest.raises(PlantError, match="broken.toml: not a valid TOML file"):
        load_plant(path)
