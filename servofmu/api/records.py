"""Records held in memory: a machine's log handed over as arrays or a pandas DataFrame, looked at, cut, detrended,
resampled and merged before it is fitted — what MATLAB's ``iddata`` does, for servofmu's records.

A :class:`Records` is a tuple of the very :class:`~servofmu.measurement.datafile.Record` objects that ``servofmu
import`` writes: every record is made and checked by the same code as a file's (servofmu.measurement.records:
the velocity estimate of a position, the clock, the first-harmonic analysis), so that ``save`` writes the data
file ``import`` would have written and ``load`` reads any records file back.  Each operation returns new records,
made again from the changed samples.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError
from ..measurement.datafile import DataFile, Record, read_data_file, records_in_memory, write_records
from ..measurement.duplicates import TWICE, first_repeat, series_digest
from ..measurement.records import record_from_arrays
from ..runtime import optional_import, utc_now
from ..version import __version__

if TYPE_CHECKING:
    import pandas

__all__ = ["Records", "DETREND"]

DETREND = ("constant", "linear")
# what each role of a record is called in a DataFrame made by to_dataframe (and read by from_dataframe by default)
FRAME_COLUMNS = {"time": "time", "u": "input", "output": "output", "reference": "reference",
                 "disturbance": "disturbance"}


def _output(r: Record) -> np.ndarray:
    """The signal a record was given as: the position of a position record, else the velocity."""
    return r.series.position if r.kind == "position" else r.series.v


def _remade(r: Record, cutoff: float | None = None, **signals) -> Record:
    """``r`` made again (velocity estimate, clock, analysis) from its samples with ``signals`` changed (and the
    velocity estimate's cut-off ``cutoff``, default the record's)."""
    s = r.series
    values = {"time": s.time, "input": s.u, "output": _output(r), "reference": s.reference,
              "disturbance": s.disturbance, **signals}
    again = record_from_arrays(r.name, values["time"], values["input"], values["output"], kind=r.kind,
                               reference=values["reference"], disturbance=values["disturbance"],
                               cutoff=cutoff or r.velocity_cutoff, index=r.index, intersample=r.intersample)
    return replace(again, input_scale=r.input_scale, disturbance_scale=r.disturbance_scale, source=r.source,
                   columns=r.columns)


@dataclass(frozen=True, repr=False)
class Records:
    """Records of one axis held in memory (each a time, the input force and a velocity or position, and for a
    drive's log the reference and the injected disturbance), fitted, validated and saved as a records file is.

    Build them with :meth:`from_arrays`, :meth:`from_dataframe` or :meth:`load`; every method returns new
    Records.

    Parameters
    ----------
    records : tuple of Record
        The records (servofmu.measurement.datafile.Record), each made as ``import`` makes one.
    name : str
        What stands for the file in messages and in a result's provenance.
    """

    records: tuple[Record, ...]
    name: str = "records"

    def __post_init__(self):
        if not self.records:
            raise UserError(f"{self.name}: holds no records")
        repeat = first_repeat([(f"record {r.name!r}", series_digest(r.series)) for r in self.records])
        if repeat is not None:
            raise UserError(f"{self.name}: {repeat[0]} holds the same samples as {repeat[1]}: {TWICE}")

    # ----------------------------------------------------------------------------------------------------------
    # Building
    # ----------------------------------------------------------------------------------------------------------
    @classmethod
    def from_arrays(cls, time: ArrayLike, input: ArrayLike, output: ArrayLike, *, kind: str = "velocity",
                    reference: ArrayLike | None = None, disturbance: ArrayLike | None = None,
                    name: str = "record", intersample: str = "zoh", cutoff: float | None = None,
                    frequency: float | None = None, input_scale: float = 1.0,
                    disturbance_scale: float = 1.0) -> Records:
        """One record from arrays.

        Parameters
        ----------
        time : array_like
            Time stamps (s), strictly increasing.
        input : array_like
            The force driving the axis (N, or units that ``input_scale`` N/unit turns into newtons).
        output : array_like
            The velocity (m/s, ``kind="velocity"``) or the position (m, ``kind="position"``: a zero-phase velocity
            estimate is made beside it, as ``import`` makes it).
        kind : {"velocity", "position"}
            What ``output`` is.
        reference, disturbance : array_like, optional
            A drive's log: the reference position (m) its controller followed and a known force it added after
            its output limit (units that ``disturbance_scale`` turns into newtons); with a reference the record is
            a closed-loop one (identify and select with ``controller=``).
        name : str
            The record's name.
        intersample : {"zoh", "foh"}
            The input between samples: held (a digital drive's command) or linear.
        cutoff : float, optional
            The velocity estimate's low-pass cut-off (Hz) for a position (default a tenth of the sample rate).
        frequency : float, optional
            The excitation frequency of a sinusoidal record, when it is not to be detected.

        Raises
        ------
        UserError
            For arrays that are not one-dimensional real numbers of one length, NaN or infinite values, a time
            that does not increase, or a position or drive log off a regular clock; the message names the array.
        """
        record = record_from_arrays(name, time, input, output, kind=kind, reference=reference,
                                    disturbance=disturbance, cutoff=cutoff, frequency=frequency,
                                    intersample=intersample, input_scale=input_scale,
                                    disturbance_scale=disturbance_scale)
        return cls((record,), name)

    @classmethod
    def from_dataframe(cls, frame: object, input: str = "input", output: str = "output", *, time: str | None = None,
                       reference: str | None = None, disturbance: str | None = None, kind: str = "velocity",
                       name: str = "record", **options: object) -> Records:
        """One record from the columns of a pandas DataFrame (or any mapping of column names to arrays).

        ``time`` names the time column (s); None takes the frame's index.  ``input``, ``output``, ``reference``
        and ``disturbance`` name the other columns; ``options`` are those of :meth:`from_arrays`.  A column
        that is not in the frame is a UserError naming it and the columns there are.
        """
        columns = list(getattr(frame, "columns", frame))
        wanted = {"input": input, "output": output, "time": time, "reference": reference,
                  "disturbance": disturbance}
        for role, column in wanted.items():
            if column is not None and column not in columns:
                raise UserError(f"{name}: no column {column!r} ({role}=) in the frame (it has "
                                f"{', '.join(map(str, columns)) or 'none'})")
        values = {role: None if column is None else np.asarray(frame[column]) for role, column in wanted.items()}
        if values["time"] is None:
            if not hasattr(frame, "index"):
                raise UserError(f"{name}: give time= (the frame has no index)")
            values["time"] = np.asarray(frame.index, dtype=float)
        return cls.from_arrays(values["time"], values["input"], values["output"], kind=kind,
                               reference=values["reference"], disturbance=values["disturbance"], name=name,
                               **options)

    @classmethod
    def load(cls, path: str | Path) -> Records:
        """The records of a records file (``servofmu import``, ``cosim``, or :meth:`save`)."""
        ds = read_data_file(path)
        if ds.kind != "records":
            raise UserError(f"{path}: is a {ds.kind} file, not records")
        return cls(ds.records, Path(path).stem)

    @classmethod
    def merge(cls, *parts: Records, name: str | None = None) -> Records:
        """Several Records as one set of experiments of the axis (fitted jointly); where names repeat, every
        record is named by its place ("a-1", "a-2", ...)."""
        records = [r for p in parts for r in p.records]
        if not records:
            raise UserError("merge: no records given")
        names = [r.name for r in records]
        if len(set(names)) < len(names):
            records = [replace(r, name=f"{r.name}-{i + 1}") for i, r in enumerate(records)]
        records = [replace(r, index=i) for i, r in enumerate(records)]
        return cls(tuple(records), name or "+".join(p.name for p in parts))

    # ----------------------------------------------------------------------------------------------------------
    # Looking at them
    # ----------------------------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self):
        return iter(self.records)

    def __getitem__(self, key: int | str) -> Records:
        """One record, by position or name, as Records."""
        if isinstance(key, str):
            found = [r for r in self.records if r.name == key]
            if not found:
                raise UserError(f"{self.name}: no record {key!r} (it has {', '.join(self.names)})")
            return Records((replace(found[0], index=0),), key)
        if not isinstance(key, (int, np.integer)) or not -len(self) <= key < len(self):
            raise UserError(f"{self.name}: record index {key!r} out of range (it holds {len(self)})")
        r = self.records[key]
        return Records((replace(r, index=0),), r.name)

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        rs = self.records
        total = sum(r.series.time.size for r in rs)
        seconds = sum(float(r.series.time[-1] - r.series.time[0]) for r in rs)
        kinds = sorted({r.kind for r in rs})
        head = (f"{self.name!r}: {len(rs)} record{'s' * (len(rs) != 1)} of {'/'.join(kinds)}"
                f"{', closed loop' if self.closed_loop else ''}")
        figures = (figure("samples", total), figure("duration", seconds, "s"),
                   figure("sample rate", rs[0].sample_rate, "Hz"))
        table = figures + tuple(figure(f"{r.name}", float(r.series.time[-1] - r.series.time[0]), "s")
                                for r in rs[:12])
        return Shown("Records", head, figures, table, (f"{len(rs) - 12} more records",) if len(rs) > 12 else ())

    @property
    def names(self) -> list[str]:
        """The records' names."""
        return [r.name for r in self.records]

    @property
    def closed_loop(self) -> bool:
        """Whether the records are a drive's logs (they have a reference)."""
        return all(r.series.reference is not None for r in self.records)

    def to_dataframe(self, record: int | str = 0) -> pandas.DataFrame:
        """One record's signals as a pandas DataFrame indexed by time (s); columns input (N), output (m or m/s),
        velocity (m/s) and the log's reference and disturbance when present."""
        pd = optional_import("pandas", "Records.to_dataframe", "notebook", package="pandas")
        r = self[record].records[0]
        s = r.series
        columns = {"input": s.u, "output": _output(r), "velocity": s.v, "reference": s.reference,
                   "disturbance": s.disturbance}
        return pd.DataFrame({k: v for k, v in columns.items() if v is not None},
                            index=pd.Index(s.time, name="time"))

    def to_data_file(self) -> DataFile:
        """The records as the data file ``save`` would write, held in memory (what identify, select and validate
        take)."""
        return records_in_memory(self.records, self.name, {"package": "servofmu", "sources": self.names})

    def frf(self, closed_loop: bool = False, segment: int | None = None) -> list:
        """Every record's frequency response (``servofmu frf``): the H1 estimate with its coherence and, for a
        drive's log with ``closed_loop``, the estimate from the reference that its loop's noise does not bias
        (servofmu.broadband.records_frf.RecordFrf)."""
        from ..broadband.records_frf import records_frf

        return records_frf(self.to_data_file(), closed_loop, segment)[1]

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Write the records file (docs/hdf5.md) that :meth:`load` and every command read."""
        provenance = {"package": "servofmu", "package_version": __version__, "command": "Records.save",
                      "created": utc_now(), "sources": [r.source for r in self.records]}
        return write_records(path, list(self.records), provenance, overwrite=overwrite)

    # ----------------------------------------------------------------------------------------------------------
    # Changing them
    # ----------------------------------------------------------------------------------------------------------
    def between(self, start: float | None = None, stop: float | None = None) -> Records:
        """The samples with ``start`` ≤ t ≤ ``stop`` (s) of every record (None: from the first, to the last)."""
        out = []
        for r in self.records:
            t = r.series.time
            keep = (t >= (t[0] if start is None else start)) & (t <= (t[-1] if stop is None else stop))
            out.append(_remade(r, **{k: None if v is None else v[keep] for k, v in _signals(r).items()}))
        return Records(tuple(out), self.name)

    def detrend(self, kind: str = "constant", signals: Sequence[str] = ("input", "output")) -> Records:
        """Records with the mean (``kind="constant"``) or the straight line (``"linear"``) of ``signals`` (among
        "input" and "output") removed, as a least-squares fit over each record.

        Friction makes the mean force physical (it is what the axis needs to move), so detrend only offsets a
        sensor adds.  A drive's log is refused: its controller computed the command from the very reference and
        position a detrend would change.
        """
        if kind not in DETREND:
            raise UserError(f"detrend kind {kind!r}: give one of {', '.join(DETREND)}")
        unknown = [s for s in signals if s not in ("input", "output")]
        if unknown:
            raise UserError(f"detrend signal {unknown[0]!r}: give input and/or output")
        if any(r.series.reference is not None for r in self.records):
            raise UserError(f"{self.name}: a drive's log is not detrended (its command follows from its reference "
                            "and position as logged)")
        out = []
        for r in self.records:
            values = _signals(r)
            t = values["time"]
            changed = {s: values[s] - np.polyval(np.polyfit(t - t[0], values[s], DETREND.index(kind)), t - t[0])
                       for s in signals}
            out.append(_remade(r, **changed))
        return Records(tuple(out), self.name)

    def resample(self, rate: float) -> Records:
        """Every record on a uniform clock of ``rate`` Hz from its first sample.

        Where the rate drops, every signal is first low-passed (zero-phase 8th-order Butterworth at 0.4·rate:
        no phase lag, no aliasing); the samples are then interpolated linearly, except a held input (intersample
        "zoh"), which is held: the value of the last sample at or before each new instant.
        """
        if not (isinstance(rate, (int, float)) and np.isfinite(rate) and rate > 0):
            raise UserError(f"resample rate {rate!r}: give a positive number of Hz")
        return Records(tuple(_resampled(r, float(rate)) for r in self.records), self.name)


def _signals(r: Record) -> dict[str, np.ndarray | None]:
    s = r.series
    return {"time": s.time, "input": s.u, "output": _output(r), "reference": s.reference,
            "disturbance": s.disturbance}


def _resampled(r: Record, rate: float) -> Record:
    from scipy.signal import butter, sosfiltfilt

    values = _signals(r)
    t = values["time"]
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate + 1e-9)) + 1) / rate
    if grid.size < 10:
        raise UserError(f"{r.name}: {grid.size} samples at {rate:g} Hz; give a rate of at least "
                        f"{9 / (t[-1] - t[0]):.3g} Hz")
    slower = rate < 0.999 * r.sample_rate
    sos = butter(8, 0.4 * rate / (0.5 * r.sample_rate), output="sos") if slower else None
    out = {"time": grid}
    for role, v in values.items():
        if role == "time" or v is None:
            continue
        smooth = sosfiltfilt(sos, v) if slower else v
        if role == "input" and r.intersample == "zoh":
            out[role] = smooth[np.clip(np.searchsorted(t, grid + 1e-12 / rate, side="right") - 1, 0, t.size - 1)]
        else:
            out[role] = np.interp(grid, t, smooth)
    cutoff = r.velocity_cutoff
    return _remade(r, cutoff=cutoff if cutoff is None or cutoff < 0.4 * rate else 0.1 * rate, **out)
