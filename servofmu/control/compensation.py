"""Friction compensation measured: the axis run on its co-simulation engine without friction feed-forward, with
the identified friction, and with the true one when known — the paper's "velocity performance" made a number.

Each run is the axis archive with the controller's feed-forward parameters replaced in its parameter set
(resources/controller.ssv); nothing else changes.  Per run: the tracking error e = r − x (RMS and peak), and the
velocity's harmonic distortion over the reference's whole periods (when the reference is periodic).
:func:`compensate_files` is `servofmu compensate` from files; its page is servofmu.output.compensation_report's.
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import write_failures
from ..identification.results import read_result
from ..measurement.frf import estimate_frequency, harmonics
from ..model.plant import Plant, load_plant
from ..runtime import temporary_folder
from ..model.controller import ControllerSpec, friction_feedforward, missing_parameter, parameter_set, values_from
from .cosim import CosimResult, cosimulate
from .system import parameter_set_xml, read_system

__all__ = ["TrackingRun", "Compensation", "run_variant", "compare_compensation", "compensate_files"]


@dataclass(frozen=True)
class TrackingRun:
    """One run of the axis: its label, the co-simulation, and its tracking figures."""

    label: str
    result: CosimResult
    rms_error: float
    peak_error: float
    distortion: float  # sqrt(Σ_{k≥2}|V_k|²)/|V_1| of the velocity; NaN for a reference that is not periodic

    @property
    def error(self) -> np.ndarray:
        """The tracking error, reference minus position (m), at every communication step."""
        return self.result["reference"] - self.result["position"]


def _distortion(result: CosimResult) -> float:
    t, r, v = result.time, result["reference"], result["v"]
    frequency, share = estimate_frequency(t, r)
    periods = int(np.floor((t[-1] - t[0]) * frequency))
    if share < 0.8 or periods < 2:
        return float("nan")
    start = t[-1] - (periods - 1) / frequency  # the last whole periods: the start's transient left out
    return float(harmonics(t, v, frequency, start=start, periods=periods - 1).distortion)


def run_variant(ssp: str | Path, controller: ControllerSpec, label: str, engine: str = "libcosim") -> TrackingRun:
    """The axis archive run with ``controller``'s parameter values bound in place of its own."""
    with temporary_folder("compensate") as tmp:
        variant = Path(tmp) / f"{Path(ssp).stem}.ssp"
        with write_failures(str(variant)), zipfile.ZipFile(ssp) as src, \
                zipfile.ZipFile(variant, "w", zipfile.ZIP_DEFLATED) as dst:
            for item in src.infolist():
                if item.filename != "resources/controller.ssv":
                    dst.writestr(item, src.read(item.filename))
            dst.writestr("resources/controller.ssv", parameter_set_xml(parameter_set(controller)))
        result = cosimulate(variant, engine=engine)
    e = result["reference"] - result["position"]
    return TrackingRun(label, result, float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e))), _distortion(result))


def compare_compensation(ssp: str | Path, identified: Plant, truth: Plant | None = None,
                         engine: str = "libcosim", progress=None) -> list[TrackingRun]:
    """Runs without friction feed-forward, with the identified friction, and (given) with the true friction;
    ``progress(done, total)`` (runtime.Progress) as the runs finish."""
    with temporary_folder("compensate") as tmp:
        system = read_system(ssp, tmp)
    missing = missing_parameter(system.controller)
    if missing:
        raise UserError(f"{ssp}: the controller's parameter set has no {missing!r}")
    base = ControllerSpec("controller", values_from(system.controller), str(ssp))
    variants = [(base.with_values(friction_feedforward=0.0), "no compensation"),
                (friction_feedforward(base, identified), "identified friction")]
    if truth is not None:
        variants.append((friction_feedforward(base, truth), "true friction"))
    runs = []
    for spec, label in variants:
        if progress is not None:
            progress(len(runs), len(variants))
        runs.append(run_variant(ssp, spec, label, engine))
    if progress is not None:
        progress(len(runs), len(variants))
    return runs


@dataclass(frozen=True)
class Compensation:
    """`servofmu compensate`'s runs and the plants whose friction they fed forward (the truth None if not given)."""

    runs: list[TrackingRun]
    identified: Plant
    truth: Plant | None
    axis: str  # the axis archive's file name


def compensate_files(result_path: str | Path, ssp: str | Path, truth: str | Path | None = None,
                     engine: str = "libcosim", progress=None) -> Compensation:
    """`servofmu compensate` from files: the axis archive ``ssp`` run without friction feed-forward, with the
    friction of the result file ``result_path`` and (``truth``: a plant file or an example's name) with the true
    friction (:func:`compare_compensation`); ``progress(done, total)`` as the runs finish.  Nothing is written."""
    identified = read_result(result_path).plant
    true_plant = load_plant(truth) if truth is not None else None
    runs = compare_compensation(ssp, identified, true_plant, engine=engine, progress=progress)
    return Compensation(runs, identified, true_plant, Path(ssp).name)
