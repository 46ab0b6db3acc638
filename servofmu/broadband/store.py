"""Broadband data in files: the excitation as CSV for a drive to play (time, force, with its plan in a header
comment), and the broadband measurement as a data file of kind ``broadband`` (schema version 3, docs/hdf5.md).

The signal of a plan is played in one go: level after level, realisation after realisation, each (T + P) periods
(``BroadbandPlan.signals`` in that order), sample i at time i/rate held until the next sample.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import (READ_ERRORS, atomic_write, claim_output, hdf5_attr, output_mode, read_error_reason, read_hdf5,
                      store_array, write_hdf5)
from ..measurement.datafile import FORMAT, READ_VERSION, write_header
from .bla import BLA
from .signals import BroadbandPlan

__all__ = ["CSV_TAG", "write_excitation_csv", "read_excitation_csv", "BroadbandLevel", "BroadbandData",
           "write_broadband", "read_broadband", "write_bla", "BROADBAND_VERSION", "BLA_UNITS"]

CSV_TAG = "# servofmu-excitation "  # the first line of a signal file: this, then the plan as JSON
BROADBAND_VERSION = 3
BLA_UNITS = {"frequencies": "Hz", "G": "output unit per N (m/(N.s) for v)", "var_noise": "(G's unit)^2",
             "var_distortion": "(G's unit)^2", "var_total": "(G's unit)^2", "coherence": "1", "U": "N",
             "detection_frequencies": "Hz", "detection_level": "output unit (m/s)",
             "detection_noise": "output unit (m/s)", "detection_lines": "1"}

# the strongest component between the period's lines (bla.nonsynchronous_components): root attributes of a BLA group,
# NaN where the response is periodic
NONSYNCHRONOUS = ("nonsynchronous_frequency", "nonsynchronous_re_response_db", "nonsynchronous_over_floor_db")


def excitation_csv_text(plan: BroadbandPlan) -> str:
    """The signal file's text: the tag line with the plan, the header ``time,force``, one row per sample."""
    force = plan.signals().ravel()
    time = np.arange(force.size) / plan.rate
    rows = np.column_stack([time, force])
    body = "\n".join(f"{t:.9g},{x:.12g}" for t, x in rows)
    return f"{CSV_TAG}{plan.to_json()}\ntime,force\n{body}\n"


def write_excitation_csv(path: str | Path, plan: BroadbandPlan, overwrite: bool = False) -> Path:
    """Write the plan's whole signal (time in s, force in N) as CSV, its plan on the first line (a comment); an
    existing ``path`` only with ``overwrite``."""
    path = claim_output(path, output_mode(overwrite))
    return atomic_write(path, excitation_csv_text(plan))


def read_excitation_csv(path: str | Path) -> tuple[BroadbandPlan, np.ndarray, np.ndarray]:
    """A signal file read back: its plan, time (s) and force (N); a file without the tag line, or whose samples
    are not its plan's, is a UserError naming it."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as f:
            first = f.readline()
            if not first.startswith(CSV_TAG):
                raise UserError(f"{path}: not a servofmu excitation file (its first line is not {CSV_TAG.strip()!r})")
            plan = BroadbandPlan.from_description(json.loads(first[len(CSV_TAG):]))
            values = np.loadtxt(f, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        if isinstance(exc, UserError):
            raise UserError(f"{path}: {exc}") from None
        raise UserError(f"{path}: not a readable excitation file ({exc})") from None
    expected = plan.signals().ravel()
    if values.shape != (expected.size, 2) or not np.allclose(values[:, 1], expected, rtol=1e-9, atol=1e-12):
        raise UserError(f"{path}: its samples are not those of the plan on its first line (edited or cut)")
    return plan, values[:, 0], values[:, 1]


@dataclass(frozen=True)
class BroadbandLevel:
    """One RMS level of a broadband measurement: the inputs ``u`` (N) and outputs ``v`` (m/s), shape
    (realisations, (T + P)·samples), optionally ``v_noisy``, and the BLA stored with them."""

    level: float
    u: np.ndarray
    v: np.ndarray
    v_noisy: np.ndarray | None
    bla: BLA


@dataclass(frozen=True)
class BroadbandData:
    """A broadband data file read back."""

    path: Path
    plan: BroadbandPlan
    levels: tuple[BroadbandLevel, ...]
    provenance: dict = field(default_factory=dict)


def write_bla(g, bla: BLA) -> None:
    """Store a BLA's arrays and summary levels in the HDF5 group ``g`` (units in its ``units`` attribute)."""
    for name in BLA_UNITS:
        value = getattr(bla, name)
        store_array(g, name, np.asarray(value, complex if name == "G" else int if name == "detection_lines"
                                        else float), unit=BLA_UNITS[name])
    g.attrs["periods"], g.attrs["realisations"] = bla.periods, bla.realisations
    for name in ("distortion_to_noise_db", "relative_distortion_db", "total_to_noise_db"):
        g.attrs[name] = getattr(bla, name)
    g.attrs["even_detection_to_noise_db"] = bla.detection_to_noise_db("even")
    g.attrs["odd_detection_to_noise_db"] = bla.detection_to_noise_db("odd")
    for name in NONSYNCHRONOUS:
        g.attrs[name] = getattr(bla, name)
    g.attrs["units"] = json.dumps(BLA_UNITS)


def _read_bla(g) -> BLA:
    values = {name: np.asarray(g[name][()]) for name in BLA_UNITS}
    # files written before the check have no such attributes: NaN, as for a periodic response
    found = {name: float(g.attrs.get(name, math.nan)) for name in NONSYNCHRONOUS}
    return BLA(**values, periods=int(hdf5_attr(g, "periods")), realisations=int(hdf5_attr(g, "realisations")),
               **found)


def write_broadband(path: str | Path, plan: BroadbandPlan, levels: list[BroadbandLevel], provenance: dict,
                    parameters: dict | None = None) -> Path:
    """Write a broadband data file (atomically: the previous file or the complete new one)."""
    def edit(f):
        write_header(f, "broadband", provenance, parameters or {}, version=BROADBAND_VERSION)
        g = f.create_group("excitation")
        g.attrs["description"] = plan.to_json()
        store_array(g, "lines", plan.lines, unit="1")
        store_array(g, "free_lines", plan.free_lines, unit="1")
        store_array(g, "frequencies", plan.frequencies, unit="Hz")
        for i, lv in enumerate(levels):
            lg = f.create_group(f"levels/level_{i:02d}")
            lg.attrs["level"] = lv.level
            store_array(lg, "u", lv.u, unit="N", description="input, one row per realisation, sample k at k/rate")
            store_array(lg, "v", lv.v, unit="m/s", description="output, one row per realisation")
            if lv.v_noisy is not None:
                store_array(lg, "v_noisy", lv.v_noisy, unit="m/s", description="v plus measurement noise")
            write_bla(lg.create_group("bla"), lv.bla)
        f.attrs["complete"] = True

    return write_hdf5(Path(path), edit, None)


def read_broadband(path: str | Path) -> BroadbandData:
    """A broadband data file; another kind of data file (or none) is a UserError naming it."""
    path = Path(path)

    def read(f, version):
        kind = hdf5_attr(f, "kind", None)
        if kind != "broadband":
            raise UserError(f"{path}: is a {kind} data file, not a broadband measurement (servofmu measure "
                            "--excitation multisine)")
        try:
            plan = BroadbandPlan.from_description(json.loads(hdf5_attr(f["excitation"], "description")))
            levels = []
            for name in sorted(f["levels"]):
                g = f["levels"][name]
                noisy = np.asarray(g["v_noisy"][()]) if "v_noisy" in g else None
                levels.append(BroadbandLevel(float(hdf5_attr(g, "level")), np.asarray(g["u"][()]),
                                             np.asarray(g["v"][()]), noisy, _read_bla(g["bla"])))
            prov = {k: hdf5_attr(f["provenance"], k) for k in f["provenance"].attrs}
        except UserError:
            raise
        except READ_ERRORS as exc:
            raise UserError(f"{path}: damaged servofmu data file ({read_error_reason(exc)})") from exc
        return BroadbandData(path, plan, tuple(levels), prov)

    return read_hdf5(path, "data file", FORMAT, READ_VERSION, read)
