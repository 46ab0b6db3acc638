"""The FMI 2.0 and 3.0 API of the built FMUs, called through FMPy's low-level classes
(fmpy.fmi3.FMU3Slave/FMU3Model, fmpy.fmi2.FMU2Slave/FMU2Model)."""
from __future__ import annotations

import functools
from ctypes import byref, c_double
from pathlib import Path

import numpy as np
import pytest
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Model,
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.logging import addLoggerProxy
from reference import gain_from_dc, simulate_reference

FMI_ERROR = 3
DT, STOP = 0.01, 1.5


class Instance:
    """One FMPy low-level instance (FMI 2.0 or 3.0, "me" or "cs") of a servofmu FMU; the importer's logger
    callback appends (status, message) to ``messages``."""

    def __init__(self, path, version, interface, token=None, messages=None):
        md = read_model_description(str(path))
        self.version, self.interface = version, interface
        self.messages = [] if messages is None else messages
        self.nx = len(md.derivatives)
        args = dict(guid=md.guid if token is None else token, unzipDirectory=_unzipped(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
        if version == 3:
            self.fmu = (FMU3Model if interface == "me" else FMU3Slave)(**args)
            self.fmu.instantiate(logMessage=self._log3)
        else:
            self.fmu = (FMU2Model if interface == "me" else FMU2Slave)(**args)
            self.callbacks = fmi2CallbackFunctions()
            self.callbacks.logger = fmi2CallbackLoggerTYPE(self._log2)
            self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            addLoggerProxy(byref(self.callbacks))  # formats the variadic message before Python sees it
            self.fmu.instantiate(callbacks=self.callbacks)

    def _log3(self, env, status, category, message):
        self.messages.append((status, message.decode()))

    def _log2(self, env, instance, status, category, message):
        self.messages.append((status, message.decode()))

    def get(self, vrs):
        return self.fmu.getFloat64(vrs) if self.version == 3 else self.fmu.getReal(vrs)

    def set(self, vrs, values):
        (self.fmu.setFloat64 if self.version == 3 else self.fmu.setReal)(vrs, values)

    def initialize(self, tolerance=None):
        if self.version == 3:
            self.fmu.enterInitializationMode(tolerance=tolerance, startTime=0.0)
        else:
            self.fmu.setupExperiment(tolerance=tolerance, startTime=0.0)
            self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        if self.interface == "me":
            if self.version == 3:
                self.fmu.updateDiscreteStates()
            else:
                self.fmu.newDiscreteStates()
            self.fmu.enterContinuousTimeMode()

    # Model Exchange
    def set_states(self, x):
        self.fmu.setContinuousStates((c_double * self.nx)(*x), self.nx)

    def states(self):
        x = (c_double * self.nx)()
        self.fmu.getContinuousStates(x, self.nx)
        return np.array(x)

    def derivatives(self):
        dx = (c_double * self.nx)()
        (self.fmu.getContinuousStateDerivatives if self.version == 3 else self.fmu.getDerivatives)(dx, self.nx)
        return np.array(dx)

    def directional(self, unknowns, knowns, seed):
        return np.array(self.fmu.getDirectionalDerivative(unknowns, knowns, seed))

    # Co-Simulation
    def run(self, t0, t1, vrs):
        """doStep from t0 to t1 in steps of DT; the values of ``vrs`` after every step."""
        out = []
        n0, n1 = int(round(t0 / DT)), int(round(t1 / DT))
        for k in range(n0, n1):
            self.fmu.doStep(k * DT, (k + 1) * DT - k * DT)
            out.append(self.get(vrs))
        return np.array(out)

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()


@functools.lru_cache(maxsize=None)
def _unzipped(path):
    """Extracted once, next to the FMU (in pytest's temporary directory)."""
    return extract(path, unzipdir=str(Path(path).with_suffix("")) + "_unzipped")


# ---- parameters through the API ----------------------------------------------------------------------------------
COULOMB = {"model": "coulomb", "fc_neg": 0.4}
CHANGES = {  # plant -> (new parameter values, poles before, poles after)
    "g1": ({"pole1": -6.0, "fc_pos": 0.3}, [-10.0], [-6.0]),
    "g2": ({"pole1_re": -4.0, "pole1_im": 20.0, "pole2": -15.0, "fc_pos": 0.3},
           [-2.5 + 31.52j, -2.5 - 31.52j, -10.0], [-4.0 + 20.0j, -4.0 - 20.0j, -15.0]),
}
EXCITATION = {"excitation_amplitude": 0.9, "excitation_frequency": 1.0}


@functools.lru_cache(maxsize=None)
def reference_v(poles, fc_pos):
    """tests/reference.py (scipy Radau on the equations, DC gain 1) on the grid DT, 2 DT, ..., STOP."""
    t = np.linspace(0.0, STOP, int(round(STOP / DT)) + 1)
    v = simulate_reference(list(poles), [], gain_from_dc(list(poles), [], 1.0), {**COULOMB, "fc_pos": fc_pos},
                           EXCITATION["excitation_amplitude"], EXCITATION["excitation_frequency"], t)
    return v[1:]


@pytest.mark.parametrize("name", ["g1", "g2"])
@pytest.mark.parametrize("version", [3, 2])
def test_parameters_set_through_the_api_change_the_response_as_the_reference_predicts(built_fmu, fmu_layout, name,
                                                                                       version):
    layout = fmu_layout(name)
    new, poles_before, poles_after = CHANGES[name]
    fmu = Instance(built_fmu(name, version), version, "cs")
    values = {**new, **EXCITATION}
    fmu.set([layout.parameters[p] for p in values], list(values.values()))
    assert fmu.get([layout.parameters[p] for p in values]) == list(values.values())
    fmu.initialize()
    v = fmu.run(0.0, STOP, [layout.V])[:, 0]
    fmu.close()
    expected = reference_v(tuple(poles_after), new["fc_pos"])
    before = reference_v(tuple(poles_before), 0.5)
    assert np.abs(v - expected).max() < 1e-6
    assert np.abs(v - before).max() > 1e-2  # the change matters: the test tells the two parameter sets apart


# ---- errors ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("interface", ["cs", "me"])
@pytest.mark.parametrize("version", [3, 2])
def test_unknown_value_references_are_errors_named_in_the_log(built_fmu, fmu_layout, version, interface):
    layout = fmu_layout("g2")
    fmu = Instance(built_fmu("g2", version), version, interface)
    unknown = [999, 5000, 1000 + len(layout.parameters), 2000 + layout.nx, 3000 + layout.nx]
    for vr in unknown:
        for call, args in ((fmu.get, ([vr],)), (fmu.set, ([vr], [1.0]))):
            fmu.messages.clear()
            with pytest.raises(FMICallException) as info:
                call(*args)
            assert info.value.status == FMI_ERROR
            assert any(status == FMI_ERROR and str(vr) in text for status, text in fmu.messages), fmu.messages
    # known but not settable: an output
    with pytest.raises(FMICallException):
        fmu.set([layout.V], [1.0])
    # the instance survives and still works
    fmu.initialize()
    assert fmu.get([layout.TIME, layout.U, layout.POSITION]) == [0.0, 0.0, 0.0]
    if interface == "cs":
        assert np.all(np.isfinite(fmu.run(0.0, 0.05, [layout.V])))
    fmu.close()


@pytest.mark.parametrize("interface", ["cs", "me"])
@pytest.mark.parametrize("version", [3, 2])
def test_a_wrong_instantiation_token_fails_instantiation_and_says_why(built_fmu, version, interface):
    path = built_fmu("g1", version)
    messages = []
    with pytest.raises(Exception, match="(?i)failed to instantiate"):  # FMPy's reaction to a NULL instance
        Instance(path, version, interface, token="{00000000-0000-0000-0000-000000000000}", messages=messages)
    token = read_model_description(str(path)).guid
    assert any(status == FMI_ERROR and token in text for status, text in messages), messages
    fmu = Instance(path, version, interface)  # the right token works
    fmu.close()


# ---- FMU state -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", [3, 2])
def test_fmu_state_restores_the_trajectory_and_survives_serialization(built_fmu, fmu_layout, version):
    layout = fmu_layout("g2")
    outputs = [layout.TIME, layout.V, layout.POSITION, layout.FRICTION_FORCE]
    path = built_fmu("g2", version)
    fmu = Instance(path, version, "cs")
    fmu.set([layout.parameters["excitation_amplitude"], layout.parameters["excitation_frequency"]], [2.0, 5.0])
    fmu.initialize()
    fmu.run(0.0, 0.3, outputs)
    state = fmu.fmu.getFMUState()
    first = fmu.run(0.3, 0.6, outputs)
    fmu.fmu.setFMUState(state)
    assert fmu.get([layout.TIME]) == [pytest.approx(0.3, abs=1e-15)]
    second = fmu.run(0.3, 0.6, outputs)
    assert np.array_equal(first, second)
    assert np.abs(first[:, 1]).max() > 0.1 and first[-1, 0] == pytest.approx(0.6)

    # serialize, then restore into a fresh instance (with other parameters, which the state overrides)
    data = fmu.fmu.serializeFMUState(state)
    fmu.fmu.freeFMUState(state)
    fmu.close()
    other = Instance(path, version, "cs")
    other.initialize()
    other.run(0.0, 0.1, outputs)
    restored = other.fmu.deserializeFMUState(data)
    other.fmu.setFMUState(restored)
    assert np.array_equal(other.run(0.3, 0.6, outputs), first)
    with pytest.raises(FMICallException):
        other.fmu.deserializeFMUState(b"\x00" * len(data))  # not a state of this FMU
    with pytest.raises(FMICallException):
        other.fmu.deserializeFMUState(data[:-1])
    other.fmu.freeFMUState(restored)
    other.close()


@pytest.mark.parametrize("version", [3, 2])
def test_fmu_state_in_model_exchange_restores_time_and_states(built_fmu, fmu_layout, version):
    fmu = Instance(built_fmu("lugre_servo", version), version, "me")
    fmu.initialize()
    fmu.fmu.setTime(0.25)
    x = np.array([0.02, 0.001, 1e-4])
    fmu.set_states(x)
    dx = fmu.derivatives()
    state = fmu.fmu.getFMUState()
    fmu.fmu.setTime(0.75)
    fmu.set_states(-x)
    assert not np.array_equal(fmu.derivatives(), dx)
    fmu.fmu.setFMUState(state)
    assert np.array_equal(fmu.states(), x) and np.array_equal(fmu.derivatives(), dx)
    assert fmu.get([0]) == [0.25]
    fmu.fmu.freeFMUState(state)
    fmu.close()


# ---- derivatives -----------------------------------------------------------------------------------------------
POINTS = {  # plant -> (time, u, states): a point of the state space where every friction term is active
    "g1": (0.3, 0.1, [4e-4, 0.01]),                      # v / v_smooth = 0.4: inside the tanh smoothing
    "g2": (0.3, 0.1, [0.05, -0.02, 0.01, 0.02]),
    "stribeck_servo": (0.3, 0.1, [0.04, 0.01, 0.02]),    # v / vs = 0.8: on the Stribeck curve
    "lugre_servo": (0.3, 0.1, [0.04, 0.01, 2e-4]),       # bristle deflection near g/sigma0
}


def finite_difference_jacobian(fmu, layout, x, u):
    """Central differences of [der(x); v, position, friction_force] w.r.t. [x; u], read through the API."""
    outputs = [layout.V, layout.POSITION, layout.FRICTION_FORCE]

    def f(xk, uk):
        fmu.set_states(xk)
        fmu.set([layout.U], [uk])
        return np.concatenate([fmu.derivatives(), fmu.get(outputs)])

    columns = []
    for k in range(layout.nx + 1):
        h = 1e-8 if k < layout.nx else 1e-6  # v varies on the scale of v_smooth = 1e-3 near zero
        dx = np.zeros(layout.nx)
        du = 0.0
        if k < layout.nx:
            dx[k] = h
        else:
            du = h
        columns.append((f(x + dx, u + du) - f(x - dx, u - du)) / (2 * h))
    f(x, u)
    return np.array(columns).T


@pytest.mark.parametrize("name", list(POINTS))
@pytest.mark.parametrize("version", [3, 2])
def test_directional_derivatives_match_finite_differences(built_fmu, fmu_layout, name, version):
    layout = fmu_layout(name)
    t, u, x = POINTS[name]
    x = np.array(x)
    fmu = Instance(built_fmu(name, version), version, "me")
    fmu.set([layout.parameters["excitation_amplitude"]], [0.7])
    fmu.initialize()
    fmu.fmu.setTime(t)
    unknowns = layout.derivatives + [layout.V, layout.POSITION, layout.FRICTION_FORCE]
    knowns = layout.states + [layout.U]
    fd = finite_difference_jacobian(fmu, layout, x, u)
    fmu.set_states(x)
    fmu.set([layout.U], [u])
    jac = np.array([fmu.directional(unknowns, [k], [1.0]) for k in knowns]).T
    scale = np.abs(jac).max()
    assert np.abs(jac - fd).max() <= 1e-6 * scale, np.abs(jac - fd).max() / scale
    assert np.abs(jac[:layout.nx, 0]).max() > 1.0  # d der(x)/d v includes the friction slope: not all zeros

    # one call with a full seed is the Jacobian-vector product
    seed = np.linspace(-1.0, 1.0, len(knowns))
    assert np.allclose(fmu.directional(unknowns, knowns, list(seed)), jac @ seed, rtol=1e-12, atol=1e-12 * scale)

    if version == 3:  # the adjoint is the transposed product
        weights = np.linspace(0.5, -1.5, len(unknowns))
        adjoint = np.array(fmu.fmu.getAdjointDerivative(unknowns, knowns, list(weights), len(knowns)))
        assert np.allclose(adjoint, jac.T @ weights, rtol=1e-12, atol=1e-12 * scale)

    # time and parameters are not knowns the FMU differentiates by: an error, not a wrong number
    with pytest.raises(FMICallException):
        fmu.directional(unknowns, [layout.TIME], [1.0])
    fmu.close()


# ---- time ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", [3, 2])
def test_time_reads_back_the_current_time(built_fmu, fmu_layout, version):
    layout = fmu_layout("g1")
    cs = Instance(built_fmu("g1", version), version, "cs")
    cs.initialize()
    times = cs.run(0.0, 0.37, [layout.TIME])[:, 0]
    assert times == pytest.approx(DT * np.arange(1, 38), abs=1e-14)
    cs.close()
    me = Instance(built_fmu("g1", version), version, "me")
    me.initialize()
    me.fmu.setTime(0.123)
    assert me.get([layout.TIME]) == [0.123]
    me.close()


# ---- values the plant file refuses ------------------------------------------------------------------------------
@pytest.mark.parametrize("interface", ["cs", "me"])
@pytest.mark.parametrize("version", [3, 2])
@pytest.mark.parametrize("name, value", [("fv", -5.0), ("v_smooth", 0.0), ("fc_pos", -0.1), ("vs", -1.0),
                                         ("pole1", 1.0), ("dc_gain", 0.0), ("excitation_frequency", 1e9),
                                         ("excitation_frequency", 0.0)])
def test_values_the_plant_file_refuses_are_refused_through_the_api(built_fmu, fmu_layout, version, interface, name,
                                                                    value):
    """As a NaN is: an error status and a log line naming the variable, the instance unchanged and usable."""
    layout = fmu_layout("stribeck_servo")
    fmu = Instance(built_fmu("stribeck_servo", version), version, interface)
    vr = layout.parameters[name]
    before = fmu.get([vr])
    with pytest.raises(FMICallException) as info:
        fmu.set([vr], [value])
    assert info.value.status == FMI_ERROR
    assert any(status == FMI_ERROR and str(vr) in text for status, text in fmu.messages), fmu.messages
    assert fmu.get([vr]) == before
    fmu.initialize()
    if interface == "cs":
        assert np.all(np.isfinite(fmu.run(0.0, 0.05, [layout.V])))
    fmu.close()


@pytest.mark.parametrize("interface", ["cs", "me"])
@pytest.mark.parametrize("version", [3, 2])
def test_static_friction_below_coulomb_friction_ends_initialisation_with_an_error(built_fmu, fmu_layout, version,
                                                                                   interface):
    layout = fmu_layout("stribeck_servo")
    fmu = Instance(built_fmu("stribeck_servo", version), version, interface)
    fmu.set([layout.parameters["fs_pos"]], [0.2])  # below fc_pos = 0.3: each value alone is fine
    with pytest.raises(FMICallException):
        fmu.initialize()
    assert any(status == FMI_ERROR and "static friction" in text for status, text in fmu.messages), fmu.messages
