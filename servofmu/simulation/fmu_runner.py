"""One FMU in a worker process: extracted and instantiated once, reset between runs, driven step by step
through FMPy (FMI 2.0 and 3.0 Co-Simulation).  What measure, records and co-simulation runs share."""
from __future__ import annotations

import weakref
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

from ..errors import UserError
from ..fileio import write_failures
from ..runtime import make_temporary_folder, remove_temporary_folders
from .fmpy_runs import EXCITATION

__all__ = ["FmuError", "FmuRunner", "FmuRunnerFactory"]


class FmuError(UserError):
    """The FMU reported an error or refused a call."""


@dataclass(frozen=True)
class FmuRunnerFactory:
    """Picklable recipe for an FmuRunner: the FMU's bytes travel to the worker, which extracts them once."""

    data: bytes
    name: str
    input: str
    output: str

    def __call__(self) -> "FmuRunner":
        return FmuRunner(self.data, self.name, self.input, self.output)


class FmuRunner:
    """One extracted, instantiated Co-Simulation FMU; ``start`` resets it for the next run."""

    def __init__(self, data: bytes, name: str, input_name: str, output_name: str):
        from fmpy import extract, read_model_description

        self.name = name
        self._dir = make_temporary_folder("fmu")
        self._cleanup = weakref.finalize(self, remove_temporary_folders, self._dir)
        archive = Path(self._dir) / "model.fmu"
        try:
            with write_failures(f"the extracted copy of {name} in {self._dir}", FmuError):
                archive.write_bytes(data)
                unzipdir = extract(str(archive), unzipdir=str(Path(self._dir) / "unzipped"))
            md = read_model_description(unzipdir, validate=False)
        except (zipfile.BadZipFile, zlib.error, EOFError, ValueError) as exc:  # a damaged member: bad CRC, bad data
            raise FmuError(f"{name}: not a readable FMU (a damaged archive: {str(exc) or type(exc).__name__})") \
                from exc
        self.fmi3 = md.fmiVersion.startswith("3")
        self.variables = {v.name: v for v in md.modelVariables}
        self.vr = {n: v.valueReference for n, v in self.variables.items()}
        self.input_name, self.output_name = input_name, output_name
        self.builtin = all(n in self.vr for n in EXCITATION)
        self.messages: list[str] = []
        self._fresh = True
        args = dict(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="servofmu")
        if self.fmi3:
            from fmpy.fmi3 import FMU3Slave
            self.fmu = self._load(FMU3Slave, args)
            self._call("instantiate", lambda: self.fmu.instantiate(logMessage=self._log3))
            self._get, self._set = self.fmu.getFloat64, self.fmu.setFloat64
        else:
            from ctypes import byref

            from fmpy import calloc, free
            from fmpy.fmi2 import (
                FMU2Slave,
                fmi2CallbackAllocateMemoryTYPE,
                fmi2CallbackFreeMemoryTYPE,
                fmi2CallbackFunctions,
                fmi2CallbackLoggerTYPE,
            )
            from fmpy.logging import addLoggerProxy
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = fmi2CallbackLoggerTYPE(self._log2)
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            addLoggerProxy(byref(callbacks))
            self._callbacks = callbacks  # keep alive while the FMU lives
            self.fmu = self._load(FMU2Slave, args)
            self._call("instantiate", lambda: self.fmu.instantiate(callbacks=callbacks))
            self._get, self._set = self.fmu.getReal, self.fmu.setReal
        self._vr_in, self._vr_out = self.vr[input_name], self.vr[output_name]

    def _load(self, kind, args):
        """The FMU's shared library loaded; a missing or broken binary is one FmuError naming the FMU."""
        try:
            return kind(**args)
        except Exception as exc:  # fmpy raises plain Exceptions, ctypes OSError
            raise FmuError(f"{self.name}: cannot load the FMU's binary for this platform "
                           f"({(str(exc).splitlines() or [type(exc).__name__])[0]})") from exc

    # FMU log messages are collected, never printed; the last one explains a failure.
    def _log3(self, env, status, category, message):
        self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))

    def _log2(self, env, instance, status, category, message):
        self.messages.append(message.decode(errors="replace") if isinstance(message, bytes) else str(message))

    def _call(self, what: str, fn):
        try:
            return fn()
        except Exception as exc:  # fmpy raises FMICallException or plain Exception
            raise self._failure(what, exc) from exc

    def _failure(self, what: str, exc: Exception) -> FmuError:
        detail = self.messages[-1] if self.messages else (str(exc).splitlines() or [type(exc).__name__])[0]
        return FmuError(f"{self.name}: {what} failed: {detail}")

    def start(self, tolerance: float, values: dict[str, float]) -> None:
        """Reset (after the first run), set ``values``, initialise at t = 0 with ``tolerance``."""
        self.messages.clear()
        if not self._fresh:
            self._call("fmiReset", self.fmu.reset)
        self._fresh = False
        refs = [self.vr[n] for n in values]
        self._call("setting start values", lambda: self._set(refs, [float(x) for x in values.values()]))
        if self.fmi3:
            self._call("initialisation", lambda: self.fmu.enterInitializationMode(tolerance=tolerance,
                                                                                 startTime=0.0))
        else:
            self._call("initialisation", lambda: (self.fmu.setupExperiment(tolerance=tolerance, startTime=0.0),
                                                  self.fmu.enterInitializationMode()))
        self._call("initialisation", self.fmu.exitInitializationMode)

    def value(self) -> float:
        """The output now."""
        return self._get([self._vr_out])[0]

    def set_input(self, value: float) -> None:
        """Set the input (the force u, N) for the next steps."""
        self._set([self._vr_in], [value])

    def step(self, t: float, h: float) -> float:
        """One communication step from t to t + h; returns the output at t + h."""
        try:
            self.fmu.doStep(t, h)
        except Exception as exc:
            raise self._failure(f"doStep at t = {t:.9g} s", exc) from exc
        return self._get([self._vr_out])[0]

    def finish(self) -> None:
        """Terminate the simulation (the instance can be reset and run again)."""
        self._call("fmiTerminate", self.fmu.terminate)

    def close(self) -> None:
        """Free the instance and remove the extracted FMU."""
        try:
            self.fmu.freeInstance()
        finally:
            self._cleanup()
