"""The data file: one self-describing HDF5 file per measurement or set of records (layout in docs/hdf5.md).

Every write builds the new file beside the target (``.NAME.part``) and renames it over the target in one
step, so a killed run leaves either the previous file or a complete new one.  A measurement file is
written when the run starts (plan + provenance, no experiments), again after every finished experiment,
and a last time to mark it complete; ``--resume`` reads which experiments are stored and runs the others.

What an experiment's or a record's group holds is declared once, on the fields of ExperimentResult,
RecordAnalysis and Record (servofmu.measurement.schema); the writer, the reader and the checks of the stored numbers all
follow those declarations.
"""
from __future__ import annotations

import json
from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path
from typing import Iterable

import h5py
import numpy as np

from ..display import Shown, shown_html, shown_repr
from ..errors import UserError
from ..fileio import (
    READ_ERRORS,
    check_output_path,
    check_values,
    hdf5_attr,
    read_error_reason,
    read_hdf5,
    store_array,
    write_hdf5,
)
from ..model.signals import INTERSAMPLE
from .excitation import ExperimentSpec, Plan
from .shown import data_file_shown, experiment_shown, record_shown
from .schema import (
    BOUNDED,
    DATASET,
    FINITE,
    NESTED,
    SIGNALS,
    STORED,
    check_fields,
    read_fields,
    set_attrs,
    stored,
    write_fields,
)

__all__ = ["DataFile", "Series", "ExperimentResult", "RecordAnalysis", "Record", "read_data_file",
           "create_measurement", "add_experiments", "mark_complete", "write_records", "experiment_group_name",
           "FORMAT", "SCHEMA_VERSION", "READ_VERSION", "KINDS", "write_header", "as_data_file", "data_name",
           "records_in_memory"]

FORMAT = "servofmu-data"
# 2: records carry their intersample behaviour ("intersample": "zoh" or "foh"); version 1 files are read as
# "foh", what servofmu assumed when it wrote them (a version 1 file that is appended to is upgraded).
SCHEMA_VERSION = 2
# 3: the kind "broadband" (servofmu.broadband.store; written as version 3). Measurements and records are still
# written as version 2, which older servofmu reads.
READ_VERSION = 3
KINDS = ("measurement", "records", "broadband")

SIGNAL_INFO = {
    "time": ("s", "time"),
    "u": ("N", "input force driving the plant (for built-in excitation: u + excitation_amplitude*sin(2*pi*"
               "excitation_frequency*t); for input-port drive: the value held on [t, t + interval))"),
    "v": ("m/s", "velocity, the plant output"),
    "v_noisy": ("m/s", "v plus white Gaussian measurement noise (see noise_sigma)"),
    "position": ("m", "measured position (raw, as recorded)"),
    "reference": ("m", "reference position of the drive's controller (closed-loop records)"),
    "disturbance": ("N", "known force the drive adds to its controller's output after the output limit (an "
                         "injected test signal; closed-loop records); u includes it"),
}
# The units of the numbers an experiment or a record stores: also written, as is, as each group's "units" attribute.
RESULT_UNITS = {
    "amplitude": "N", "frequency": "Hz", "U1": "N", "V1": "m/s", "H": "m/(N.s)", "dc": "m/s", "dc_u": "N",
    "distortion": "1", "settling_time": "s", "window_start": "s", "window_periods": "1", "hold_error": "1",
    "last_change": "1", "remaining_error": "1", "noise_sigma": "m/s", "H_noisy": "m/(N.s)", "dc_noisy": "m/s",
    "sample_rate": "Hz", "sine_fraction": "1", "velocity_cutoff": "Hz", "samples_per_period": "1",
    "time_step": "s", "time_jitter": "s", "time_jitter_max": "s", "input_scale": "N per unit of the column",
    "disturbance_scale": "N per unit of the column",
}


# ---------------------------------------------------------------------------
# What is stored: every field declared once, with how it is stored
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
    disturbance: np.ndarray | None = None

    def signals(self) -> dict[str, np.ndarray]:
        """The signals present, by name, in the order of the fields."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class ExperimentResult:
    """One stepped-sine experiment of a measurement (docs/measurement.md defines every field)."""

    index: int = stored(dtype=int)
    amplitude: float = stored(check=FINITE)
    frequency: float = stored(check=FINITE)
    excitation: str = stored(dtype=str)   # "builtin" or "input"
    U1: complex = stored(dtype=complex, check=FINITE)
    V1: complex = stored(dtype=complex, check=FINITE)
    H: complex = stored(dtype=complex, check=FINITE)
    dc: float = stored(check=FINITE)
    harmonics: np.ndarray = stored(kind=DATASET, dtype=complex, check=FINITE,  # S_1..S_K of v
                                   description="phasors S_1..S_K of v over the window (m/s)")
    distortion: float = stored(check=BOUNDED)        # inf when it did not settle
    converged: bool = stored(dtype=bool)
    settling_time: float = stored(check=FINITE)
    last_change: float = stored(check=BOUNDED)       # inf when it did not settle
    remaining_error: float = stored(check=BOUNDED)   # inf when it did not settle
    window_start: float = stored(check=FINITE)
    window_periods: int = stored(dtype=int)
    samples_per_period: int = stored(dtype=int)
    hold_error: float = stored(check=FINITE)
    transient: Series = stored(kind=SIGNALS)
    window: Series = stored(kind=SIGNALS)
    noise_sigma: float | None = stored(None, check=FINITE)
    H_noisy: complex | None = stored(None, dtype=complex, check=FINITE)
    dc_noisy: float | None = stored(None, check=FINITE)

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return experiment_shown(self)

    @property
    def spec(self) -> ExperimentSpec:
        """The experiment of the plan that this is the result of."""
        return ExperimentSpec(self.index, self.amplitude, self.frequency)


@dataclass(frozen=True)
class RecordAnalysis:
    """First-harmonic analysis of a sinusoidal record (same meaning as for an experiment)."""

    frequency: float = stored(check=FINITE)
    sine_fraction: float = stored()
    amplitude: float = stored(check=FINITE)
    U1: complex = stored(dtype=complex, check=FINITE)
    V1: complex = stored(dtype=complex, check=FINITE)
    H: complex = stored(dtype=complex, check=BOUNDED)  # NaN when U1 is 0
    dc_u: float = stored(check=FINITE)
    dc: float = stored(check=FINITE)
    harmonics: np.ndarray = stored(kind=DATASET, dtype=complex, check=FINITE)
    distortion: float = stored()
    converged: bool = stored(dtype=bool)
    settling_time: float = stored(check=FINITE)
    window_start: float = stored(check=FINITE)
    window_periods: int = stored(dtype=int)


@dataclass(frozen=True)
class Record:
    """A record imported from a machine: raw signals, the velocity used, and its analysis if sinusoidal."""

    index: int = stored(dtype=int)
    name: str = stored(dtype=str)
    source: str = stored(dtype=str)
    source_sha256: str = stored(dtype=str)
    kind: str = stored(dtype=str)                   # "velocity" or "position"
    columns: dict = stored(dtype=dict)              # role (time/u/v or position) -> column name in the source
    series: Series = stored(kind=SIGNALS, inline=True)
    sample_rate: float = stored(check=FINITE)
    velocity_estimate: str = stored(dtype=str)      # how v was obtained
    velocity_cutoff: float | None = stored(optional=True)
    analysis: RecordAnalysis | None = stored(kind=NESTED, nested=RecordAnalysis, flag="sinusoidal")
    note: str = stored("", dtype=str)
    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return record_shown(self)

    # the input between samples: held ("zoh") or linear ("foh"); schema version 1 files meant "foh"
    intersample: str = stored("zoh", optional=False, dtype=str, choices=INTERSAMPLE, since=2, before="foh")
    # the time stamps as logged, measured against their least-squares grid (servofmu.measurement.clock): its step
    # (s) and the stamps' RMS and largest deviation from it (s); absent in files written before they were stored
    time_step: float | None = stored(None, check=FINITE)
    time_jitter: float | None = stored(None, check=FINITE)
    time_jitter_max: float | None = stored(None, check=FINITE)
    # the factors that made forces of the logged columns (N per unit of the log, e.g. N/V): u and the disturbance
    input_scale: float | None = stored(None, check=FINITE)
    disturbance_scale: float | None = stored(None, check=FINITE)


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
    sha256: str = ""  # of the bytes read (the file as it was parsed; provenance records this)

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return data_file_shown(self)

    def missing(self) -> tuple[ExperimentSpec, ...]:
        """The experiments of the plan not stored yet (what ``--resume`` runs)."""
        done = {e.index for e in self.experiments}
        return tuple(s for s in self.plan.experiments if s.index not in done) if self.plan else ()

    def experiment(self, amplitude: float, frequency: float) -> ExperimentResult:
        """The stored experiment at ``amplitude`` (N) and ``frequency`` (Hz); KeyError if there is none."""
        for e in self.experiments:
            if e.amplitude == amplitude and e.frequency == frequency:
                return e
        raise KeyError((amplitude, frequency))


# ---------------------------------------------------------------------------
# Atomic writes
# ---------------------------------------------------------------------------
def _write_series(group: h5py.Group, series: Series) -> None:
    for name, data in series.signals().items():
        unit, description = SIGNAL_INFO[name]
        store_array(group, name, np.asarray(data, dtype=float), unit=unit, description=description)


def write_header(f: h5py.File, kind: str, provenance: dict, parameters: dict,
                 version: int = SCHEMA_VERSION) -> None:
    """The root attributes (format, schema ``version``, ``kind``, not yet complete) and the provenance group of a
    new data file."""
    f.attrs["format"] = FORMAT
    f.attrs["schema_version"] = version
    f.attrs["kind"] = kind
    f.attrs["complete"] = False
    prov = f.create_group("provenance")
    set_attrs(prov, provenance)
    par = prov.create_group("parameters")
    set_attrs(par, {k: float(v) for k, v in parameters.items()})


def create_measurement(path: str | Path, plan: Plan, provenance: dict, parameters: dict) -> Path:
    """A new measurement file with its plan and provenance and no experiments yet."""
    path = check_output_path(path)

    def edit(f):
        write_header(f, "measurement", provenance, parameters)
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
    """The group of experiment ``index`` under ``experiments``."""
    return f"exp_{index:04d}"


def record_group_name(index: int) -> str:
    """The group of record ``index`` under ``records``."""
    return f"rec_{index:04d}"


def add_experiments(path: str | Path, results: Iterable[ExperimentResult]) -> None:
    """Store finished experiments (one atomic rewrite for all of them)."""
    path = Path(path)
    results = list(results)
    for r in results:  # the readers' bounds, before the first byte: a file no reader opens is never written
        check_fields(path, experiment_group_name(r.index), r, why="not written")

    def edit(f):
        exps = f["experiments"]
        for r in results:
            name = experiment_group_name(r.index)
            if name in exps:  # a resumed run never recomputes a stored experiment; keep the first
                continue
            write_fields(exps.create_group(name), r, _write_series, units=RESULT_UNITS)

    write_hdf5(path, edit, path)


def mark_complete(path: str | Path) -> None:
    """Mark a measurement file complete: every experiment of its plan is stored."""
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
    for i, r in enumerate(records):  # the readers' bounds, before the first byte: a file no reader opens (or an
        # appended one whose good records are lost) is never written
        check_fields(r.source or path, f"record {record_group_name(offset + i)}", r,
                     why=f"not written to {path}: check the column and its scale")

    start_from = path if (append and path.exists()) else None

    def edit(f):
        if start_from is None:
            write_header(f, "records", provenance, {})
            f.attrs["complete"] = True
            f.create_group("records")
        else:
            prov = f["provenance"]
            appended = json.loads(hdf5_attr(prov, "appended_by", "[]")) + [provenance.get("command", "")]
            set_attrs(prov, {"appended_by": appended})
            version = hdf5_attr(f, "schema_version")
            if version < SCHEMA_VERSION:  # upgrade: say what the old records meant
                for g in f["records"].values():
                    set_attrs(g, {f.name: f.metadata[STORED].before for f in fields(Record)
                                  if f.metadata[STORED].since > version})
                f.attrs["schema_version"] = SCHEMA_VERSION
        recs = f["records"]
        for i, r in enumerate(records):
            write_fields(recs.create_group(record_group_name(offset + i)), r, _write_series, units=RESULT_UNITS,
                         index=offset + i)

    write_hdf5(path, edit, start_from)
    return path


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------
def _read_series(g: h5py.Group) -> Series:
    """The signals of a group: those without a default in Series (time, the input u and the velocity v) are
    required (KeyError naming the missing one); every signal has the length of time."""
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
    return Series(time=time, **{f.name: get(f.name, f.default is MISSING) for f in fields(Series)[1:]})


def check_stored_data(path: Path, f: h5py.File, plan: Plan | None, experiments, records) -> None:
    """The values a data file holds are what servofmu writes (fileio.check_values): finite numbers within
    bounds, signals of one length, and a plan whose per-experiment datasets match it."""
    if plan is not None:
        n = len(plan.experiments)
        for name, values in (("amplitude", [e.amplitude for e in plan.experiments]),
                             ("frequency", [e.frequency for e in plan.experiments])):
            stored_values = check_values(path, f"plan/{name}", f["plan"][name][()], (None,))
            if stored_values.shape != (n,) or not np.array_equal(stored_values, values):
                raise UserError(f"{path}: plan/{name} does not match the plan's {len(plan.amplitudes)} amplitudes × "
                                f"{len(plan.frequencies)} frequencies (a damaged or foreign file)")
    for e in experiments:
        check_fields(path, experiment_group_name(e.index), e)
    for r in records:
        check_fields(path, record_group_name(r.index), r)


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
    from ..api_checks import check_arguments

    check_arguments(read_data_file, locals())  # a wrong type: UserError naming it
    path = Path(path)
    data, sha256 = read_hdf5(path, "data file", FORMAT, READ_VERSION,
                             lambda f, version: _read_data(path, f, version), with_sha256=True)
    return replace(data, sha256=sha256)


def as_data_file(data) -> DataFile:
    """``data`` itself when it is a DataFile (held in memory or read before), else the data file at that path."""
    return data if isinstance(data, DataFile) else read_data_file(data)


def data_name(data) -> str:
    """What names ``data`` (a path or a DataFile) in provenance and messages: the path it was read from or the
    name it was given in memory."""
    return str(data.path) if isinstance(data, DataFile) else str(data)


def records_in_memory(records: Iterable[Record], name: str, provenance: dict | None = None) -> DataFile:
    """A data file of kind records held in memory (never written): ``name`` stands for its path in messages and
    provenance, and its digest is that of its records' samples (the SHA-256 of a file's bytes otherwise)."""
    import hashlib

    records = tuple(records)
    if not records:
        raise UserError(f"{name}: holds no records")
    digest = hashlib.sha256("".join(r.source_sha256 for r in records).encode()).hexdigest()
    return DataFile(path=Path(name), kind="records", schema_version=SCHEMA_VERSION, complete=True, plan=None,
                    experiments=(), records=records, provenance=dict(provenance or {}), sha256=digest)


def _read_data(path: Path, f: h5py.File, version: int) -> DataFile:
    """The contents of the open data file ``f`` (schema ``version``); a missing or malformed item is a UserError
    naming ``path``: ``damaged servofmu data file (reason)``."""
    try:
        kind = str(hdf5_attr(f, "kind"))
        if kind not in KINDS:
            raise KeyError(f"kind {kind!r}")
        plan = None
        if "plan" in f:
            plan = Plan(tuple(float(x) for x in f["plan"].attrs["amplitudes"]),
                        tuple(float(x) for x in f["plan"].attrs["frequencies"]))
        experiments = tuple(sorted((read_fields(ExperimentResult, g, version, _read_series)
                                    for g in f.get("experiments", {}).values()), key=lambda e: e.index))
        records = tuple(sorted((read_fields(Record, g, version, _read_series) for g in f.get("records", {}).values()),
                               key=lambda r: r.index))
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
