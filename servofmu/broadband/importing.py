"""A drive's log of a broadband excitation into a data file of kind broadband (`servofmu import --excitation
SIGNAL.csv`, docs/broadband.md): the signal file's plan gives the periods, the lines, the levels and the
realisations exactly, the log the measured input and output.

The log must hold the whole signal as it was played, from its first sample: as many samples as the signal file,
at its rate (the time column's step within 1e-6 relative of 1/rate, its spread within 1 % of a step), and an input
that is the signal (scaled by ``input_scale``: correlation ≥ MIN_CORRELATION with the file's force).  The output
is the velocity, or a position turned into one (servofmu.measurement.records.velocity_from_position).  Per level,
the BLA is that of the logged input and output, as `measure --excitation` computes it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import claim_output, file_sha256, output_mode
from ..measurement.records import check_wrap, read_columns, velocity_from_position
from ..runtime import RunOptions, utc_now
from ..version import __version__
from .bla import estimate_bla, split_periods
from .store import BroadbandData, BroadbandLevel, read_broadband, read_excitation_csv, write_broadband

__all__ = ["import_broadband", "MIN_CORRELATION"]

MIN_CORRELATION = 0.9  # of the logged input with the signal file's force: below, the log is of another signal


def _checked_time(path: Path, t: np.ndarray, rate: float, column: str) -> None:
    steps = np.diff(t)
    step = float(np.median(steps))
    if abs(step * rate - 1) > 1e-6:
        raise UserError(f"{path}: column {column!r} steps by {step:.9g} s, not the excitation's 1/{rate:g} s (its "
                        "--rate): log the drive at the rate the signal was played")
    if np.ptp(steps) > 0.01 * step:
        raise UserError(f"{path}: column {column!r} is not on a regular grid (steps {steps.min():.9g} to "
                        f"{steps.max():.9g} s)")


def import_broadband(log, output, excitation, time: str, input: str, output_column: str, kind: str = "velocity",
                     cutoff: float | None = None, input_scale: float = 1.0,
                     run: RunOptions | None = None) -> BroadbandData:
    """Import a drive's log of the signal file ``excitation`` into the broadband data file ``output``.

    Parameters
    ----------
    log : str or Path
        The log (CSV or MAT) holding the whole signal from its first sample.
    output : str or Path
        The data file to write (nothing is written when the log is refused).
    excitation : str or Path
        The signal file the drive played (`servofmu excitation ... -o SIGNAL.csv`).
    time, input, output_column : str
        The columns: time (s), input force (N after ``input_scale``), velocity (m/s) or position (m).
    kind : {"velocity", "position"}
        What the output column holds.
    cutoff : float, optional
        Low-pass cut-off (Hz) of the velocity estimate of a position (default a tenth of the rate).
    input_scale : float
        N per unit of the input column.
    run : RunOptions, optional
        ``overwrite``, ``command`` (provenance).

    Returns
    -------
    BroadbandData
        The file read back: per level the logged records and their BLA.
    """
    run, log, excitation = run or RunOptions(), Path(log), Path(excitation)
    out = claim_output(output, output_mode(run.overwrite, False), inputs=(log, excitation))
    plan, _, force = read_excitation_csv(excitation)
    cols = read_columns(log, [time, input, output_column])
    t, u, y = cols[time], cols[input] * input_scale, cols[output_column]
    if t.size != force.size:
        raise UserError(f"{log}: {t.size} samples, but the excitation {excitation.name} has {force.size} "
                        f"({len(plan.levels)} levels × {plan.realisations} realisations × "
                        f"{plan.transient_periods + plan.periods} periods × {plan.samples}): log the whole signal "
                        "from its first sample, nothing before or after")
    _checked_time(log, t, plan.rate, time)
    correlation = float(np.corrcoef(u, force)[0, 1]) if np.ptp(u) > 0 else 0.0
    if not correlation >= MIN_CORRELATION:
        raise UserError(f"{log}: column {input!r} is not the excitation {excitation.name} (correlation "
                        f"{correlation:.3g} < {MIN_CORRELATION}): another signal, or shifted in time")
    if kind == "position":
        check_wrap(log, t, y, output_column)
        v = velocity_from_position(t, y, plan.rate / 10 if cutoff is None else cutoff)
    elif cutoff is not None:
        raise UserError("a velocity cutoff applies to position records only")
    else:
        v = y
    shape = (len(plan.levels), plan.realisations, -1)
    u, v = u.reshape(shape), v.reshape(shape)
    levels = []
    for i, level in enumerate(plan.levels):
        cut = [split_periods(x, plan.samples, plan.periods, plan.transient_periods, f"{log}: level {level:g}")
               for x in (u[i], v[i])]
        levels.append(BroadbandLevel(level, u[i], v[i], None, estimate_bla(*cut, plan.lines, plan.rate,
                                                                         plan.free_lines)))
    provenance = {"package": "servofmu", "package_version": __version__, "command": run.command,
                  "created": utc_now(), "source": log.name, "source_sha256": file_sha256(log),
                  "excitation_file": excitation.name, "excitation_sha256": file_sha256(excitation),
                  "columns": f"time={time}, u={input}, {'position' if kind == 'position' else 'v'}={output_column}",
                  "input_scale": float(input_scale), "input_correlation": correlation, "excitation": "log",
                  "broadband": plan.to_json()}
    write_broadband(out, plan, levels, provenance)
    return read_broadband(out)
