"""The frequency response of a broadband data file (``servofmu frf``): per level, the BLA recomputed from the stored
records (the noisy output when there is one), as JSON (schema in docs/broadband.md) or as an HDF5 file."""
from __future__ import annotations

import math
from pathlib import Path


from ..fileio import claim_output, hdf5_attr, output_mode, write_hdf5
from ..version import __version__
from .bla import BLA, estimate_bla, split_periods
from .store import BroadbandData, read_broadband, write_bla

__all__ = ["frf_of_file", "frf_json", "write_frf", "read_frf_levels", "FRF_FORMAT", "FRF_VERSION"]

FRF_FORMAT = "servofmu-frf"
FRF_VERSION = 1


def frf_of_file(path: str | Path) -> tuple[BroadbandData, list[tuple[float, BLA]]]:
    """The data file and, per RMS level (N), the BLA of its records."""
    data = read_broadband(path)
    plan, out = data.plan, []
    for lv in data.levels:
        y = lv.v if lv.v_noisy is None else lv.v_noisy
        cut = [split_periods(x, plan.samples, plan.periods, plan.transient_periods, f"{data.path}: level "
                             f"{lv.level:g}") for x in (lv.u, y)]
        out.append((lv.level, estimate_bla(*cut, plan.lines, plan.rate, plan.free_lines)))
    return data, out


def _finite(x: float):
    return float(x) if math.isfinite(x) else None


def frf_json(data: BroadbandData, levels: list[tuple[float, BLA]]) -> dict:
    """The ``--json`` document: the plan and, per level, the BLA's lines with their standard deviations."""
    doc = {"format": FRF_FORMAT, "schema_version": FRF_VERSION, "data": str(data.path),
           "excitation": data.plan.describe(), "levels": []}
    for level, b in levels:
        doc["levels"].append({
            "level": level, "frequency": b.frequencies.tolist(), "re": b.G.real.tolist(), "im": b.G.imag.tolist(),
            "std_noise": [_finite(x) for x in b.std_noise], "std_distortion": [_finite(x) for x in b.std_distortion],
            "std_total": [_finite(x) for x in b.std_total], "band_factor_95": _finite(b.band_factor()),
            "coherence": b.coherence.tolist(),
            "distortion_to_noise_db": _finite(b.distortion_to_noise_db),
            "relative_distortion_db": _finite(b.relative_distortion_db),
            "total_to_noise_db": _finite(b.total_to_noise_db),
            "even_detection_to_noise_db": _finite(b.detection_to_noise_db("even")),
            "odd_detection_to_noise_db": _finite(b.detection_to_noise_db("odd")),
            "nonsynchronous": None if b.periodic else {
                "frequency": b.nonsynchronous_frequency, "re_response_db": b.nonsynchronous_re_response_db,
                "over_floor_db": b.nonsynchronous_over_floor_db},
            "periods": b.periods, "realisations": b.realisations})
    return doc


def write_frf(path: str | Path, data: BroadbandData, levels: list[tuple[float, BLA]], command: str = "",
              overwrite: bool = False) -> Path:
    """An HDF5 file of the frequency responses: root attributes format ``servofmu-frf``, schema_version,
    package_version, data (the data file's path), command, excitation (the plan, JSON); a group ``level_NN`` per level (attribute ``level``,
    N RMS) with the BLA's datasets (store.write_bla)."""
    def edit(f):
        f.attrs["format"], f.attrs["schema_version"] = FRF_FORMAT, FRF_VERSION
        f.attrs["package_version"], f.attrs["data"], f.attrs["command"] = __version__, str(data.path), command
        f.attrs["excitation"] = data.plan.to_json()
        for i, (level, b) in enumerate(levels):
            g = f.create_group(f"level_{i:02d}")
            g.attrs["level"] = level
            write_bla(g, b)

    return write_hdf5(claim_output(path, output_mode(overwrite)), edit, None)


def read_frf_levels(f) -> list[float]:
    """The RMS levels (N) of an open FRF file, in order (for readers and tests)."""
    return [float(hdf5_attr(f[name], "level")) for name in sorted(f) if name.startswith("level_")]

