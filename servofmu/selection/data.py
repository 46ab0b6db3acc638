"""What a selection fits and validates on: one or more data files of one axis merged into the identifier's data
(stepped-sine experiments, open-loop records or closed-loop records), checked to be of one kind, and a
validation file checked to hold the same signals."""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import ServofmuWarning, UserError
from ..identification.criterion import RecordCriterion, RecordData, SineCriterion, SineData, record_data, sine_data
from ..identification.shortening import first_share, shortened
from ..identification.closed_loop import ClosedLoopCriterion, ClosedLoopData
from ..measurement.datafile import DataFile, as_data_file, data_name
from ..measurement.duplicates import file_items, refuse_repeats
from ..simulation.batch import BatchSimulator, RecordResponse, SteadyStateOptions, valid_parameter_sets
from ..simulation.closed_loop import LoopSimulator
from .estimate import Series, series_of_experiments, series_of_records

__all__ = ["load_selection_data", "check_validation", "criterion_for", "estimation_series", "data_kind",
           "BoundedSimulator", "BoundedLoopSimulator", "without_quantiser", "STEPS_PER_SAMPLE", "steps_per_sample",
           "first_share", "fitted_seconds", "ranked_data"]

# The integrator steps a record's simulation may take per sample before it is stopped (its response then NaN, as
# for a failed integration), at the polish's tolerance BUDGET_RTOL: the bench's true plants need at most 28 per
# sample there (docs/selection.md); a candidate with fast poles and Coulomb friction can chatter about zero
# velocity and take millions (one simulation of the polish 24 s instead of 10 ms).
STEPS_PER_SAMPLE = 200
BUDGET_RTOL = 1e-10
# How the budget follows the tolerance: the true plants' steps grow as rtol^-0.2 (1.3-1.9 per sample at 1e-4,
# 3.6-6.8 at 1e-7, 14-28 at 1e-10), so a looser run keeps the same margin over them with fewer steps.
BUDGET_EXPONENT = 0.2


def steps_per_sample(rtol: float) -> float:
    """The step budget per sample of a record simulated at ``rtol``: STEPS_PER_SAMPLE at BUDGET_RTOL, scaled as
    the steps a plant needs (13 at the swarm's screening 1e-4, 50 at the screening polish's 1e-7)."""
    return STEPS_PER_SAMPLE * (BUDGET_RTOL / rtol) ** BUDGET_EXPONENT


def data_kind(data) -> str:
    """"sine", "records" or "closed-loop"."""
    if isinstance(data, SineData):
        return "sine"
    return "records" if isinstance(data, RecordData) else "closed-loop"


def _one(source, skip: float, controller):
    """(DataFile, identifier data) of one file or DataFile."""
    ds, path = as_data_file(source), data_name(source)
    if ds.kind == "broadband":  # its records, as one run from rest (identification.broadband_identify)
        from ..broadband.store import read_broadband
        from ..identification.broadband_identify import broadband_records

        if controller is not None:
            raise UserError(f"{path}: broadband data is open loop (the plant driven by the excitation): select "
                            "without --closed-loop")
        data = read_broadband(source)
        wild = [f"{lv.level:g}" for lv in data.levels if not lv.bla.periodic]
        if wild:  # g2's limit cycle: the truth 3rd and 5th in two of three seeds (docs/bench-select-broadband.md)
            warnings.warn(f"{path}: the response at {', '.join(wild)} N is not periodic in the excitation's period (a "
                          "limit cycle or a transient; `servofmu frf` names the component): its records are ranked "
                          "on as they are, where a selection may rank structures by where their fits happened to end",
                          ServofmuWarning, stacklevel=2)
        return ds, broadband_records(data, skip)
    if controller is not None:
        from ..identification.closed_loop import closed_loop_data

        if ds.kind != "records":
            raise UserError(f"{path}: --closed-loop needs records (servofmu import or cosim), not stepped-sine data")
        return ds, closed_loop_data(ds, controller, skip)
    if ds.kind == "records":
        return ds, record_data(ds, skip)
    if skip:
        raise UserError(f"{path}: skip applies to records, not to stepped-sine experiments")
    return ds, sine_data(ds)


def ranked_data(data, files: list[DataFile], samples: int, skip: float = 0.0):
    """What the candidates are ranked on where ``data`` is long: of broadband files, the first realisation of
    every level after its transient periods (identification.broadband_identify.level_pieces: the run's own start
    holds only the first level's transient, one level where the paper needs two to tell G from the friction);
    else ``data`` shortened to ``samples`` fitted samples (identification.shortening.shortened); and whether it
    is the levels' realisations."""
    if len(files) == 1 and files[0].kind == "broadband" and sum(r.fitted.sum() for r in data.records) > samples:
        from ..broadband.store import read_broadband
        from ..identification.broadband_identify import level_pieces

        pieces = level_pieces(read_broadband(files[0].path), samples, skip)
        if pieces is not None:
            return pieces, True
    return shortened(data, samples), False


def _unique(records, files):
    """Records of several files renamed FILE:NAME where two share a name."""
    names = [r.name for r in records]
    if len(set(names)) == len(names):
        return tuple(records)
    return tuple(replace(r, name=f"{Path(f).stem}:{r.name}") for r, f in zip(records, files))


def _merge(parts: list, paths: list[str]):
    """One identifier data object from those of several files."""
    kinds = {data_kind(p) for p in parts}
    if len(kinds) > 1:
        raise UserError(f"{', '.join(paths)}: mix stepped-sine data and records; select on one kind at a time")
    first = parts[0]
    if len(parts) == 1:
        return first
    source = ", ".join(paths)
    if isinstance(first, SineData):
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        noise = cat("noise") if all(p.noise is not None for p in parts) else None  # the identifier's noise floor
        return SineData(amplitudes=cat("amplitudes"), frequencies=cat("frequencies"), H=cat("H"), dc=cat("dc"),
                        noisy=all(p.noisy for p in parts), source=source, skipped=sum(p.skipped for p in parts),
                        noise=noise)
    records = [r for p in parts for r in p.records]
    files = [f for p, f in zip(parts, paths) for _ in p.records]
    return replace(first, records=_unique(records, files), source=source)


def load_selection_data(paths, skip: float = 0.0, controller=None):
    """(data, DataFiles) of the files ``paths`` (one axis, one kind of data), merged as the identifier fits them:
    SineData, RecordData or closed-loop data (with ``controller``).  The plant a file may record is not checked
    against the candidates (every structure is tried); files recording different plants are refused."""
    if not paths:
        raise UserError("no data files to select from")
    loaded = [_one(p, skip, controller) for p in paths]
    paths = [data_name(p) for p in paths]
    files = [ds for ds, _ in loaded]
    refuse_repeats([item for ds in files for item in file_items(ds)], "give each measurement once")
    recorded = [(ds.path, _plant_values(ds)) for ds in files if _plant_values(ds)]
    for path, values in recorded[1:]:
        if values != recorded[0][1]:
            raise UserError(f"{path}: records another plant than {recorded[0][0]} (its parameters differ); select on "
                            "data of one axis")
    return _merge([d for _, d in loaded], paths), files


def _plant_values(ds: DataFile) -> dict:
    """The plant parameters a measurement of a servofmu FMU records (empty for a machine's records)."""
    return {k: v for k, v in ds.parameters.items() if not k.startswith("excitation")}


def _signals(data) -> list[str]:
    """What the data measures, as words: per record its output, for sine data the velocity's harmonics."""
    if isinstance(data, SineData):
        return ["stepped-sine harmonics of v"]
    if isinstance(data, RecordData):
        return sorted({f"records of {r.output} driven by u" for r in data.records})
    return ["closed-loop records (reference, position, force command)"]


def check_validation(fit, fit_files: list[DataFile], validation, validation_file: DataFile) -> None:
    """Refuse a validation file that holds other signals than the fitted data (another kind, another output), a
    record or experiment of the fitted data (by the digest of its samples), a record that never moves, or that
    records another plant than the fitted files do."""
    path = validation_file.path
    if data_kind(fit) != data_kind(validation) or _signals(fit) != _signals(validation):
        raise UserError(f"{path}: holds {', '.join(_signals(validation))}, the fitted data "
                        f"{', '.join(_signals(fit))}: validate on data of the same signals (the same input and "
                        "output)")
    fitted = {digest: what for f in fit_files for what, digest in file_items(f)}
    for what, digest in file_items(validation_file, f"{path} (--validate)"):
        if digest in fitted:
            raise UserError(f"{what} holds the same samples as {fitted[digest]}, which is fitted: validation on "
                            "fitted data tests no prediction; give --validate another measurement of the axis")
    _refuse_still(validation, f"{path} (--validate)")
    mine = _plant_values(validation_file)
    theirs = next((_plant_values(f) for f in fit_files if _plant_values(f)), {})
    if mine and theirs and mine != theirs:
        differ = sorted(k for k in set(mine) | set(theirs) if mine.get(k) != theirs.get(k))
        raise UserError(f"{path}: was measured on another plant than the fitted data ({', '.join(differ[:4])} "
                        "differ); validate on data of the same axis")


def _refuse_still(data, where: str) -> None:
    """Refuse records whose measured output never changes over their fitted samples: a fit to them divides by
    their spread (no number), so no candidate could be ranked on them."""
    if isinstance(data, SineData):
        return
    for r in data.records:
        y, signal = (r.y, r.output) if isinstance(data, RecordData) else (r.position, "position")
        seen = np.asarray(y, dtype=float)[r.fitted]
        if seen.size and np.ptp(seen) == 0:
            raise UserError(f"{where}: record {r.name!r}: its {signal} is {float(seen[0]):g} throughout the fitted "
                            "samples: the axis never moves, so no fit to it can be computed; give a record in which "
                            "it moves")


class FlooredSineSimulator(BatchSimulator):
    """The batch simulator whose stepped-sine runs keep a tolerance of at least ``rtol_floor`` (a screening fit's;
    the periods compared to a tenth of it, as the identifier's settings do)."""

    stopped = 0
    rtol_floor = 0.0

    def steady_state(self, params, amplitudes, frequencies, options: SteadyStateOptions = SteadyStateOptions(),
                     progress=None, start=None):
        """As :meth:`BatchSimulator.steady_state`, at a tolerance of at least ``rtol_floor``."""
        if options.rtol < self.rtol_floor:
            options = replace(options, rtol=self.rtol_floor, tol=min(max(self.rtol_floor / 10, 1e-10), 1e-6))
        return BatchSimulator.steady_state(self, params, amplitudes, frequencies, options, progress, start)


class BoundedSimulator(BatchSimulator):
    """The batch simulator with a step budget on every record: steps_per_sample(rtol) integrator steps per sample, a run
    that needs more stopped and its response NaN (a candidate far from the data: the search scores it infinite,
    the polish steps back); ``rtol_floor``: the loosest tolerance asked for is kept (a screening fit's).
    ``stopped`` counts the runs of valid parameter sets that gave NaN (stopped at the
    budget or failed)."""

    stopped = 0
    rtol_floor = 0.0  # no tolerance tighter than this (the screening fit's)

    def simulate_record(self, params, time, u, hold: str = "zoh", rtol: float = 1e-8, max_steps: int = 50_000_000,
                        progress=None) -> RecordResponse:
        """As :meth:`BatchSimulator.simulate_record`, with at most steps_per_sample(rtol) steps per sample and a
        tolerance of at least ``rtol_floor``."""
        return _within_budget(self, params, time, rtol, max_steps, lambda out: out.v, lambda tol, steps:
                              BatchSimulator.simulate_record(self, params, time, u, hold=hold, rtol=tol,
                                                             max_steps=steps, progress=progress))


class BoundedLoopSimulator(LoopSimulator):
    """The loop simulator with BoundedSimulator's step budget and tolerance floor: a candidate whose loop chatters
    (fast poles and a steep friction sign fed back through the velocity loop) cannot hold up a selection."""

    stopped = 0
    rtol_floor = 0.0

    def simulate_loop(self, params, time, reference, controller, rtol: float = 1e-8, max_steps: int = 50_000_000,
                      disturbance=None, encoder_error=None):
        """As :meth:`LoopSimulator.simulate_loop`, with at most steps_per_sample(rtol) steps per sample and a
        tolerance of at least ``rtol_floor``."""
        return _within_budget(self, params, time, rtol, max_steps, lambda out: out.position, lambda tol, steps:
                              LoopSimulator.simulate_loop(self, params, time, reference, controller, rtol=tol,
                                                          max_steps=steps, disturbance=disturbance,
                                                          encoder_error=encoder_error))


def _within_budget(sim, params, time, rtol, max_steps, response, run):
    """``run(rtol, max_steps)`` at a tolerance of at least ``sim.rtol_floor`` and at most steps_per_sample(rtol)
    steps per sample of ``time``; the valid parameter sets whose ``response`` is not finite counted in
    ``sim.stopped``."""
    rtol = max(rtol, sim.rtol_floor)
    out = run(rtol, min(max_steps, int(steps_per_sample(rtol) * max(np.size(time), 1))))
    valid = valid_parameter_sets(sim.plant, np.atleast_2d(np.asarray(params, dtype=float)))
    sim.stopped += int(np.sum(valid & ~np.all(np.isfinite(response(out)), axis=1)))
    return out


def criterion_for(structure, data, threads: int | None = None):
    """The identifier's criterion of ``structure`` on ``data``, records and loops simulated within the step budget
    (BoundedSimulator, BoundedLoopSimulator)."""
    if isinstance(data, SineData):
        return SineCriterion(structure, data, FlooredSineSimulator(structure, threads=threads))
    if isinstance(data, RecordData):
        return RecordCriterion(structure, data, BoundedSimulator(structure, threads=threads))
    return ClosedLoopCriterion(structure, data, BoundedLoopSimulator(structure, threads=threads))


def without_quantiser(data):
    """Closed-loop ``data`` with its encoder's quantisation not modelled (one loop per candidate instead of
    ENCODER_REALISATIONS): what a screening fit simulates, whose ranking the quantiser's few-per-mille effect on
    the friction levels does not change (docs/selection.md); other data as it is."""
    if isinstance(data, ClosedLoopData) and data.encoder_resolution > 0:
        return replace(data, encoder_resolution=0.0)
    return data




def fitted_seconds(data) -> float:
    """The longest fitted time span of a record of ``data`` (s)."""
    return max(float(r.time[r.fitted][-1] - r.time[r.fitted][0]) for r in data.records)


def estimation_series(data, files: list[DataFile]) -> list[Series]:
    """The stretches of data the linear estimate is computed from: the records (velocity, or the position
    differentiated; in a closed loop the force command against the position's derivative), or the windows of
    the stepped-sine experiments."""
    if isinstance(data, SineData):
        return series_of_experiments([e for f in files for e in f.experiments])
    if isinstance(data, RecordData):
        return series_of_records(data.records)
    out = []
    for r in data.records:
        f = r.fitted
        v = np.gradient(r.position[f], r.time[f])
        out.append(Series(u=np.asarray(r.command[f], float), v=v, dt=float(np.median(np.diff(r.time))),
                          periodic=False))
    return out
