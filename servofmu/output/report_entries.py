"""What a report shows, computed: each labelled result of a report source simulated against its data — the
identified first harmonics at the used experiments, or the records replayed as they were fitted."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..identification.criterion import POLISH_RTOL, SineData, sine_data, steady_state_options
from ..identification.results import Result, read_results
from ..measurement.datafile import DataFile
from ..model.controller import load_controller
from ..model.plant import Plant
from ..simulation.batch import BatchSimulator
from ..validation.replay import Validation
from ..validation.replay import validate as validate_model

__all__ = ["Entry", "read_entries", "compute_entries", "model_sine", "velocity_range", "used_sine_data",
           "loop_controller", "CURVE_POINTS", "CURVE_RTOL", "FRICTION_POINTS"]

CURVE_POINTS = 40          # frequencies per magnitude of the identified model's Bode curve
CURVE_RTOL = 1e-8          # integrator tolerance of that curve (a figure); the tables use the polish's
FRICTION_POINTS = 2000     # velocities of the friction curve (an even number: v = 0 is not among them)


# ---------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Entry:
    """One result on the page and what is computed from it against the data.

    sine: the identified model's H and dc at the data's used experiments (None for records);
    records: the identified model on every record it was fitted to (None for stepped-sine data).
    """

    label: str
    result: Result
    sine: tuple[np.ndarray, np.ndarray] | None = None
    records: Validation | None = None


def read_entries(path: str | Path) -> list[tuple[str, Result]]:
    """The labelled results of a report source: a result file gives one, a comparison file (`servofmu compare`)
    one per method, labelled by the method.  Other files are refused (servofmu.identification.results.read_results)."""
    return list(read_results(path).items())


# ---------------------------------------------------------------------------
# Numbers
# ---------------------------------------------------------------------------
def model_sine(plant: Plant, amplitudes, frequencies, rtol: float = CURVE_RTOL):
    """(H, dc, converged) of ``plant`` in steady state at each (amplitude, frequency) pair; the convergence test
    as the identifier's (servofmu.identification.criterion.SineCriterion)."""
    options = steady_state_options(rtol)
    feats = BatchSimulator(plant).steady_state(plant.parameter_vector(), amplitudes, frequencies, options)
    return feats.H[0], feats.dc[0], feats.converged[0]


def used_sine_data(data_file: DataFile) -> SineData | None:
    """The stepped-sine data a report shows (None for a records file)."""
    return sine_data(data_file) if data_file.kind == "measurement" else None


def velocity_range(data_file: DataFile) -> float:
    """The velocity range (m/s) of the friction figure: a tenth beyond the largest measured velocity."""
    peaks = [np.max(np.abs(e.window.v)) for e in data_file.experiments if e.window.v.size]
    peaks += [np.max(np.abs(r.series.v)) for r in data_file.records if r.series.v.size]
    peak = max(peaks, default=0.0)
    return 1.1 * peak if np.isfinite(peak) and peak > 0 else 1.0


def loop_controller(result: Result):
    """The controller of a closed-loop identification (its file, as the provenance names it), else None."""
    path = result.provenance.get("controller_file")
    return load_controller(path) if path else None


def compute_entries(labelled: Sequence[tuple[str, Result]], data_file: DataFile) -> list[Entry]:
    """Simulate each identified plant against the data: at the used experiments, or along each record."""
    data = used_sine_data(data_file)
    entries = []
    for label, result in labelled:
        if data is not None:
            H, dc, _ = model_sine(result.plant, data.amplitudes, data.frequencies, rtol=POLISH_RTOL)
            entries.append(Entry(label, result, sine=(H, dc)))
        else:  # the records replayed as identify fitted them: their holds, outputs, skipped segment and loop
            entries.append(Entry(label, result,
                                 records=validate_model(result, data_file, float(result.provenance.get("skip", 0.0)),
                                                        loop_controller(result))))
    return entries
