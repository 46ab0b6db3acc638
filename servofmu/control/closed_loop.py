"""The axis in its loop, simulated for many plants at once: the batch simulator's plant with the drive's
controller law at every sample (control/c/loop_driver.c), and the closed-loop output-error criterion.

The loop reproduces the co-simulation of servofmu.control.cosim exactly — sampling, delay, saturation, the
Jacobi exchange — so a candidate plant simulated in the known loop from the recorded reference can be compared
with the recorded position and force command.  The encoder's quantisation and the actuator noise are not
reproduced in a fit: they are the measurement's and the machine's noise, unknown to the identifier (simulating a
quantiser would make the criterion piecewise constant in the parameters).
"""
from __future__ import annotations

import ctypes
import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..identification.criterion import TimeDomainCriterion, check_structure, fitted_samples
from ..identification.identifier import identification_provenance
from ..identification.prior import full_vectors
from ..measurement.datafile import read_data_file
from ..model.plant import Plant, load_plant
from ..simulation.batch import H_START, BatchSimulator, c_doubles, c_mask, compiled_driver
from .controller import ControllerSpec, load_controller, params_header

__all__ = ["LoopSimulator", "LoopResponse", "ClosedLoopData", "ClosedLoopSeries", "ClosedLoopCriterion",
           "closed_loop_data", "load_closed_loop_inputs"]

C_DIR = Path(__file__).resolve().parent / "c"


@dataclass(frozen=True)
class LoopResponse:
    """The loop of N plants at the samples: position (m) and velocity (m/s) at t_k, and the force command (N)
    applied on [t_k, t_k+1); each of shape (N, samples)."""

    position: np.ndarray
    v: np.ndarray
    command: np.ndarray


@functools.lru_cache(maxsize=None)
def _loop_library(plant: Plant) -> ctypes.CDLL:
    lib = compiled_driver(plant, C_DIR / "loop_driver.c",
                          {"controller_params.h": params_header(),
                           "controller_law.h": (C_DIR / "controller_law.h").read_text()})
    d, pd, lng, i = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_long, ctypes.c_int
    lib.sb_loop.argtypes = [lng, i, pd, ctypes.POINTER(ctypes.c_ubyte), lng, pd, pd, pd, d, d, lng, i, pd]
    lib.sb_loop.restype = i
    return lib


class LoopSimulator(BatchSimulator):
    """A batch simulator that can also close the drive's loop around the plant (:meth:`simulate_loop`)."""

    @staticmethod
    def _load(plant: Plant) -> ctypes.CDLL:
        return _loop_library(plant)

    def simulate_loop(self, params, time, reference, controller: ControllerSpec, rtol: float = 1e-8,
                      max_steps: int = 50_000_000) -> LoopResponse:
        """The loop at the sample times ``time`` (uniform, the controller's sample time) following ``reference``,
        all plant states zero at time[0], for every row of ``params``."""
        p, valid = self._parameter_sets(params)
        t = np.ascontiguousarray(np.asarray(time, dtype=float).ravel())
        r = np.ascontiguousarray(np.asarray(reference, dtype=float).ravel())
        if t.size != r.size or t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
            raise UserError("a closed-loop run needs at least two finite samples of time and reference")
        steps = np.diff(t)
        if np.max(np.abs(steps - controller.sample_time)) > 1e-6 * controller.sample_time:
            raise UserError(f"the samples are {np.median(steps):g} s apart, the controller samples every "
                            f"{controller.sample_time:g} s: the loop needs one record sample per controller sample")
        if not 0 < rtol < 1e-2:
            raise UserError(f"rtol must be in (0, 0.01), not {rtol}")
        cp = np.ascontiguousarray(controller.vector())
        out = np.empty((p.shape[0], 3, t.size))
        rc = self._lib.sb_loop(p.shape[0], p.shape[1], c_doubles(p), c_mask(valid), t.size, c_doubles(t),
                               c_doubles(r), c_doubles(cp), rtol, H_START, max_steps, self.threads, c_doubles(out))
        if rc != 0:
            raise RuntimeError(f"loop library rejected the call (code {rc})")
        return LoopResponse(position=out[:, 0], v=out[:, 1], command=out[:, 2])


# ---------------------------------------------------------------------------
# Closed-loop identification
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ClosedLoopSeries:
    """One closed-loop record as it is fitted: time (s, one sample per controller sample), the reference (m), the
    measured position (m, the encoder) and the force command (N, applied from each sample on), ``fitted``: the
    samples that enter the fit."""

    name: str
    time: np.ndarray
    reference: np.ndarray
    position: np.ndarray
    command: np.ndarray
    fitted: np.ndarray


@dataclass(frozen=True)
class ClosedLoopData:
    """Closed-loop records and the controller they were made with (its noise-free, unquantised law: the loop a
    candidate plant is simulated in)."""

    records: tuple[ClosedLoopSeries, ...]
    controller: ControllerSpec
    source: str

    def criterion(self, structure: Plant, threads: int | None = None) -> "ClosedLoopCriterion":
        """The criterion the identifier scores candidates by."""
        return ClosedLoopCriterion(structure, self, LoopSimulator(structure, threads=threads))


def closed_loop_data(data_file, controller: ControllerSpec, skip: float = 0.0) -> ClosedLoopData:
    """The records of a records file as closed-loop data for ``controller``.

    Every record needs its reference, the measured position and the force command, sampled once per controller
    sample.  The controller's encoder quantisation and actuator noise are switched off (see the module
    docstring); ``skip`` seconds at the start of every record are left out of the fit.
    """
    out = []
    for r, fitted in zip(data_file.records, fitted_samples(data_file, skip)):
        s = r.series
        if s.reference is None:
            raise UserError(f"{data_file.path}: record {r.name} has no reference: a closed-loop identification "
                            "simulates the loop from the recorded reference")
        if s.position is None:
            raise UserError(f"{data_file.path}: record {r.name} has no measured position")
        out.append(ClosedLoopSeries(r.name, s.time, s.reference, s.position, s.u, fitted))
    law = controller.with_values(encoder_resolution=0.0, force_noise=0.0)
    return ClosedLoopData(tuple(out), law, str(data_file.path))


class ClosedLoopCriterion(TimeDomainCriterion):
    """Candidate plants simulated in the known loop: per record the position and the force command against the
    recorded ones, each signal weighted by its noise (servofmu.identification.criterion.TimeDomainCriterion)."""

    def __init__(self, structure: Plant, data: ClosedLoopData, simulator: LoopSimulator):
        self.data, self.simulator = data, simulator
        super().__init__(structure)

    def signals(self) -> list[tuple[str, np.ndarray]]:
        return [pair for r in self.data.records for pair in ((f"{r.name} position", r.position[r.fitted]),
                                                             (f"{r.name} force", r.command[r.fitted]))]

    def errors(self, theta: np.ndarray, rtol: float) -> list[np.ndarray]:
        """Model minus record at the fitted samples: per record the position, then the command."""
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        full = full_vectors(self.structure, theta)
        out = []
        for r in self.data.records:
            loop = self.simulator.simulate_loop(full, r.time, r.reference, self.data.controller, rtol=rtol)
            out += [loop.position[:, r.fitted] - r.position[r.fitted], loop.command[:, r.fitted] - r.command[r.fitted]]
        return out


def load_closed_loop_inputs(data_path, structure_path, controller_path, command: str = "", skip: float = 0.0):
    """(structure, ClosedLoopData, provenance) for a closed-loop identification from files."""
    structure = load_plant(structure_path)
    data_file = read_data_file(data_path)
    check_structure(structure, data_file, f"the structure {structure_path}")
    data = closed_loop_data(data_file, load_controller(controller_path), skip)
    return structure, data, identification_provenance(data_path, structure_path, command, skip=skip,
                                                      controller_file=str(controller_path))
