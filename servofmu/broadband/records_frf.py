"""The frequency response of records that are not a broadband measurement (`servofmu frf RECORDS.h5`): per record
the direct estimate S_uy/S_uu (H1, Welch) and, for a drive's log with its reference (``--closed-loop``), the
estimate from the reference S_ry/S_ru (servofmu.broadband.bla.closed_loop_estimate), which the loop's noise does
not bias (docs/broadband.md, "Closed loop"); beside them the local polynomial method's estimate on the record's
every DFT line, its transient removed (servofmu.broadband.lpm; from the reference with ``--closed-loop``)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..display import Shown, figure, shown_html, shown_repr
from ..measurement.datafile import DataFile, as_data_file, data_name
from .bla import ClosedLoopEstimate, H1Estimate, closed_loop_estimate, h1_estimate
from .lpm import LpmEstimate, default_half_width, lpm_estimate

__all__ = ["RecordFrf", "records_frf", "records_frf_json", "TRUSTED_COHERENCE", "SEGMENTS", "EXTERNAL_SIGNALS"]

# the external signals of a drive's log that the estimate in its loop may be taken from: independent of the noise
EXTERNAL_SIGNALS = ("reference", "disturbance")
TRUSTED_COHERENCE = 0.9  # γ²_ru at or above which the estimate from the external signal is reported as usable
# a record is cut into this many Welch segments (at least 256 samples each): 63 averages with half overlap, a
# standard deviation of G about a tenth of its size where the coherence is 0.5
SEGMENTS = 32


@dataclass(frozen=True)
class RecordFrf:
    """One record's estimates: ``direct`` (H1 of u → v), ``closed_loop`` (from the reference; None without) and
    ``lpm`` (the local polynomial method's, open loop, or from the reference with ``closed_loop``; None for a record
    too short for its window)."""

    name: str
    samples: int
    rate: float
    direct: H1Estimate
    closed_loop: ClosedLoopEstimate | None
    lpm: LpmEstimate | None = None
    external: str | None = None  # the external signal of ``closed_loop``: "reference" or "disturbance"

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        d = self.direct
        figures = [figure("samples", self.samples), figure("rate", self.rate, "Hz"),
                   figure("band", f"{d.frequencies[0]:.3g}–{d.frequencies[-1]:.3g}", "Hz"),
                   figure("median coherence", float(np.median(d.coherence)))]
        if self.closed_loop is not None:
            figures.append(figure("direct vs from the reference", self.direct_deviation()))
        if self.lpm is not None and self.lpm.frequencies.size:
            figures.append(figure("LPM median σ/|G|", float(np.median(self.lpm.std / np.abs(self.lpm.G)))))
        head = "H1 and from the reference" if self.closed_loop else "H1"
        return Shown("RecordFrf", f"{self.name!r}: {head}{', LPM' if self.lpm is not None else ''}", tuple(figures))

    def direct_deviation(self) -> float:
        """Median |G_direct/G_reference − 1| over the lines where γ²_ru ≥ TRUSTED_COHERENCE (NaN without)."""
        if self.closed_loop is None:
            return math.nan
        cl = self.closed_loop
        good = cl.coherence_ru >= TRUSTED_COHERENCE
        if not good.any():
            return math.nan
        direct = np.interp(cl.frequencies, self.direct.frequencies, self.direct.G.real) + 1j * np.interp(
            cl.frequencies, self.direct.frequencies, self.direct.G.imag)
        return float(np.median(np.abs(direct[good] / cl.G[good] - 1)))


def records_frf(path: str | Path | DataFile, closed_loop: bool = False, segment: int | None = None,
                lpm_order: int = 2, external: str = "reference") -> tuple[DataFile, list[RecordFrf]]:
    """The estimates of every record of a records file (or a DataFile held in memory); with ``closed_loop`` every
    record must have the ``external`` signal — its ``reference``, or the ``disturbance`` injected into the drive's
    output (a test signal, as drives inject for their own frequency response) — and a UserError names the first
    without.  The LPM's polynomials have the degree ``lpm_order`` (its window the default of
    servofmu.broadband.lpm.default_half_width)."""
    data, path = as_data_file(path), data_name(path)
    if data.kind != "records" or not data.records:
        raise UserError(f"{path}: is a {data.kind} file without records; frf takes broadband data or records")
    if external not in EXTERNAL_SIGNALS:
        raise UserError(f"--external {external}: give one of {', '.join(EXTERNAL_SIGNALS)}")
    out = []
    for rec in data.records:
        s = rec.series
        r = getattr(s, external) if closed_loop else None
        if closed_loop and r is None:
            raise UserError(f"{path}: record {rec.name} has no {external}: --closed-loop needs a drive's log "
                            f"imported with --{external} (or co-simulated in its loop)")
        rate = float(rec.sample_rate)
        n = s.u.size
        seg = min(n, int(segment or max(256, n // SEGMENTS)))
        band = (rate / seg, rate / 2)
        direct = h1_estimate(s.u, s.v, rate, seg, band)
        cl = closed_loop_estimate(r, s.u, s.v, rate, seg, band) if closed_loop else None
        lpm = None
        if n >= 4 * default_half_width(lpm_order) + 8:  # the window fits into the record's lines, DC left out
            lpm = lpm_estimate(s.u, s.v, rate, lpm_order, reference=r)
        out.append(RecordFrf(rec.name, n, rate, direct, cl, lpm, external if closed_loop else None))
    return data, out


def _std(var) -> list:
    return [float(x) if math.isfinite(x) else None for x in np.sqrt(np.clip(var, 0, None))]


def records_frf_json(data: DataFile, estimates: list[RecordFrf]) -> dict:
    """The ``--json`` document of records (schema in docs/broadband.md)."""
    doc = {"format": "servofmu-frf", "schema_version": 1, "data": str(data.path), "records": []}
    for e in estimates:
        d = e.direct
        entry = {"name": e.name, "samples": e.samples, "rate": e.rate,
                 "direct": {"frequency": d.frequencies.tolist(), "re": d.G.real.tolist(), "im": d.G.imag.tolist(),
                            "std": _std(d.var), "coherence": d.coherence.tolist(), "segments": d.segments},
                 "closed_loop": None}
        if e.closed_loop is not None:
            c = e.closed_loop
            dev = e.direct_deviation()
            entry["closed_loop"] = {"external": e.external, "frequency": c.frequencies.tolist(),
                                    "re": c.G.real.tolist(), "im": c.G.imag.tolist(), "std": _std(c.var),
                                    "coherence_ru": c.coherence_ru.tolist(), "coherence_ry": c.coherence_ry.tolist(),
                                    "segments": c.segments,
                                    "direct_deviation": dev if math.isfinite(dev) else None}
        entry["lpm"] = None if e.lpm is None else _lpm_json(e.lpm)
        doc["records"].append(entry)
    return doc


def _lpm_json(e: LpmEstimate) -> dict:
    """The LPM's part of a record's ``--json`` entry: with its 95 % band as a disc per line (LpmEstimate.band; the
    radius null where the data do not bound G)."""
    centre, radius = e.band()
    return {"frequency": e.frequencies.tolist(), "re": e.G.real.tolist(), "im": e.G.imag.tolist(), "std": _std(e.var),
            "noise_std": _std(e.noise_var), "dof": e.dof, "band_factor": e.band_factor(), "order": e.order,
            "half_width": e.half_width, "closed_loop": e.closed_loop, "band_centre_re": centre.real.tolist(),
            "band_centre_im": centre.imag.tolist(),
            "band_radius": [float(x) if math.isfinite(x) else None for x in radius]}
