"""Co-simulation of an axis (an SSP archive of servofmu.control.system) on an existing engine, and its log as a
records file.

Engines: libcosim (through libcosimpy, ``CosimExecution.from_ssp_file``) and FMPy (``fmpy.ssp.simulation.
simulate_ssp``).  Both step every FMU with the controller's sample time and pass the outputs of a step to the
inputs of the next (a Jacobi scheme): the force computed from the measurement at t_k reaches the plant at t_k+1,
which is the drive's one-sample computation delay.  Both start with every connection at 0 (a reference that
starts at 0); they agree to rounding.

The records file holds one record per run, sampled at the communication points t_0 … t_N−1: ``time``; ``u`` the
force command applied from t_k on (zero-order hold, as the drive logs it: the total, with a disturbance);
``position`` the encoder reading the controller used at t_k; ``v`` the plant's velocity; ``reference`` the
reference position; with a disturbance source, ``disturbance`` the force it added from t_k on — the record of a
drive's log with an injected test signal (servofmu import --disturbance).
"""
from __future__ import annotations

import importlib.util
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..errors import ServofmuWarning, UserError
from ..fileio import claim_output, file_sha256, output_mode
from ..measurement.datafile import DataFile, Record, Series, read_data_file, write_records
from ..runtime import Progress, RunOptions, temporary_folder, utc_now
from ..version import __version__
from .system import DISTURBANCE, read_system

__all__ = ["ENGINES", "CosimResult", "cosimulate", "write_cosim_records"]

MAX_STEPS = 10_000_000  # communication steps of one run: about 3 h on libcosim at the demo axis's pace
PROGRESS_EVERY = 1000  # libcosim steps between progress reports (a report costs a bar's refresh)
ENGINES = ("libcosim", "fmpy")
# (component, variable): what is recorded
SIGNALS = {"reference": ("reference", "position_reference"), "force": ("controller", "force"),
           "force_command": ("controller", "force_command"), "position_measured": ("controller", "position_measured"),
           "position": ("plant", "position"), "v": ("plant", "v")}
# recorded when the system has a disturbance source: what it outputs at t_k the controller applies from t_k+1 on
DISTURBANCE_SIGNAL = {"disturbance": (DISTURBANCE, "force_disturbance")}


def _signals(components) -> dict:
    """What is recorded of a system with these components."""
    return {**SIGNALS, **(DISTURBANCE_SIGNAL if DISTURBANCE in components else {})}


@dataclass(frozen=True)
class CosimResult:
    """Every signal of SIGNALS (and DISTURBANCE_SIGNAL with a disturbance source) at the communication points
    (arrays of one length, ``time`` first), and the system's components."""

    engine: str
    time: np.ndarray
    signals: dict
    components: tuple = ("reference", "controller", "plant")

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]


def _steps(stop_time: float, step: float) -> int:
    if not stop_time / step <= MAX_STEPS:  # (also a stop time that is not a number)
        raise UserError(f"the stop time {stop_time:g} s is {stop_time / step:.3g} communication steps of {step:g} s, "
                        f"more than the {MAX_STEPS:.0e} a run may take (hours on either engine)")
    n = int(round(stop_time / step))
    if n < 2 or abs(n * step - stop_time) > 1e-9 * stop_time:
        raise UserError(f"the stop time {stop_time:g} s is not a whole number (≥ 2) of communication steps of "
                        f"{step:g} s")
    return n


def _run_libcosim(folder: Path, ssp: Path, n: int, step: float, signals: dict, progress=None) -> dict:
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)  # libcosim logs every FMU load at debug level on stderr otherwise

    try:
        execution = CosimExecution.from_ssp_file(str(ssp), step_size=int(round(step * 1e9)))
    except AssertionError as exc:
        raise UserError(f"{ssp}: libcosim cannot load the system") from exc
    index = {info.name.decode(): info.index for info in execution.slave_infos()}
    refs = {}
    for name, (component, variable) in signals.items():
        variables = {v.name.decode(): v.reference for v in execution.slave_variables(index[component])}
        refs[name] = (index[component], variables[variable])
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    out = {name: np.zeros(n + 1) for name in signals}
    for k in range(1, n + 1):
        if not execution.step():
            raise UserError(f"{ssp}: libcosim failed at step {k} (t = {k * step:g} s)")
        for name, (slave, vr) in refs.items():
            out[name][k] = observer.last_real_values(slave, [vr])[0]
        if progress is not None and (k % PROGRESS_EVERY == 0 or k == n):
            progress(k, n)
    return out


def _run_fmpy(folder: Path, ssp: Path, n: int, step: float, parameters: dict, signals: dict) -> dict:
    from fmpy.ssp.simulation import simulate_ssp

    # FMPy applies one parameter set, named by component path, to the components it instantiates
    parameter_set = SimpleNamespace(parameters=[SimpleNamespace(name=f"controller.{k}", value=v)
                                                for k, v in parameters.items()])
    # FMPy extracts the archive and each FMU into folders of tempfile's and removes them only when the run ends
    # normally: made inside this run's own temporary folder instead, they go with it however the run ends
    tempdir, tempfile.tempdir = tempfile.tempdir, str(folder)
    try:
        result = simulate_ssp(str(ssp), start_time=0.0, stop_time=n * step - step / 2, step_size=step,
                              parameter_set=parameter_set)
    finally:
        tempfile.tempdir = tempdir
    out = {name: np.zeros(n + 1) for name in signals}
    for name, (component, variable) in signals.items():
        # FMPy labels a row with the start of the step whose outputs it holds
        out[name][1:] = np.asarray(result[f"{component}.{variable}"])[:n]
    return out


def cosimulate(ssp: str | Path, stop_time: float | None = None, engine: str = "libcosim",
               progress: Progress | None = None) -> CosimResult:
    """Run an axis archive on a co-simulation engine.

    Parameters
    ----------
    ssp : str or Path
        An archive written by :func:`servofmu.control.system.write_system` (``servofmu system``).
    stop_time : float, optional
        Seconds to simulate (default: the system's default experiment, the reference's duration).
    engine : {"libcosim", "fmpy"}
        libcosim through libcosimpy, or FMPy's SSP runner.  Where libcosimpy is not installed (it has wheels for
        Linux x86_64 and Windows only), "libcosim" runs on FMPy with a ServofmuWarning; ``CosimResult.engine``
        names the engine that ran.
    progress : Progress, optional
        Called with (steps done, steps): every PROGRESS_EVERY steps on libcosim, at the end on FMPy.

    Returns
    -------
    CosimResult
        Every recorded signal at the communication points 0, Ts, …, stop_time.

    Raises
    ------
    UserError
        For an unknown engine, a damaged archive, a stop time that is no whole number of steps, a failing FMU.
    """
    if engine not in ENGINES:
        raise UserError(f"engine must be one of {', '.join(ENGINES)}, not {engine!r}")
    if engine == "libcosim" and importlib.util.find_spec("libcosimpy") is None:
        warnings.warn("libcosimpy is not installed (its wheels are for Linux x86_64 and Windows): co-simulating on "
                      "FMPy instead", ServofmuWarning, stacklevel=2)
        engine = "fmpy"
    ssp = Path(ssp)
    with temporary_folder("cosim") as tmp:
        system = read_system(ssp, tmp)
        stop = system.stop_time if stop_time is None else float(stop_time)
        n = _steps(stop, system.step_size)
        try:
            signals = _signals(system.components)
            if progress is not None:
                progress(0, n)
            if engine == "libcosim":
                out = _run_libcosim(Path(tmp), ssp, n, system.step_size, signals, progress)
            else:  # FMPy's runner has no hook: done when it returns
                out = _run_fmpy(Path(tmp), ssp, n, system.step_size, system.controller, signals)
                if progress is not None:
                    progress(n, n)
        except UserError:
            raise
        except Exception as exc:  # an engine's own error: the first line names it
            raise UserError(f"{ssp}: {engine} failed: {(str(exc).splitlines() or [type(exc).__name__])[0]}") \
                from exc
    return CosimResult(engine=engine, time=np.arange(n + 1) * system.step_size, signals=out,
                       components=system.components)


def write_cosim_records(result: CosimResult, ssp: str | Path, output: str | Path, append: bool = False,
                        run: RunOptions | None = None) -> DataFile:
    """The run as a records file: one record (see the module docstring), the input held between samples; an
    existing ``output`` is appended to (``append``), replaced (``run.overwrite``) or refused; ``run.command`` is
    recorded as provenance."""
    run = run or RunOptions()
    output = claim_output(output, output_mode(run.overwrite, append), inputs=(ssp,), can_continue="append")
    t = result.time[:-1]
    disturbance = None
    columns = {"time": "communication points", "u": "controller.force_command",
               "position": "controller.position_measured", "v": "plant.v", "reference": "reference.position_reference"}
    if "disturbance" in result.signals:
        # the source's output at t_k-1 is what the controller applies from t_k on; nothing before t_1
        disturbance = np.concatenate([[0.0], result["disturbance"][:-2]])
        columns["disturbance"] = "disturbance.force_disturbance (one sample later)"
    series = Series(time=t, u=result["force_command"][:-1], v=result["v"][:-1],
                    position=result["position_measured"][1:], reference=result["reference"][:-1],
                    disturbance=disturbance)
    existing = len(read_data_file(output).records) if append and output.exists() else 0
    record = Record(index=existing, name=f"{Path(ssp).stem}-{result.engine}-{existing}", source=Path(ssp).name,
                    source_sha256=file_sha256(ssp), kind="position", columns=columns, series=series, sample_rate=1.0 / float(t[1] - t[0]),
                    velocity_estimate="the plant FMU's output v", velocity_cutoff=None, analysis=None,
                    note=f"co-simulated on {result.engine}", intersample="zoh")
    provenance = {"package": "servofmu", "package_version": __version__, "command": run.command,
                  "created": utc_now(),
                  "sources": [Path(ssp).name], "engine": result.engine, "components": list(result.components)}
    write_records(output, [record], provenance, append=append, overwrite=run.overwrite)
    return read_data_file(output)
