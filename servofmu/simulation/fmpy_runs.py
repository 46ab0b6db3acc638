"""Run an FMU in FMPy: the servo FMUs of this package or any FMU with a real input and output."""
from __future__ import annotations

import csv
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError, check_optional_real, check_positive
from ..fileio import write_failures
from ..runtime import check_memory, temporary_folder

__all__ = ["FmuInfo", "read_fmu", "read_input_csv", "simulate", "format_csv", "hold_table", "replay_record", "EXCITATION"]

EXCITATION = ("excitation_amplitude", "excitation_frequency")


@dataclass(frozen=True)
class FmuInfo:
    """What a caller needs to know about an FMU before running it."""

    path: Path
    fmi_version: str
    model_name: str
    interfaces: tuple[str, ...]          # subset of ("me", "cs")
    variables: dict                      # name -> fmpy ScalarVariable
    default_tolerance: float | None
    default_step: float | None

    @property
    def has_builtin_excitation(self) -> bool:
        """Whether the FMU has servofmu's sine excitation (excitation_amplitude and excitation_frequency)."""
        return all(name in self.variables for name in EXCITATION)

    def outputs(self) -> list[str]:
        """The names of the FMU's output variables."""
        return [n for n, v in self.variables.items() if v.causality == "output"]

    def require(self, *names: str) -> None:
        """Raise a UserError naming the FMU and the first of ``names`` it has no variable of."""
        for name in names:
            if name not in self.variables:
                raise UserError(f"{self.path}: the FMU has no variable named {name!r} "
                                f"(it has {', '.join(sorted(self.variables)[:12])}...)")


def read_fmu(path: str | Path) -> FmuInfo:
    """The model description of the FMU at ``path`` (read with FMPy): FMI version, interfaces, variables; a
    UserError for a missing file or one that is not an FMU."""
    from fmpy import read_model_description

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such FMU file")
    if not zipfile.is_zipfile(path):
        raise UserError(f"{path}: not an FMU (not a zip archive)")
    try:
        md = read_model_description(str(path), validate=False)
    except Exception as exc:  # fmpy raises plain Exceptions for any malformed FMU
        raise UserError(f"{path}: not a readable FMU ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") \
            from exc
    interfaces = tuple(k for k, present in (("me", md.modelExchange), ("cs", md.coSimulation)) if present)
    exp = md.defaultExperiment
    return FmuInfo(path=path, fmi_version=md.fmiVersion, model_name=md.modelName, interfaces=interfaces,
                   variables={v.name: v for v in md.modelVariables},
                   default_tolerance=float(exp.tolerance) if exp and exp.tolerance else None,
                   default_step=float(exp.stepSize) if exp and exp.stepSize else None)


def read_input_csv(path: str | Path, input_name: str = "u") -> np.ndarray:
    """A CSV with a header row `time,<input>`: an FMPy input signal (time strictly increasing, finite)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such input file")
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        rows = list(reader)
    for col in ("time", input_name):
        if col not in header:
            raise UserError(f"{path}: missing column {col!r} (header is {','.join(header) or 'empty'})")
    it, iu = header.index("time"), header.index(input_name)
    try:
        data = np.array([(float(r[it]), float(r[iu])) for r in rows if r], dtype=float)
    except (ValueError, IndexError) as exc:
        raise UserError(f"{path}: a row is not numeric or is short") from exc
    if len(data) < 2:
        raise UserError(f"{path}: needs at least two rows")
    if not np.all(np.isfinite(data)):
        bad = int(np.argwhere(~np.isfinite(data))[0][0]) + 2
        raise UserError(f"{path}: line {bad}: NaN or Inf value")
    if np.any(np.diff(data[:, 0]) <= 0):
        bad = int(np.argmax(np.diff(data[:, 0]) <= 0)) + 3
        raise UserError(f"{path}: line {bad}: time is not strictly increasing")
    signal = np.zeros(len(data), dtype=[("time", float), (input_name, float)])
    signal["time"], signal[input_name] = data[:, 0], data[:, 1]
    return signal


def simulate(fmu: str | Path | FmuInfo, stop_time: float, interface: str = "me", amplitude: float | None = None,
             frequency: float | None = None, input_signal: np.ndarray | None = None, output_interval: float | None = None,
             relative_tolerance: float | None = None, outputs: list[str] | None = None,
             start_values: dict | None = None) -> np.ndarray:
    """Simulate an FMU in FMPy from 0 to ``stop_time``.

    Parameters
    ----------
    fmu : str, Path or FmuInfo
        Any FMU with Model Exchange or Co-Simulation.
    stop_time : float
        End of the simulation (s).
    interface : {"me", "cs"}
        Model Exchange (FMPy's solver) or Co-Simulation (the FMU's own).
    amplitude, frequency : float, optional
        The built-in sine excitation of servofmu FMUs (N, Hz).
    input_signal : ndarray, optional
        An FMPy input table (structured array with ``time`` and input names) for the input port.
    output_interval : float, optional
        Output interval (s); default: the FMU's step size, at most a hundredth of ``stop_time``.
    relative_tolerance : float, optional
        Solver tolerance; default: the FMU's.
    outputs : list of str, optional
        Variables to record; default: the outputs.
    start_values : dict, optional
        Start values by variable name.

    Returns
    -------
    ndarray
        FMPy's structured result: ``time`` and one field per recorded variable.

    Raises
    ------
    UserError
        For a file that is not an FMU, unknown variables, bad options or a failing simulation.
    """
    from ..api_checks import check_arguments

    check_arguments(simulate, locals())  # a wrong type: UserError naming it
    from fmpy import extract, simulate_fmu

    _check_arguments(fmu, stop_time, amplitude, frequency, input_signal, output_interval, relative_tolerance,
                     outputs, start_values)
    info = fmu if isinstance(fmu, FmuInfo) else read_fmu(fmu)
    if interface not in ("me", "cs"):
        raise UserError(f"interface must be me or cs, not {interface!r}")
    if interface not in info.interfaces:
        raise UserError(f"{info.path}: the FMU has no {'Model Exchange' if interface == 'me' else 'Co-Simulation'}"
                        " interface")
    if not stop_time > 0:
        raise UserError(f"stop_time must be positive, not {stop_time}")
    starts = dict(start_values or {})
    if amplitude is not None or frequency is not None:
        if not info.has_builtin_excitation:
            raise UserError(f"{info.path}: the FMU has no built-in excitation parameters; drive its input with an input signal")
        if amplitude is not None:
            starts["excitation_amplitude"] = float(amplitude)
        if frequency is not None:
            if not frequency > 0:
                raise UserError(f"frequency must be positive, not {frequency}")
            starts["excitation_frequency"] = float(frequency)
    info.require(*starts, *(outputs or []))
    if input_signal is not None:
        info.require(*[n for n in input_signal.dtype.names if n != "time"])
    interval = output_interval or min(info.default_step or 1e-3, stop_time / 100)
    if not interval > 0:
        raise UserError(f"output_interval must be positive, not {interval}")
    rows = stop_time / interval
    check_memory(f"{info.path}: {rows:.3g} output rows ({stop_time:g} s every {interval:g} s)",
                 rows * 8 * (2 + len(outputs or info.outputs())),
                 "give a longer output interval or a shorter stop time")
    # extracted into servofmu's own temporary folder: removed however the run ends (FMPy's is not, on SIGTERM)
    with temporary_folder("simulate") as folder:
        try:
            with write_failures(f"the extracted copy of {info.path} in {folder}"):
                unzipped = extract(str(info.path), unzipdir=str(folder))
            return simulate_fmu(unzipped, fmi_type="ModelExchange" if interface == "me" else "CoSimulation",
                                stop_time=stop_time, output_interval=interval, relative_tolerance=relative_tolerance,
                                start_values=starts, input=input_signal, output=outputs)
        except Exception as exc:  # a failing FMU: report it, not our stack
            raise UserError(f"{info.path}: simulation failed: "
                            f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from exc


def _check_arguments(fmu, stop_time, amplitude, frequency, input_signal, output_interval, relative_tolerance,
                     outputs, start_values) -> None:
    """:func:`simulate`'s arguments of a wrong type or value refused by name (FMPy would fail deep inside)."""
    if not isinstance(fmu, (str, Path, FmuInfo)):
        raise UserError(f"fmu must be a file name, a Path or an FmuInfo, not {type(fmu).__name__}")
    check_positive("stop_time", stop_time)
    check_optional_real("amplitude", amplitude)
    for name, value in (("frequency", frequency), ("output_interval", output_interval),
                        ("relative_tolerance", relative_tolerance)):
        if value is not None:
            check_positive(name, value)
    if input_signal is not None and not (isinstance(input_signal, np.ndarray) and input_signal.dtype.names
                                         and "time" in input_signal.dtype.names and input_signal.ndim == 1):
        raise UserError("input_signal must be an FMPy input table: a structured numpy array with a field time and "
                        "one per input (servofmu.simulation.fmpy_runs.read_input_csv, hold_table), not "
                        + (f"an array of shape {input_signal.shape}" if isinstance(input_signal, np.ndarray)
                           else type(input_signal).__name__))
    if outputs is not None and (isinstance(outputs, str) or not all(isinstance(n, str) for n in outputs)):
        raise UserError(f"outputs must be a list of variable names, not {outputs!r}")
    if start_values is not None and not (isinstance(start_values, dict) and all(isinstance(k, str) for k in start_values)):
        raise UserError(f"start_values must be a dict of variable name to value, not {type(start_values).__name__}")


def hold_table(time: np.ndarray, u: np.ndarray, hold: str, name: str = "u") -> np.ndarray:
    """An FMPy input table that applies the samples ``u`` with the record's hold: "foh" the samples themselves
    (FMPy interpolates linearly), "zoh" a staircase whose steps sit at the sample times (a time point given twice
    is a discontinuity to FMPy, which applies the value after it)."""
    time, u = np.asarray(time, dtype=float), np.asarray(u, dtype=float)
    if hold == "foh":
        t_in, u_in = time, u
    elif hold == "zoh":
        t_in = np.concatenate([[time[0]], np.repeat(time[1:], 2)])
        u_in = np.repeat(u, 2)[:-1]
    else:
        raise UserError(f"intersample behaviour must be zoh or foh, not {hold!r}")
    table = np.zeros(t_in.size, dtype=[("time", float), (name, float)])
    table["time"], table[name] = t_in, u_in
    return table


def replay_record(fmu: str | Path, time: np.ndarray, u: np.ndarray, hold: str = "zoh", start_values: dict | None = None,
                  relative_tolerance: float | None = None, outputs: tuple[str, ...] = ("v", "position")) -> np.ndarray:
    """Drive an FMU's input port ``u`` with a record's samples and hold; the outputs at the sample times.

    A held input runs in Co-Simulation, which keeps an input constant between communication points, with a
    communication point at every sample; a linear one in Model Exchange, where FMPy interpolates the table (at
    a relative tolerance of 1e-8 unless given: FMPy's CVODE fails at the 1e-10 of servofmu's FMUs on the smoothed
    Coulomb friction).  The record must be uniformly sampled (FMPy's output grid is regular).  Returns FMPy's
    structured result.
    """
    time = np.asarray(time, dtype=float)
    steps = np.diff(time)
    if time.size < 2 or np.ptp(steps) > 1e-6 * np.mean(steps):
        raise UserError("replaying a record through an FMU needs uniformly sampled time")
    interface = "cs" if hold == "zoh" else "me"
    if interface == "me" and relative_tolerance is None:
        relative_tolerance = 1e-8
    result = simulate(fmu, float(time[-1] - time[0]), interface=interface, input_signal=hold_table(time - time[0], u,
                      hold), output_interval=float(np.mean(steps)), relative_tolerance=relative_tolerance,
                      outputs=list(outputs), start_values=start_values)
    if result.size != time.size:
        raise UserError(f"{fmu}: the replay gave {result.size} samples for a record of {time.size}")
    return result


def format_csv(result: np.ndarray) -> str:
    """The result as CSV text with a header row of variable names."""
    names = result.dtype.names
    lines = [",".join(names)]
    lines += [",".join(repr(float(row[n])) for n in names) for row in result]
    return "\n".join(lines) + "\n"
