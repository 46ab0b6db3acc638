"""Closed-loop identification: records of the axis in its drive's loop (reference, encoder position, force
command) and the output-error criterion that simulates candidate plants in the known loop
(servofmu.simulation.closed_loop).

The actuator noise is not reproduced in a fit: it is the machine's noise, unknown to the identifier.  The
encoder's quantisation is modelled, not simulated (a quantiser would make the criterion piecewise constant in the
parameters): its error — uniform on ±q/2, variance q²/12, white while the axis moves — is fed back through the
controller, where the velocity loop turns it into a force jitter that the friction averages at low speed (a bias
of up to 0.5 % in static friction when it is left out; docs/bench-closed-loop.md).  A candidate is simulated in
the loop once per encoder-error sequence — :data:`ENCODER_REALISATIONS` sequences drawn once per fit from a
seeded generator in antithetic pairs (e and −e), the same for every candidate (common random numbers: the
criterion stays smooth) — and the mean of these loops is compared with the record: the part of the response
linear in the error cancels, what the friction makes of the jitter stays.  Without a quantiser (resolution 0) one loop is simulated, with
no error.  A known disturbance that the drive injected after its output limit (a record's ``disturbance``) is
reproduced exactly as recorded.

A log's time stamps come from the drive's clock: they are checked against the controller's sample time
(servofmu.measurement.clock: no missing sample, no stamp off the grid, a rate error of at most 1e-4) and the loop
is simulated on the nominal grid t_0 + k·Ts; what the stamps showed is kept per record (``ClosedLoopSeries.clock``)
and in the result's provenance.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import ServofmuWarning, UserError
from ..measurement.clock import ClockFit, fit_clock
from ..measurement.datafile import as_data_file
from ..model.controller import ControllerSpec, load_controller
from ..model.plant import Plant
from ..simulation.closed_loop import LoopSimulator
from .criterion import TimeDomainCriterion, check_structure, fitted_samples
from .inputs import identification_provenance, structure_name, structure_of
from .law_check import law_fit
from .prior import full_vectors

__all__ = ["ClosedLoopData", "ClosedLoopSeries", "ClosedLoopCriterion", "closed_loop_data",
           "load_closed_loop_inputs", "clock_lines", "check_log", "check_law",
           "ENCODER_REALISATIONS"]

ENCODER_REALISATIONS = 4  # encoder-error sequences a candidate's loop is averaged over (docs/bench-closed-loop.md)


@dataclass(frozen=True)
class ClosedLoopSeries:
    """One closed-loop record as it is fitted: time (s, the controller's grid t_0 + k·Ts), the reference (m), the
    measured position (m, the encoder) and the force command (N, applied from each sample on; the total, with the
    disturbance), ``fitted``: the samples that enter the fit; ``disturbance``: the known force injected after the
    output limit (N, or None); ``clock``: what the record's own time stamps showed against the controller."""

    name: str
    time: np.ndarray
    reference: np.ndarray
    position: np.ndarray
    command: np.ndarray
    fitted: np.ndarray
    disturbance: np.ndarray | None = None
    clock: ClockFit | None = None

    def simulate(self, simulator: LoopSimulator, params: np.ndarray, controller: ControllerSpec,
                 rtol: float = 1e-8, encoder_error: np.ndarray | None = None):
        """The loop of every row of ``params`` through this record (servofmu.simulation.closed_loop.LoopResponse):
        its reference followed, its disturbance injected, ``encoder_error`` (m per sample, optional) added to the
        position the controller reads."""
        return simulator.simulate_loop(params, self.time, self.reference, controller, rtol=rtol,
                                       disturbance=self.disturbance, encoder_error=encoder_error)

    def encoder_errors(self, resolution: float, realisations: int, seed: int) -> np.ndarray:
        """(realisations, samples) encoder errors uniform on ±resolution/2 from a generator seeded by ``seed``, in
        antithetic pairs (e and −e); (1, samples) zeros without a quantiser."""
        if resolution <= 0:
            return np.zeros((1, self.time.size))
        # antithetic pairs e, −e: the loops' response linear in the error cancels in their mean, which keeps what
        # the friction makes of the jitter (even in the error) with far less of the draws' own randomness
        half = resolution * (np.random.default_rng(seed).random(((realisations + 1) // 2, self.time.size)) - 0.5)
        return np.concatenate([half, -half])[:realisations]

    def mean_loop(self, simulator: LoopSimulator, params: np.ndarray, controller: ControllerSpec, rtol: float,
                  errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The position and the command (N, samples) of the loop averaged over the encoder-error sequences
        ``errors`` (one row each; a row of zeros: the loop without error)."""
        position, command = 0.0, 0.0
        for e in errors:
            loop = self.simulate(simulator, params, controller, rtol, None if not np.any(e) else e)
            position, command = position + loop.position, command + loop.command
        return position / len(errors), command / len(errors)


@dataclass(frozen=True)
class ClosedLoopData:
    """Closed-loop records and the controller they were made with (its noise-free, unquantised law: the loop a
    candidate plant is simulated in); ``encoder_resolution``: the drive's encoder quantum q (m, 0: exact), whose
    error is modelled by ``realisations`` sequences of uniform noise drawn from ``seed`` (module docstring)."""

    records: tuple[ClosedLoopSeries, ...]
    controller: ControllerSpec
    source: str
    encoder_resolution: float = 0.0
    realisations: int = ENCODER_REALISATIONS
    seed: int = 0

    def criterion(self, structure: Plant, threads: int | None = None) -> "ClosedLoopCriterion":
        """The criterion the identifier scores candidates by."""
        return ClosedLoopCriterion(structure, self, LoopSimulator(structure, threads=threads))


def closed_loop_data(data_file, controller: ControllerSpec, skip: float = 0.0) -> ClosedLoopData:
    """The records of a records file as closed-loop data for ``controller``.

    Every record needs its reference, the measured position and the force command, sampled once per controller
    sample: its time stamps are mapped to the controller's grid (a UserError names the first stamp beyond the
    bounds of servofmu.measurement.clock).  The controller's encoder quantisation and actuator noise are switched
    off in the law and the quantum kept as the data's ``encoder_resolution`` (see the module docstring); ``skip``
    seconds at the start of every record are left out of the fit.
    """
    out = []
    ts = controller.sample_time
    for r, fitted in zip(data_file.records, fitted_samples(data_file, skip)):
        s = r.series
        if s.reference is None:
            raise UserError(f"{data_file.path}: record {r.name} has no reference: a closed-loop identification "
                            "simulates the loop from the recorded reference")
        if s.position is None:
            raise UserError(f"{data_file.path}: record {r.name} has no measured position")
        t = s.time
        clock = fit_clock(t, ts, where=lambda i: f"{data_file.path}: record {r.name}: sample {i + 1} "
                                                 f"(t = {t[i]:.9g} s)")
        where = f"{data_file.path}: record {r.name}"
        check_log(where, s.reference[fitted], s.position[fitted], s.u[fitted],
                  None if s.disturbance is None else s.disturbance[fitted], controller)
        check_law(where, controller, s.reference, s.position, s.u, s.disturbance, fitted)
        grid = t[0] + ts * np.arange(t.size)
        out.append(ClosedLoopSeries(r.name, grid, s.reference, s.position, s.u, fitted, s.disturbance, clock))
    law = controller.with_values(encoder_resolution=0.0, force_noise=0.0)
    return ClosedLoopData(tuple(out), law, str(data_file.path), controller["encoder_resolution"])


# The share (and the number) of a log's samples at its command's largest magnitude from which the drive is taken to
# saturate there: a command's largest value is one sample of a log that never saturates
SATURATED_SHARE, HELD_SAMPLES = 0.01, 5
# How far a logged command may pass the controller's output limit: the noise of a logged (or measured) command
# passes it where the drive saturates (the benchmark's cogging axis: 3003.9 N at a 3000 N limit); a wrong limit or
# input scale passes it by far more (a 100 N limit on a log of 467 N)
BEYOND_LIMIT = 0.05
# The share of a log's samples at the controller's output limit beyond which identify warns: the plant is driven by
# the limit there, and the loop's own law (the gains it was logged with) leaves no trace in those samples
MOSTLY_SATURATED = 0.25


def check_log(where: str, reference: np.ndarray, position: np.ndarray, command: np.ndarray,
              disturbance: np.ndarray | None, controller: ControllerSpec) -> None:
    """Refuse in one line a drive's log that a closed-loop fit cannot use: nothing excites the loop (a constant
    reference and no injected signal), the encoder or the command never changes, the logged command beyond the
    controller file's output limit or held at a level below it (a drive that saturates where the file says it
    cannot); warn where the command sits at the limit in more than MOSTLY_SATURATED of the samples."""
    injected = disturbance is not None and np.ptp(disturbance) > 0
    if np.ptp(reference) == 0 and not injected:
        raise UserError(f"{where}: the reference is constant ({reference[0]:.6g} m) and no test signal is injected: "
                        "nothing excites the loop, so neither G nor the friction can be identified from it (log a "
                        "move of the axis, or a test signal with --disturbance)")
    if np.ptp(position) == 0:
        raise UserError(f"{where}: the encoder position never changes ({position[0]:.6g} m): the axis does not "
                        "move, or the --output-variable column is not its position")
    if np.ptp(command) == 0:
        raise UserError(f"{where}: the force command never changes ({command[0]:.6g} N): is --input the drive's "
                        "output command?")
    own = command - disturbance if disturbance is not None else command  # the controller's part, limited
    limit, top = controller["force_limit"], float(np.max(np.abs(own)))
    if top > limit * (1 + BEYOND_LIMIT):
        raise UserError(f"{where}: the logged command reaches {top:.6g} N, beyond the output limit of "
                        f"{controller.source} ({limit:.6g} N): its [output] limit or the --input-scale is wrong")
    at_top = np.abs(own) >= top * (1 - 1e-9)
    held = float(np.mean(at_top))
    if held > SATURATED_SHARE and np.count_nonzero(at_top) >= HELD_SAMPLES and top < limit * (1 - 1e-6):
        raise UserError(f"{where}: the command is held at ±{top:.6g} N, its largest magnitude, in {100 * held:.3g} % "
                        f"of the samples: the drive saturates there, and {controller.source} says its output limit "
                        f"is {limit:.6g} N (set [output] limit to the drive's own, in N)")
    if held > MOSTLY_SATURATED:
        warnings.warn(f"{where}: the command is at the output limit ±{limit:.6g} N in {100 * held:.3g} % of the "
                      "samples: there the axis is driven by the limit, not by the loop, and only the rest of the "
                      "log shows the controller's law", ServofmuWarning, stacklevel=3)


def check_law(where: str, controller: ControllerSpec, reference, position, command, disturbance, fitted) -> None:
    """Refuse in one line a log whose command the controller file's law does not reproduce from the log's own
    reference and encoder (servofmu.identification.law_check: the key the log fits instead is named); warn where
    it reproduces it only roughly."""
    fit = law_fit(controller, reference, position, command, disturbance, fitted)
    verdict = fit.verdict()
    if verdict == "refuse":
        raise UserError(f"{where}: {fit.describe(controller.source)}: {fit.question()}")
    if verdict == "warn":
        warnings.warn(f"{where}: {fit.describe(controller.source)}", ServofmuWarning, stacklevel=3)


class ClosedLoopCriterion(TimeDomainCriterion):
    """Candidate plants simulated in the known loop: per record the position and the force command against the
    recorded ones, each signal weighted by its noise (servofmu.identification.criterion.TimeDomainCriterion)."""

    def __init__(self, structure: Plant, data: ClosedLoopData, simulator: LoopSimulator):
        self.data, self.simulator = data, simulator
        self.encoder_errors = [r.encoder_errors(data.encoder_resolution, data.realisations, data.seed + i)
                               for i, r in enumerate(data.records)]
        super().__init__(structure)
        # a record's position and command are sampled together and share the loop's noise (the actuator noise
        # moves the axis and the controller answers it): their residuals are correlated
        self.concurrent = [(2 * i, 2 * i + 1) for i in range(len(data.records))]

    def signals(self) -> list[tuple[str, np.ndarray]]:
        """Per record its measured position (m) and force command (N) at the fitted samples, with their names."""
        return [pair for r in self.data.records for pair in ((f"{r.name} position", r.position[r.fitted]),
                                                             (f"{r.name} force", r.command[r.fitted]))]

    def simulate_errors(self, theta: np.ndarray, rtol: float) -> list[np.ndarray]:
        """Model minus record at the fitted samples: per record the position, then the command."""
        theta = np.atleast_2d(theta)
        self.evaluations += theta.shape[0]
        full = full_vectors(self.structure, theta)
        out = []
        for r, errors in zip(self.data.records, self.encoder_errors):
            position, command = r.mean_loop(self.simulator, full, self.data.controller, rtol, errors)
            out += [position[:, r.fitted] - r.position[r.fitted], command[:, r.fitted] - r.command[r.fitted]]
        return out


def load_closed_loop_inputs(data_path, structure_path, controller_path, command: str = "", skip: float = 0.0):
    """(structure, ClosedLoopData, provenance) for a closed-loop identification: each input a file or the object
    read from it (DataFile, Plant, ControllerSpec)."""
    structure = structure_of(structure_path)
    data_file = as_data_file(data_path)
    check_structure(structure, data_file, f"the structure {structure_name(structure_path)}")
    controller = controller_path if isinstance(controller_path, ControllerSpec) else load_controller(controller_path)
    data = closed_loop_data(data_file, controller, skip)
    clocks = {r.name: r.clock.summary() for r in data.records}
    return structure, data, identification_provenance(data_file, structure_name(structure_path), command, skip=skip,
                                                      controller_file=str(controller.source), clocks=clocks)


def clock_lines(provenance: dict) -> list[str]:
    """One line per closed-loop record of a result's provenance: its time stamps against the controller's clock
    (rate error, jitter in samples), as identify prints them."""
    return [f"{name}: time stamps {c['rate_error']:+.3g} off the controller's clock, jitter RMS "
            f"{c['jitter_rms_samples']:.3g} (max {c['jitter_max_samples']:.3g}) of a sample; simulated on the "
            "controller's grid" for name, c in provenance.get("clocks", {}).items()]
