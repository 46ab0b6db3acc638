"""Importers other than FMPy run the built FMUs and agree with FMPy.

* fmuloader (ctypes FMI 2.0/3.0 loader): Model Exchange integrated by scipy's BDF, with the Jacobian from the FMU's
  directional derivatives, and Co-Simulation with doStep;
* libcosimpy (libcosim, the Open Simulation Platform's co-simulation engine): the FMI 2.0 Co-Simulation FMU.

Tolerances: v is O(0.1-5) m/s here.  Two different integrators of the Model Exchange equations (FMPy's CVode at
rtol 1e-12, scipy's BDF at rtol 1e-10/atol 1e-12, the FMU's own RODAS4 at its default 1e-10) agree to about 3e-7
in the worst case (g2 at 0.6 N, where the friction switches at every velocity reversal of the lightly damped
resonance), so they are compared at 1e-6 absolute.  Co-Simulation runs on the same 10 ms communication grid use the
same integrator inside the FMU: fmuloader, given FMPy's communication points, reproduces FMPy bit for bit; libcosim
counts time in nanoseconds and rounds the communication points differently (measured difference <= 1e-12).  Both
are compared at 1e-10.
"""
from __future__ import annotations

import functools

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from scipy.integrate import solve_ivp

STOP, DT = 2.0, 0.01
N_STEPS = int(round(STOP / DT))
CASES = [("g1", 0.6, 0.5), ("g1", 2.0, 5.0), ("g2", 0.6, 0.5), ("g2", 2.0, 5.0)]
TOL_INTEGRATORS = 1e-6
TOL_SAME_INTEGRATOR = 1e-10


def excitation_vrs(layout):
    return [layout.parameters["excitation_amplitude"], layout.parameters["excitation_frequency"]]


@pytest.fixture(scope="module")
def fmpy_v(built_fmu):
    """fmpy_v(name, version, amplitude, frequency, interface) -> v on the grid 0, DT, ..., STOP."""

    @functools.lru_cache(maxsize=None)
    def run(name, version, amplitude, frequency, interface):
        me = interface == "me"
        result = simulate_fmu(str(built_fmu(name, version)), fmi_type="ModelExchange" if me else "CoSimulation",
                              stop_time=STOP, output_interval=DT, relative_tolerance=1e-12 if me else None,
                              start_values={"excitation_amplitude": amplitude, "excitation_frequency": frequency},
                              output=["v"])
        assert np.allclose(result["time"], np.linspace(0.0, STOP, N_STEPS + 1))
        v = np.asarray(result["v"])
        assert np.abs(v).max() > 0.1  # the plant moves: the comparisons are not between zeros
        return v

    return run


# ---- fmuloader ------------------------------------------------------------------------------------------------
class LoaderInstance:
    """One fmuloader instance of FMI 2.0 or 3.0 behind the few calls the tests need."""

    def __init__(self, path, name, version, interface, messages):
        from fmuloader.fmi2 import Fmi2Slave, Fmi2Type
        from fmuloader.fmi3 import Fmi3Slave

        token = read_model_description(str(path)).guid

        def log3(env, status, category, message):
            messages.append((status, message.decode()))

        def log2(env, instance, status, category, message):
            messages.append((status, message.decode()))

        self.version = version
        if version == 3:
            self.fmu = Fmi3Slave(path, model_identifier=name)
            instantiate = self.fmu.instantiate_model_exchange if interface == "me" else \
                self.fmu.instantiate_co_simulation
            instantiate("plant", instantiation_token=token, log_message_callback=log3)
        else:
            self.fmu = Fmi2Slave(path, model_identifier=name)
            kind = Fmi2Type.MODEL_EXCHANGE if interface == "me" else Fmi2Type.CO_SIMULATION
            self.fmu.instantiate("plant", kind, guid=token, log_message_callback=log2)

    def get(self, vrs):
        return self.fmu.get_float64(vrs) if self.version == 3 else self.fmu.get_real(vrs)

    def set(self, vrs, values):
        return self.fmu.set_float64(vrs, values) if self.version == 3 else self.fmu.set_real(vrs, values)

    def initialize(self):
        if self.version == 3:
            self.fmu.enter_initialization_mode(start_time=0.0)
        else:
            self.fmu.setup_experiment(start_time=0.0)
            self.fmu.enter_initialization_mode()
        self.fmu.exit_initialization_mode()

    def enter_continuous_time_mode(self):
        if self.version == 3:
            assert not self.fmu.update_discrete_states().discrete_states_need_update
        else:
            assert not self.fmu.new_discrete_states().newDiscreteStatesNeeded
        self.fmu.enter_continuous_time_mode()

    def derivatives(self, nx):
        return self.fmu.get_continuous_state_derivatives(nx) if self.version == 3 else self.fmu.get_derivatives(nx)

    def close(self):
        self.fmu.terminate()
        self.fmu.free_instance()


def loader_model_exchange(path, name, version, layout, amplitude, frequency):
    """v on the grid 0, DT, ..., STOP: fmuloader's Model Exchange instance integrated by scipy's BDF."""
    fmu = LoaderInstance(path, name, version, "me", [])
    fmu.set(excitation_vrs(layout), [amplitude, frequency])
    fmu.initialize()
    fmu.enter_continuous_time_mode()
    nx = layout.nx
    x0 = fmu.fmu.get_continuous_states(nx)

    def at(t, x):
        fmu.fmu.set_time(float(t))
        fmu.fmu.set_continuous_states([float(xi) for xi in x])

    def rhs(t, x):
        at(t, x)
        return fmu.derivatives(nx)

    def jacobian(t, x):  # column k = d der(x) / d x_k, from the FMU's directional derivatives
        at(t, x)
        return np.array([fmu.fmu.get_directional_derivative(layout.derivatives, [k], [1.0])
                         for k in layout.states]).T

    t_eval = np.linspace(0.0, STOP, N_STEPS + 1)
    sol = solve_ivp(rhs, (0.0, STOP), x0, method="BDF", t_eval=t_eval, rtol=1e-10, atol=1e-12, jac=jacobian)
    assert sol.success, sol.message
    v = []
    for t, x in zip(sol.t, sol.y.T):
        at(t, x)
        v.append(fmu.get([layout.V])[0])
    fmu.close()
    return np.array(v)


@pytest.mark.parametrize("name, amplitude, frequency", CASES)
@pytest.mark.parametrize("version", [3, 2])
def test_fmuloader_model_exchange_with_scipy_bdf_agrees_with_fmpy(built_fmu, fmu_layout, fmpy_v, name, amplitude,
                                                                   frequency, version):
    v = loader_model_exchange(built_fmu(name, version), name, version, fmu_layout(name), amplitude, frequency)
    assert np.abs(v - fmpy_v(name, version, amplitude, frequency, "me")).max() < TOL_INTEGRATORS
    assert np.abs(v - fmpy_v(name, version, amplitude, frequency, "cs")).max() < TOL_INTEGRATORS


def loader_cosimulation(path, name, version, layout, amplitude, frequency):
    fmu = LoaderInstance(path, name, version, "cs", [])
    fmu.set(excitation_vrs(layout), [amplitude, frequency])
    fmu.initialize()  # FMI 3.0: leaving Initialization Mode enters Step Mode (no event mode requested)
    v = [fmu.get([layout.V])[0]]
    for k in range(N_STEPS):
        fmu.fmu.do_step(k * DT, (k + 1) * DT - k * DT)
        v.append(fmu.get([layout.V])[0])
    fmu.close()
    return np.array(v)


@pytest.mark.parametrize("name, amplitude, frequency", CASES)
@pytest.mark.parametrize("version", [3, 2])
def test_fmuloader_cosimulation_agrees_with_fmpy(built_fmu, fmu_layout, fmpy_v, name, amplitude, frequency, version):
    v = loader_cosimulation(built_fmu(name, version), name, version, fmu_layout(name), amplitude, frequency)
    assert np.abs(v - fmpy_v(name, version, amplitude, frequency, "cs")).max() < TOL_SAME_INTEGRATOR
    assert np.abs(v - fmpy_v(name, version, amplitude, frequency, "me")).max() < TOL_INTEGRATORS


@pytest.mark.parametrize("version", [3, 2])
def test_fmuloader_logger_names_the_bad_value_reference(built_fmu, version):
    from fmuloader.fmi2 import Fmi2Error
    from fmuloader.fmi3 import Fmi3Error

    messages = []
    fmu = LoaderInstance(built_fmu("g1", version), "g1", version, "cs", messages)
    for call, args in ((fmu.get, ([4321],)), (fmu.set, ([4322], [1.0]))):
        with pytest.raises(Fmi3Error if version == 3 else Fmi2Error):
            call(*args)
        vr = str(args[0][0])
        assert any(status == 3 and vr in text for status, text in messages), messages
    fmu.initialize()
    assert fmu.get([0, 1]) == [0.0, 0.0]  # the instance is still usable
    fmu.close()


# ---- libcosimpy -----------------------------------------------------------------------------------------------
def libcosim_cosimulation(path, layout, amplitude, frequency):
    """v on the grid 0, DT, ..., STOP from libcosim stepping the FMI 2.0 Co-Simulation FMU."""
    from libcosimpy._internal import get_last_error_message
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    # libcosim instantiates with debug logging on; keep the FMU's per-step solver messages out of the test log
    log_output_level(CosimLogLevel.WARNING)
    step_ns = int(round(DT * 1e9))  # libcosim counts time in nanoseconds
    execution = CosimExecution.from_step_size(step_ns)
    slave = CosimLocalSlave(fmu_path=str(path), instance_name="plant")
    index = execution.add_local_slave(slave)
    assert index >= 0, f"libcosim cannot load {path}: {get_last_error_message()}"
    names = {s.name.decode(): s.reference for s in execution.slave_variables(index)}
    assert names["v"] == layout.V and names["excitation_amplitude"] == layout.parameters["excitation_amplitude"]
    observer = CosimObserver.create_last_value()
    assert execution.add_observer(observer)
    for vr, value in zip(excitation_vrs(layout), (amplitude, frequency)):
        assert execution.real_initial_value(index, vr, value), get_last_error_message()
    v = []
    for k in range(N_STEPS):
        # a last-value observer, read after every step (libcosimpy 0.0.6's time-series reader drops the step-0 sample)
        assert execution.step(), get_last_error_message()
        (v_k,) = observer.last_real_values(index, [layout.V])
        assert execution.status().current_time == (k + 1) * step_ns
        v.append(v_k)
    return np.array(v)


@pytest.mark.parametrize("name, amplitude, frequency", CASES)
def test_libcosimpy_runs_fmi2_cosimulation_and_agrees_with_fmpy(built_fmu, fmu_layout, fmpy_v, name, amplitude,
                                                               frequency):
    v = libcosim_cosimulation(built_fmu(name, 2), fmu_layout(name), amplitude, frequency)
    assert np.abs(v - fmpy_v(name, 2, amplitude, frequency, "cs")[1:]).max() < TOL_SAME_INTEGRATOR
    assert np.abs(v - fmpy_v(name, 2, amplitude, frequency, "me")[1:]).max() < TOL_INTEGRATORS


def test_the_frequency_of_a_long_record_is_found_in_a_bounded_search():
    """A record longer than the search's samples (a 16 kHz log of minutes) is thinned for the search, at eight
    samples a period or more: its frequency still to far below its noise; an ordinary record is searched whole."""
    from servofmu.measurement.frf import SEARCH_SAMPLES, estimate_frequency

    rng = np.random.default_rng(1)
    for n, dt, f0 in [(4 * SEARCH_SAMPLES, 1 / 16000, 37.3), (3 * SEARCH_SAMPLES, 1e-3, 0.8), (20000, 1e-3, 3.1)]:
        t = np.arange(n) * dt
        u = 2.0 * np.sin(2 * np.pi * f0 * t + 0.4) + 0.05 * rng.normal(size=n)
        f, fraction = estimate_frequency(t, u)
        assert abs(f / f0 - 1) < 1e-5, (n, f, f0)
        assert fraction > 0.99
