"""Closed-loop identification: records of the axis in its drive's loop (reference, encoder position, force
command) and the output-error criterion that simulates candidate plants in the known loop
(servofmu.simulation.closed_loop).

The encoder's quantisation and the actuator noise are not reproduced in a fit: they are the measurement's and the
machine's noise, unknown to the identifier (simulating a quantiser would make the criterion piecewise constant in
the parameters).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from ..measurement.datafile import read_data_file
from ..model.controller import ControllerSpec, load_controller
from ..model.plant import Plant, load_plant
from ..simulation.closed_loop import LoopSimulator
from .criterion import TimeDomainCriterion, check_structure, fitted_samples
from .identifier import identification_provenance
from .prior import full_vectors

__all__ = ["ClosedLoopData", "ClosedLoopSeries", "ClosedLoopCriterion", "closed_loop_data",
           "load_closed_loop_inputs"]


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
        """Per record its measured position (m) and force command (N) at the fitted samples, with their names."""
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
