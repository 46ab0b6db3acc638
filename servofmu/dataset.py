"""Training sets for the ANN: plants drawn around a structure, simulated under a measurement's plan (DS.h5).

Also the two maps the ANN works in (shared by `train` and `identify`):
- features of one data set: per experiment log|H|, cos∠H, sin∠H and dc/(|H|·m) — scale-free and continuous;
- targets: each identified parameter in a transformed scale (log of a magnitude where the structure's value is
  not zero, log of the damping ratio and natural frequency for a complex pair, log(fs − fc) for static friction).
The layout of DS.h5 is in docs/hdf5.md.
"""
from __future__ import annotations

import functools
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

from . import __version__
from .errors import UserError
from .fileio import check_output_path, write_hdf5
from .plant import Plant, plant_from_dict
from .prior import identified_names, sample_identified, full_vectors
from .store import Dataset

FORMAT = "servofmu-training-set"
SCHEMA_VERSION = 1
CHUNK = 250  # parameter sets per write: a killed run loses at most this much work
# Integrator tolerance of training sets: features to ~1e-5 (docs/bench-batch.md), far below what an ANN with
# validation errors near 1e-3 can use, and ~3x faster than 1e-8.
TRAINING_RTOL = 1e-6


# ---------------------------------------------------------------------------
# The plan the identifier uses from a data set
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SineData:
    """Stepped-sine observations the identifier fits: the converged experiments of a data file.

    amplitudes, frequencies (n,): the plan (N, Hz); H (n,) complex: V1/U1; dc (n,): mean velocity (m/s).
    ``noisy``: whether H and dc are the noisy measurement (when the file has noise, that is what is fitted).
    """

    amplitudes: np.ndarray
    frequencies: np.ndarray
    H: np.ndarray
    dc: np.ndarray
    noisy: bool
    source: str
    skipped: int  # experiments without steady state, left out

    @property
    def plan(self) -> np.ndarray:
        """(2, n): amplitudes and frequencies — the layout an ANN is bound to."""
        return np.vstack([self.amplitudes, self.frequencies])


def sine_data(ds: Dataset) -> SineData:
    exps = [e for e in ds.experiments if e.converged]
    if not exps:
        raise UserError(f"{ds.path}: no stepped-sine experiment with a steady state to identify from")
    noisy = all(e.H_noisy is not None for e in exps)
    H = np.array([e.H_noisy if noisy else e.H for e in exps], dtype=complex)
    dc = np.array([e.dc_noisy if noisy else e.dc for e in exps], dtype=float)
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(dc))):
        raise UserError(f"{ds.path}: the stored first harmonics contain NaN or Inf")
    amps = np.array([e.amplitude for e in exps])
    if len(np.unique(amps)) < 2:
        raise UserError(f"{ds.path}: identification needs experiments at two or more excitation magnitudes "
                        f"with a steady state (has {', '.join(map(str, np.unique(amps)))})")
    return SineData(amplitudes=amps, frequencies=np.array([e.frequency for e in exps]), H=H, dc=dc, noisy=noisy,
                    source=str(ds.path), skipped=len(ds.experiments) - len(exps))


def sine_residuals(data: SineData, H: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """The output-error residuals of responses ``H``, ``dc`` (shape (..., n)) against ``data``: per experiment
    Re and Im of (H − H_data)/|H_data| and √2·(dc − dc_data)/(|H_data|·m) — relative errors of the response
    phasor and of the mean velocity, weighted so that white measurement noise gives each about the same
    variance.  Their RMS is the fitness."""
    scale = np.abs(data.H)
    dH = (np.asarray(H) - data.H) / scale
    ddc = np.sqrt(2) * (np.asarray(dc) - data.dc) / (scale * data.amplitudes)
    return np.concatenate([dH.real, dH.imag, ddc], axis=-1)


# ---------------------------------------------------------------------------
# ANN features and targets
# ---------------------------------------------------------------------------
def feature_names(n_exp: int) -> list[str]:
    return [f"{q}[{k}]" for k in range(n_exp) for q in ("log_abs_H", "cos_arg_H", "sin_arg_H", "dc_ratio")]


def ann_features(H: np.ndarray, dc: np.ndarray, amplitudes: np.ndarray) -> np.ndarray:
    """(N, 4·n_exp) features from H and dc of shape (N, n_exp)."""
    H, dc = np.atleast_2d(H), np.atleast_2d(dc)
    mag = np.abs(H)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.stack([np.log(mag), H.real / mag, H.imag / mag, dc / (mag * amplitudes)], axis=-1)
    return f.reshape(H.shape[0], -1)


def to_targets(structure: Plant, theta: np.ndarray) -> np.ndarray:
    """Identified parameters (N, p) → ANN targets (N, p)."""
    names, out = identified_names(structure), np.array(np.atleast_2d(theta), dtype=float)
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    y = out.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, n in enumerate(names):
            if n.endswith("_re"):
                wn = np.hypot(out[:, i], out[:, i + 1])
                y[:, i], y[:, i + 1] = np.log(-out[:, i] / wn), np.log(wn)
            elif n.endswith("_im"):
                continue
            elif n.startswith("fs_"):
                y[:, i] = np.log(out[:, i] - out[:, names.index("fc_" + n[3:])])
            elif nominal[n] != 0:
                y[:, i] = np.log(np.abs(out[:, i]))
    return y


def from_targets(structure: Plant, y: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_targets`."""
    names, y = identified_names(structure), np.atleast_2d(np.asarray(y, dtype=float))
    nominal = dict(zip(structure.parameter_names(), structure.parameter_vector()))
    out = y.copy()
    for i, n in enumerate(names):
        if n.endswith("_re"):
            zeta, wn = np.clip(np.exp(y[:, i]), 0.0, 0.999), np.exp(y[:, i + 1])
            out[:, i], out[:, i + 1] = -zeta * wn, wn * np.sqrt(1 - zeta**2)
        elif n.endswith("_im") or n.startswith("fs_"):
            continue
        elif nominal[n] != 0:
            out[:, i] = np.sign(nominal[n]) * np.exp(y[:, i])
    for i, n in enumerate(names):
        if n.startswith("fs_"):
            out[:, i] = out[:, names.index("fc_" + n[3:])] + np.exp(y[:, i])
    return out


# ---------------------------------------------------------------------------
# DS.h5
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class TrainingSet:
    """A training set read back.  parameters (N, p) in identified_names order; H, dc, converged (N, n_exp)."""

    path: Path
    structure: Plant
    amplitudes: np.ndarray
    frequencies: np.ndarray
    parameters: np.ndarray
    H: np.ndarray
    dc: np.ndarray
    converged: np.ndarray
    done: np.ndarray
    attributes: dict

    @property
    def plan(self) -> np.ndarray:
        return np.vstack([self.amplitudes, self.frequencies])

    def usable(self) -> np.ndarray:
        """Rows simulated with every experiment at steady state."""
        return self.done & np.all(self.converged, axis=1) & np.all(np.isfinite(self.H), axis=1)


def _write(path: Path, arrays: dict, attrs: dict) -> None:
    """Write the whole training set anew (a killed run leaves the previous file or this one)."""
    units = {"H_re": "m/(N.s)", "H_im": "m/(N.s)", "dc": "m/s", "amplitudes": "N", "frequencies": "Hz"}

    def fill(f):
        f.attrs.update(attrs)
        for name, a in arrays.items():
            kw = {"chunks": True, "compression": "gzip", "shuffle": True} if a.size > 64 else {}
            f.create_dataset(name, data=a, **kw).attrs["unit"] = units.get(name, "1")

    write_hdf5(path, fill)


def load_training_set(path: str | Path) -> TrainingSet:
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                raise UserError(f"{path}: not a servofmu training set (format {f.attrs.get('format')!r})")
            if int(f.attrs.get("schema_version", -1)) != SCHEMA_VERSION:
                raise UserError(f"{path}: training-set schema {f.attrs.get('schema_version')} is not the supported "
                                f"{SCHEMA_VERSION}")
            attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
            arrays = {k: f[k][()] for k in ("amplitudes", "frequencies", "parameters", "H_re", "H_im", "dc",
                                             "converged", "done")}
    except UserError:
        raise
    except (OSError, KeyError) as exc:
        raise UserError(f"{path}: not a readable training set ({exc})") from None
    import tomllib
    structure = plant_from_dict(tomllib.loads(attrs["structure_toml"]), source=f"{path}:structure")
    return TrainingSet(path=path, structure=structure, amplitudes=arrays["amplitudes"],
                       frequencies=arrays["frequencies"], parameters=arrays["parameters"],
                       H=arrays["H_re"] + 1j * arrays["H_im"], dc=arrays["dc"],
                       converged=arrays["converged"].astype(bool), done=arrays["done"].astype(bool), attributes=attrs)


def _simulate_chunk(simulator, item):
    """Worker task: features of one chunk of parameter sets (full vectors)."""
    from .batch import SteadyStateOptions
    params, amps, freqs, rtol = item
    feats = simulator.steady_state(params, amps, freqs, SteadyStateOptions(rtol=rtol))
    return feats.H, feats.dc, feats.converged


def make_training_set(structure: Plant, data: SineData, samples: int, output: str | Path, spread: float = 0.5,
                      seed: int = 0, resume: bool = False, scheduler: str | None = None, rtol: float = TRAINING_RTOL,
                      command: str = "", progress: Callable[[int, int], None] | None = None) -> TrainingSet:
    """Draw ``samples`` plants around ``structure``, simulate them under ``data``'s plan and write ``output``.

    With ``resume``, an existing file made with the same arguments is completed instead of started again.
    """
    from .batch import BatchSimulator
    from .parallel import Workers, WorkerResource

    if samples < 1:
        raise UserError(f"--samples must be at least 1, not {samples}")
    output = check_output_path(output, overwrite=resume)
    theta = sample_identified(structure, samples, spread, np.random.default_rng(seed))
    full = full_vectors(structure, theta)
    attrs = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "structure_toml": structure.to_toml(),
             "parameter_names": json.dumps(identified_names(structure)), "spread": spread, "seed": seed,
             "samples": samples, "data_file": data.source, "rtol": rtol, "package_version": __version__,
             "command": command or " ".join(sys.argv)}
    n_exp = data.amplitudes.size
    arrays = {"amplitudes": data.amplitudes, "frequencies": data.frequencies, "parameters": theta,
              "H_re": np.full((samples, n_exp), np.nan), "H_im": np.full((samples, n_exp), np.nan),
              "dc": np.full((samples, n_exp), np.nan), "converged": np.zeros((samples, n_exp), np.uint8),
              "done": np.zeros(samples, np.uint8)}
    if resume and output.exists():
        old = load_training_set(output)
        same = (old.parameters.shape == theta.shape and np.array_equal(old.parameters, theta)
                and np.array_equal(old.plan, data.plan) and old.structure.to_toml() == structure.to_toml())
        if not same:
            raise UserError(f"{output}: made with other arguments (structure, plan, samples, spread or seed); "
                            "cannot resume it")
        for k, v in (("H_re", old.H.real), ("H_im", old.H.imag), ("dc", old.dc),
                     ("converged", old.converged.astype(np.uint8)), ("done", old.done.astype(np.uint8))):
            arrays[k][...] = v
    todo = np.flatnonzero(arrays["done"] == 0)
    chunks = [todo[i:i + CHUNK] for i in range(0, len(todo), CHUNK)]
    _write(output, arrays, attrs)
    done = samples - len(todo)
    if progress:
        progress(done, samples)
    workers = Workers(scheduler=scheduler, workers=0) if scheduler is None else Workers(scheduler=scheduler)
    resource = WorkerResource(key=f"batch:{structure.to_toml()}", factory=functools.partial(BatchSimulator, structure))
    items = [(full[rows], data.amplitudes, data.frequencies, rtol) for rows in chunks]
    with workers:
        for i, (H, dc, conv) in workers.imap(_simulate_chunk, items, resource=resource):
            rows = chunks[i]
            arrays["H_re"][rows], arrays["H_im"][rows], arrays["dc"][rows] = H.real, H.imag, dc
            arrays["converged"][rows], arrays["done"][rows] = conv, 1
            _write(output, arrays, attrs)
            done += len(rows)
            if progress:
                progress(done, samples)
    return load_training_set(output)
