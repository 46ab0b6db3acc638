"""The round trip of an export: an identified model exported as an FMU (output.export) and measured again
(measurement.measure) with the plan and settings of the data it was identified from, and how well that
re-measurement reproduces the data's first harmonics (docs/export.md)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import UserError
from ..fileio import check_output_path
from ..identification.criterion import sine_data, sine_residuals
from ..identification.results import Result
from ..measurement.datafile import read_data_file
from ..measurement.measure import MeasureOptions, measure
from ..output.export import export_fmu, export_provenance
from ..runtime import RunOptions

__all__ = ["remeasure", "RoundTrip", "ROUND_TRIP_TOLERANCE"]

# A round trip reproduces the data when its residual is at most the identification's fitness plus this: the
# FMU measurement and the identifier's batch simulator agree on first harmonics to <= 5e-10 relative and on the
# fitness to <= 1.3e-10 (docs/bench-export.md), so 1e-8 leaves a margin of about 20 to 80.
ROUND_TRIP_TOLERANCE = 1e-8
# Measurement settings taken over from the data file's provenance for the re-measurement.
_MEASURE_KEYS = ("tolerance", "samples_per_period", "settle_samples_per_period", "window_periods", "threshold",
                 "consecutive", "min_periods", "max_time", "harmonics")


@dataclass(frozen=True)
class RoundTrip:
    """The exported FMU measured with the plan of the data it was identified from.

    ``residual_rms``: RMS of the identifier's residuals between the re-measurement and the data (what the
    fitness measures); ``max_H_error``: max |H − H_data|/|H_data|; both over the ``compared`` experiments of the
    data that reached a steady state; ``unsettled``: how many of those did not in the re-measurement.
    """

    fmu: Path
    measured: object  # DataFile of the re-measurement
    fitness: float
    residual_rms: float
    max_H_error: float
    compared: int
    unsettled: int

    @property
    def reproduces(self) -> bool:
        """The exported model fits the data as well as the identification says (within ROUND_TRIP_TOLERANCE)."""
        return self.unsettled == 0 and self.residual_rms <= self.fitness + ROUND_TRIP_TOLERANCE


def remeasure(result: Result, data_file: str | Path, fmu_path: str | Path, measured_path: str | Path,
              fmi_version: int = 3, name: str | None = None, result_file: str | Path | None = None,
              command: str = "", workers: int | None = None, scheduler: str | None = None,
              progress: Callable[[int, int], None] | None = None,
              warn: Callable[[str], None] | None = None) -> RoundTrip:
    """Export ``result`` as an FMU to ``fmu_path``, measure it into ``measured_path`` with the plan and the
    measurement settings of ``data_file`` (the stepped-sine data it was identified from) and compare."""
    ds = read_data_file(data_file)
    if ds.kind != "measurement" or not ds.plan:
        raise UserError(f"{data_file}: is a {ds.kind} file; the round trip needs stepped-sine measurements")
    claimed = result.provenance.get("data_sha256")
    if claimed and claimed != ds.sha256:
        raise UserError(f"{data_file}: is not the data file the result was identified from "
                        f"({result.provenance.get('data_file', 'SHA-256 ' + claimed[:12])})")
    data = sine_data(ds)
    check_output_path(fmu_path)
    check_output_path(measured_path, overwrite=False)
    fmu = export_fmu(result, fmu_path, fmi_version, name, export_provenance(result, result_file, command),
                     overwrite=True)
    options = MeasureOptions(**{k: ds.provenance[k] for k in _MEASURE_KEYS if k in ds.provenance})
    measured = measure(fmu, measured_path, amplitudes=ds.plan.amplitudes, frequencies=ds.plan.frequencies,
                       options=options, warn=warn,
                       run=RunOptions(scheduler=scheduler, workers=workers, command=command, progress=progress))
    again = [measured.experiment(m, f) for m, f in zip(data.amplitudes, data.frequencies)]
    H = np.array([e.H for e in again], dtype=complex)
    dc = np.array([e.dc for e in again], dtype=float)
    r = sine_residuals(data, H, dc)
    return RoundTrip(fmu=Path(fmu), measured=measured, fitness=result.fitness,
                     residual_rms=float(np.sqrt(np.mean(r ** 2))),
                     max_H_error=float(np.max(np.abs(H - data.H) / np.abs(data.H))), compared=len(again),
                     unsettled=sum(not e.converged for e in again))
