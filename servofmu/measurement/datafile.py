"""The data file: one self-describing HDF5 file per measurement or set of records (layout in docs/hdf5.md).

Every write builds the new file beside the target (``.NAME.part``) and renames it over the target in one
step, so a killed run leaves either the previous file or a complete new one.  A measurement file is
written when the run starts (plan + provenance, no experiments), again after every finished experiment,
and a last time to mark it complete; ``--resume`` reads which experiments are stored and runs the others.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import h5py
import numpy as np

from ..errors import UserError
from ..fileio import (
    READ_ERRORS,
    check_format,
    check_output_path,
    check_values,
    hdf5_attr,
    open_hdf5,
    read_error_reason,
    store_array,
    write_hdf5,
)
from ..model.signals import INTERSAMPLE
from .excitation import ExperimentSpec, Plan

__all__ = ["DataFile", "Series", "ExperimentResult", "RecordAnalysis", "Record", "read_data_file",
           "create_measurement", "add_experiments", "mark_complete", "write_records", "experiment_group_name",
           "FORMAT", "SCHEMA_VERSION"]

FORMAT = "servofmu-data"
# 2: records carry their intersample behaviour ("intersample": "zoh" or "foh"); version 1 files are read as
# "foh", what servofmu assumed when it wrote them (a version 1 file that is appended to is upgraded).
SCHEMA_VERSION = 2
KINDS = ("measurement", "records")

SIGNAL_INFO = {
    "time": ("s", "time"),
    "u": ("N", "input force driving the plant (for built-in excitation: u + excitation_amplitude*sin(2*pi*"
               "excitation_frequency*t); for input-port drive: the value held on [t, t + interval))"),
    "v": ("m/s", "velocity, the plant output"),
    "v_noisy": ("m/s", "v plus white Gaussian measurement noise (see noise_sigma)"),
    "position": ("m", "measured position (raw, as recorded)"),
    "reference": ("m", "reference position of the drive's controller (closed-loop records)"),
}
RESULT_UNITS = {
    "amplitude": "N", "frequency": "Hz", "U1": "N", "V1": "m/s", "H": "m/(N.s)", "dc": "m/s", "dc_u": "N",
    "distortion": "1", "settling_time": "s", "window_start": "s", "window_periods": "1", "hold_error": "1",
    "last_change": "1", "remaining_error": "1", "noise_sigma": "m/s", "H_noisy": "m/(N.s)", "dc_noisy": "m/s",
    "sample_rate": "Hz", "sine_fraction": "1", "velocity_cutoff": "Hz", "samples_per_period": "1",
}


# ---------------------------------------------------------------------------
# What is stored
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Series:
    """Sampled signals (SI units: s, N, m/s, m); optional ones are None."""

    time: np.ndarray
    u: np.ndarray
    v: np.ndarray
    v_noisy: np.ndarray | None = None
    position: np.ndarray | None = None
    reference: np.ndarray | None = None

    def signals(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ("time", "u", "v", "v_noisy", "position", "reference")
                if getattr(self, k) is not None}


@dataclass(frozen=True)
class ExperimentResult:
    """One stepped-sine experiment of a measurement (docs/measurement.md defines every field)."""

    index: int
    amplitude: float
    frequency: float
    excitation: str                 # "builtin" or "input"
    U1: complex
    V1: complex
    H: complex
    dc: float
    harmonics: np.ndarray           # S_1..S_K of v
    distortion: float
    converged: bool
    settling_time: float
    last_change: float
    remaining_error: float
    window_start: float
    window_periods: int
    samples_per_period: int
    hold_error: float
    transient: Series
    window: Series
    noise_sigma: float | None = None
    H_noisy: complex | None = None
    dc_noisy: float | None = None

    @property
    def spec(self) -> ExperimentSpec:
        return ExperimentSpec(self.index, self.amplitude, self.frequency)


@dataclass(frozen=True)
class RecordAnalysis:
    """First-harmonic analysis of a sinusoidal record (same meaning as for an experiment)."""

    frequency: float
    sine_fraction: float
    amplitude: float
    U1: complex
    V1: complex
    H: complex
    dc_u: float
    dc: float
    harmonics: np.ndarray
    distortion: float
    converged: bool
    settling_time: float
    window_start: float
    window_periods: int


@dataclass(frozen=True)
class Record:
    """A record imported from a machine: raw signals, the velocity used, and its analysis if sinusoidal."""

    index: int
    name: str
    source: str
    source_sha256: str
    kind: str                      # "velocity" or "position"
    columns: dict                  # role (time/u/v or position) -> column name in the source
    series: Series
    sample_rate: float
    velocity_estimate: str         # how v was obtained
    velocity_cutoff: float | None
    analysis: RecordAnalysis | None
    note: str = ""
    intersample: str = "zoh"       # the input between samples: held ("zoh") or linear ("foh")


@dataclass(frozen=True)
class DataFile:
    """A data file read back: plan, experiments, records and provenance."""

    path: Path
    kind: str
    schema_version: int
    complete: bool
    plan: Plan | None
    experiments: tuple[ExperimentResult, ...]
    records: tuple[Record, ...]
    provenance: dict = field(default_factory=dict)
    parameters: dict = field(default_factory=dict)

    def missing(self) -> tuple[ExperimentSpec, ...]:
        done = {e.index for e in self.experiments}
        return tuple(s for s in self.plan.experiments if s.index not in done) if self.plan else ()

    def experiment(self, amplitude: float, frequency: float) -> ExperimentResult:
        for e in self.experiments:
            if e.amplitude == amplitude and e.frequency == frequency:
                return e
        raise KeyError((amplitude, frequency))


# ---------------------------------------------------------------------------
# Atomic writes
# ---------------------------------------------------------------------------
def _set_attrs(obj, values: dict) -> None:
    for key, value in values.items():
        if value is None:
            continue
        if isinstance(value, (dict, list, tuple)):
            value = json.dumps(value)
        obj.attrs[key] = value


def _write_series(group: h5py.Group, series: Series) -> None:
    for name, data in series.signals().items():
        unit, description = SIGNAL_INFO[name]
        store_array(group, name, np.asarray(data, dtype=float), unit=unit, description=description)


def _write_header(f: h5py.File, kind: str, provenance: dict, parameters: dict) -> None:
    f.attrs["format"] = FORMAT
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["kind"] = kind
    f.attrs["complete"] = False
    prov = f.create_group("provenance")
    _set_attrs(prov, provenance)
    par = prov.create_group("parameters")
    _set_attrs(par, {k: float(v) for k, v in parameters.items()})


def create_measurement(path: str | Path, plan: Plan, provenance: dict, parameters: dict) -> Path:
    """A new measurement file with its plan and provenance and no experiments yet."""
    path = check_output_path(path)

    def edit(f):
        _write_header(f, "measurement", provenance, parameters)
        g = f.create_group("plan")
        specs = plan.experiments
        for name, values, unit in (("amplitude", [s.amplitude for s in specs], "N"),
                                   ("frequency", [s.frequency for s in specs], "Hz")):
            store_array(g, name, np.asarray(values, dtype=float), unit=unit)
        g.attrs["amplitudes"] = np.asarray(plan.amplitudes, dtype=float)
        g.attrs["frequencies"] = np.asarray(plan.frequencies, dtype=float)
        g.attrs["description"] = "experiment k (group experiments/exp_k) drives the plant with " \
                                 "amplitude[k]*sin(2*pi*frequency[k]*t) from rest"
        f.create_group("experiments")

    write_hdf5(path, edit, None)
    return path


def experiment_group_name(index: int) -> str:
    return f"exp_{index:04d}"


def add_experiments(path: str | Path, results: Iterable[ExperimentResult]) -> None:
    """Store finished experiments (one atomic rewrite for all of them)."""
    path = Path(path)
    results = list(results)

    def edit(f):
        exps = f["experiments"]
        for r in results:
            name = experiment_group_name(r.index)
            if name in exps:  # a resumed run never recomputes a stored experiment; keep the first
                continue
            g = exps.create_group(name)
            _set_attrs(g, {
                "index": np.int64(r.index), "amplitude": r.amplitude, "frequency": r.frequency,
                "excitation": r.excitation, "U1": np.complex128(r.U1), "V1": np.complex128(r.V1),
                "H": np.complex128(r.H), "dc": r.dc, "distortion": r.distortion, "converged": bool(r.converged),
                "settling_time": r.settling_time, "last_change": r.last_change,
                "remaining_error": r.remaining_error, "window_start": r.window_start,
                "window_periods": np.int64(r.window_periods), "samples_per_period": np.int64(r.samples_per_period),
                "hold_error": r.hold_error, "noise_sigma": r.noise_sigma,
                "H_noisy": None if r.H_noisy is None else np.complex128(r.H_noisy), "dc_noisy": r.dc_noisy,
                "units": {k: v for k, v in RESULT_UNITS.items()},
            })
            store_array(g, "harmonics", np.asarray(r.harmonics, dtype=complex),
                        description="phasors S_1..S_K of v over the window (m/s)")
            _write_series(g.create_group("transient"), r.transient)
            _write_series(g.create_group("window"), r.window)

    write_hdf5(path, edit, path)


def mark_complete(path: str | Path) -> None:
    path = Path(path)

    def edit(f):
        f.attrs["complete"] = True

    write_hdf5(path, edit, path)


def write_records(path: str | Path, records: list[Record], provenance: dict, append: bool = False,
                  overwrite: bool = False) -> Path:
    """A records file with ``records`` (or, with ``append``, the existing one plus ``records``); without either
    ``append`` or ``overwrite``, an existing file is refused."""
    path = Path(path)
    if append and path.exists():
        existing = read_data_file(path)
        if existing.kind != "records":
            raise UserError(f"{path}: is a {existing.kind} file; records can only be appended to a records file")
        offset = len(existing.records)
    else:
        check_output_path(path, overwrite=overwrite)
        offset = 0

    start_from = path if (append and path.exists()) else None

    def edit(f):
        if start_from is None:
            _write_header(f, "records", provenance, {})
            f.attrs["complete"] = True
            f.create_group("records")
        else:
            prov = f["provenance"]
            appended = json.loads(hdf5_attr(prov, "appended_by", "[]")) + [provenance.get("command", "")]
            _set_attrs(prov, {"appended_by": appended})
            if hdf5_attr(f, "schema_version") < 2:  # upgrade: say what the old records meant
                for g in f["records"].values():
                    g.attrs["intersample"] = "foh"
                f.attrs["schema_version"] = SCHEMA_VERSION
        recs = f["records"]
        for i, r in enumerate(records):
            g = recs.create_group(f"rec_{offset + i:04d}")
            _set_attrs(g, {"index": np.int64(offset + i), "name": r.name, "source": r.source,
                           "source_sha256": r.source_sha256, "kind": r.kind, "columns": r.columns,
                           "sample_rate": r.sample_rate, "velocity_estimate": r.velocity_estimate,
                           "velocity_cutoff": r.velocity_cutoff, "sinusoidal": r.analysis is not None,
                           "note": r.note, "intersample": r.intersample, "units": RESULT_UNITS})
            if r.analysis is not None:
                a = r.analysis
                _set_attrs(g, {"frequency": a.frequency, "sine_fraction": a.sine_fraction, "amplitude": a.amplitude,
                               "U1": np.complex128(a.U1), "V1": np.complex128(a.V1), "H": np.complex128(a.H),
                               "dc_u": a.dc_u, "dc": a.dc, "distortion": a.distortion,
                               "converged": bool(a.converged), "settling_time": a.settling_time,
                               "window_start": a.window_start, "window_periods": np.int64(a.window_periods)})
                store_array(g, "harmonics", np.asarray(a.harmonics, dtype=complex))
            _write_series(g, r.series)

    write_hdf5(path, edit, start_from)
    return path


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------
def _read_series(g: h5py.Group) -> Series:
    """The signals of a group: time, the input u and the velocity v are required (KeyError naming the missing one);
    every signal has the length of time."""
    def get(name, required=False):
        if name not in g:
            if required:
                raise KeyError(f"signal {name!r} of {g.name}")
            return None
        values = np.asarray(g[name][()], dtype=float)
        if name != "time" and values.shape != time.shape:
            raise ValueError(f"signal {name!r} of {g.name}: {values.size} samples for {time.size} times")
        return values

    time = np.asarray(get("time", True))
    return Series(time=time, u=get("u", True), v=get("v", True), v_noisy=get("v_noisy"), position=get("position"),
                  reference=get("reference"))


def _read_experiment(g: h5py.Group) -> ExperimentResult:
    return ExperimentResult(
        index=int(hdf5_attr(g, "index")), amplitude=float(hdf5_attr(g, "amplitude")), frequency=float(hdf5_attr(g, "frequency")),
        excitation=str(hdf5_attr(g, "excitation")), U1=complex(hdf5_attr(g, "U1")), V1=complex(hdf5_attr(g, "V1")),
        H=complex(hdf5_attr(g, "H")), dc=float(hdf5_attr(g, "dc")), harmonics=np.asarray(g["harmonics"][()]),
        distortion=float(hdf5_attr(g, "distortion")), converged=bool(hdf5_attr(g, "converged")),
        settling_time=float(hdf5_attr(g, "settling_time")), last_change=float(hdf5_attr(g, "last_change")),
        remaining_error=float(hdf5_attr(g, "remaining_error")), window_start=float(hdf5_attr(g, "window_start")),
        window_periods=int(hdf5_attr(g, "window_periods")), samples_per_period=int(hdf5_attr(g, "samples_per_period")),
        hold_error=float(hdf5_attr(g, "hold_error")), transient=_read_series(g["transient"]),
        window=_read_series(g["window"]), noise_sigma=hdf5_attr(g, "noise_sigma", None),
        H_noisy=complex(hdf5_attr(g, "H_noisy")) if "H_noisy" in g.attrs else None,
        dc_noisy=hdf5_attr(g, "dc_noisy", None))


def _read_record(g: h5py.Group, version: int) -> Record:
    analysis = None
    if bool(hdf5_attr(g, "sinusoidal")):
        analysis = RecordAnalysis(
            frequency=float(hdf5_attr(g, "frequency")), sine_fraction=float(hdf5_attr(g, "sine_fraction")),
            amplitude=float(hdf5_attr(g, "amplitude")), U1=complex(hdf5_attr(g, "U1")), V1=complex(hdf5_attr(g, "V1")),
            H=complex(hdf5_attr(g, "H")), dc_u=float(hdf5_attr(g, "dc_u")), dc=float(hdf5_attr(g, "dc")),
            harmonics=np.asarray(g["harmonics"][()]), distortion=float(hdf5_attr(g, "distortion")),
            converged=bool(hdf5_attr(g, "converged")), settling_time=float(hdf5_attr(g, "settling_time")),
            window_start=float(hdf5_attr(g, "window_start")), window_periods=int(hdf5_attr(g, "window_periods")))
    cutoff = hdf5_attr(g, "velocity_cutoff", None)
    return Record(index=int(hdf5_attr(g, "index")), name=str(hdf5_attr(g, "name")), source=str(hdf5_attr(g, "source")),
                  source_sha256=str(hdf5_attr(g, "source_sha256")), kind=str(hdf5_attr(g, "kind")),
                  columns=json.loads(hdf5_attr(g, "columns")), series=_read_series(g),
                  sample_rate=float(hdf5_attr(g, "sample_rate")), velocity_estimate=str(hdf5_attr(g, "velocity_estimate")),
                  velocity_cutoff=None if cutoff is None else float(cutoff), analysis=analysis,
                  note=str(hdf5_attr(g, "note", "")),
                  intersample=str(hdf5_attr(g, "intersample")) if version >= 2 else "foh")


def check_stored_data(path: Path, f: h5py.File, plan: Plan | None, experiments, records) -> None:
    """The values a data file holds are what servofmu writes (fileio.check_values): finite numbers within
    bounds, signals of one length, and a plan whose per-experiment datasets match it."""
    if plan is not None:
        n = len(plan.experiments)
        for name, values in (("amplitude", [e.amplitude for e in plan.experiments]),
                             ("frequency", [e.frequency for e in plan.experiments])):
            stored = check_values(path, f"plan/{name}", f["plan"][name][()], (None,))
            if stored.shape != (n,) or not np.array_equal(stored, values):
                raise UserError(f"{path}: plan/{name} does not match the plan's {len(plan.amplitudes)} amplitudes × "
                                f"{len(plan.frequencies)} frequencies (a damaged or foreign file)")

    def series(where: str, s: Series) -> None:
        for name, values in s.signals().items():
            check_values(path, f"{where}/{name}", values, (s.time.size,))

    for e in experiments:
        where = experiment_group_name(e.index)
        for name in ("amplitude", "frequency", "U1", "V1", "H", "dc", "settling_time", "window_start",
                     "hold_error", "noise_sigma", "H_noisy", "dc_noisy"):
            if getattr(e, name) is not None:
                check_values(path, f"{where}/{name}", getattr(e, name), ())
        for name in ("distortion", "last_change", "remaining_error"):  # inf when it did not settle
            check_values(path, f"{where}/{name}", getattr(e, name), (), finite=False)
        check_values(path, f"{where}/harmonics", e.harmonics, (None,))
        series(f"{where}/transient", e.transient)
        series(f"{where}/window", e.window)
    for r in records:
        where = f"rec_{r.index:04d}"
        series(where, r.series)
        check_values(path, f"{where}/sample_rate", r.sample_rate, ())
        if r.analysis is not None:
            for name in ("frequency", "amplitude", "U1", "V1", "dc_u", "dc", "settling_time", "window_start"):
                check_values(path, f"{where}/{name}", getattr(r.analysis, name), ())
            check_values(path, f"{where}/H", r.analysis.H, (), finite=False)  # NaN when U1 is 0
            check_values(path, f"{where}/harmonics", r.analysis.harmonics, (None,))


def read_data_file(path: str | Path) -> DataFile:
    """Read a data file written by ``measure`` or ``import``.

    Parameters
    ----------
    path : str or Path
        The data file (HDF5).

    Returns
    -------
    DataFile
        Its plan, experiments, records and provenance.

    Raises
    ------
    UserError
        For a missing, foreign, newer or damaged file (the message names it).

    Examples
    --------
    >>> from servofmu import read_data_file
    >>> data = read_data_file("g1.h5")                        # doctest: +SKIP
    >>> data.kind, len(data.experiments)                      # doctest: +SKIP
    ('measurement', 6)
    """
    path = Path(path)
    with open_hdf5(path, "data file") as f:
        _, version = check_format(f, path, FORMAT, SCHEMA_VERSION, "data file")
        try:
            kind = str(hdf5_attr(f, "kind"))
            if kind not in KINDS:
                raise KeyError(f"kind {kind!r}")
            plan = None
            if "plan" in f:
                plan = Plan(tuple(float(x) for x in f["plan"].attrs["amplitudes"]),
                            tuple(float(x) for x in f["plan"].attrs["frequencies"]))
            experiments = tuple(sorted((_read_experiment(g) for g in f.get("experiments", {}).values()),
                                       key=lambda e: e.index))
            records = tuple(sorted((_read_record(g, version) for g in f.get("records", {}).values()),
                                   key=lambda r: r.index))
            bad = [r.intersample for r in records if r.intersample not in INTERSAMPLE]
            if bad:
                raise ValueError(f"intersample {bad[0]!r}")
            prov = f["provenance"]
            provenance = {k: hdf5_attr(prov, k) for k in prov.attrs}
            parameters = {k: float(hdf5_attr(prov["parameters"], k)) for k in prov["parameters"].attrs} \
                if "parameters" in prov else {}
            complete = bool(hdf5_attr(f, "complete"))
            check_stored_data(path, f, plan, experiments, records)
        except UserError:
            raise
        except READ_ERRORS as exc:
            raise UserError(f"{path}: damaged servofmu data file ({read_error_reason(exc)})") from exc
        if plan is not None:
            specs = {s.index: s for s in plan.experiments}
            for e in experiments:
                s = specs.get(e.index)
                if s is None or (s.amplitude, s.frequency) != (e.amplitude, e.frequency):
                    raise UserError(f"{path}: damaged servofmu data file (experiment {e.index} is not in the plan)")
    return DataFile(path=path, kind=kind, schema_version=version, complete=complete, plan=plan,
                   experiments=experiments, records=records, provenance=provenance, parameters=parameters)
