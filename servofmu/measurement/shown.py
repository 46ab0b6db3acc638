"""How a data file, its experiments and its records show themselves (servofmu.display): what they hold, their
size and their key figures with units, in a short repr and a compact HTML table."""
from __future__ import annotations

import numpy as np

from ..display import Shown, figure

__all__ = ["data_file_shown", "experiment_shown", "record_shown", "SHOWN_ROWS"]

SHOWN_ROWS = 12  # experiments and records listed in a data file's HTML table: a glance, not the file


def experiment_shown(e) -> Shown:
    """A stepped-sine experiment (ExperimentResult): its point, |H| and phase, distortion, settling."""
    figures = (figure("|H|", abs(e.H), "m/(N.s)"), figure("phase", np.degrees(np.angle(e.H)), "deg"),
               figure("distortion", e.distortion, "", ".2g"), figure("settled after", e.settling_time, "s"),
               figure("dc", e.dc, "m/s", ".3g"))
    head = f"#{e.index}: {e.amplitude:.4g} N at {e.frequency:.4g} Hz, " + \
        ("converged" if e.converged else "NOT converged")
    return Shown(type(e).__name__, head, figures)


def record_shown(r) -> Shown:
    """An imported record (Record): its length, rate, peaks and, if sinusoidal, its frequency."""
    t = np.asarray(r.series.time)
    figures = (figure("duration", float(t[-1] - t[0]) if t.size else 0.0, "s"),
               figure("sample rate", r.sample_rate, "Hz"),
               figure("u peak", float(np.max(np.abs(r.series.u))) if t.size else 0.0, "N"),
               figure("v peak", float(np.max(np.abs(r.series.v))) if t.size else 0.0, "m/s"))
    if r.analysis is not None:
        figures += (figure("sine at", r.analysis.frequency, "Hz"),)
    return Shown(type(r).__name__, f"#{r.index} {r.name!r}: {r.kind}, {t.size} samples", figures,
                 notes=(f"from {r.source}", f"velocity: {r.velocity_estimate}"))


def data_file_shown(d) -> Shown:
    """A data file (DataFile): its kind, experiments and records, their ranges; a row per item."""
    n = len(d.experiments)
    size = f"{n} stepped-sine experiment{'s' * (n != 1)}"
    if d.plan is not None:
        size += f" ({len(d.plan.amplitudes)} amplitudes × {len(d.plan.frequencies)} frequencies)"
    size = (f"{size}, " if n or d.plan is not None else "") + \
        f"{len(d.records)} record{'s' * (len(d.records) != 1)}"
    head = f"{d.path.name!r}: {d.kind}{'' if d.complete else ' (incomplete)'}, {size}"
    figures = ()
    if d.experiments:
        amplitudes = [e.amplitude for e in d.experiments]
        frequencies = [e.frequency for e in d.experiments]
        figures += (figure("amplitudes", f"{min(amplitudes):.4g}–{max(amplitudes):.4g}", "N"),
                    figure("frequencies", f"{min(frequencies):.4g}–{max(frequencies):.4g}", "Hz"),
                    figure("converged", f"{sum(e.converged for e in d.experiments)}/{n}"))
    if d.records:
        duration = sum(float(r.series.time[-1] - r.series.time[0]) for r in d.records if r.series.time.size)
        figures += (figure("records", ", ".join(r.name for r in d.records[:3])
                           + (", …" if len(d.records) > 3 else "")),
                    figure("recorded", duration, "s"))
    missing = len(d.missing())
    notes = (f"{missing} experiments of the plan not measured yet",) if missing else ()
    rows = tuple(figure(f"#{e.index} {e.amplitude:.4g} N at {e.frequency:.4g} Hz: |H|", abs(e.H), "m/(N.s)")
                 for e in d.experiments[:SHOWN_ROWS]) + tuple(
        figure(f"record {r.name}: {r.series.time.size} samples at", r.sample_rate, "Hz")
        for r in d.records[:SHOWN_ROWS])
    more = len(d.experiments) + len(d.records) - len(rows)
    notes += (f"{more} more experiments or records not listed",) if more > 0 else ()
    return Shown(type(d).__name__, head, figures, figures + rows, notes + (f"file {d.path}",))
