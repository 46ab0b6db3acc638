"""Training sets for the ANN (`servofmu dataset`): plants drawn around a structure, simulated under a
measurement's plan, written to DS.h5 (layout in docs/hdf5.md).  This is what "dataset" means in servofmu; a
measurement or records file is a *data file* (servofmu.measurement.datafile).
"""
from __future__ import annotations

import functools
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..broadband.store import BroadbandData
from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError, check_int
from ..fileio import check_values, claim_output, holds_outputs, output_mode, read_hdf5, store_array, write_hdf5
from ..model.plant import Plant, plant_from_dict
from ..runtime import RunOptions, check_memory
from ..simulation.batch import BatchSimulator, SteadyStateOptions
from ..simulation.parallel import WorkerResource, Workers
from ..version import __version__
from .criterion import SineData
from .prior import check_identifiable, full_vectors, identified_names, sample_identified

__all__ = ["TrainingSet", "make_training_set", "load_training_set", "training_data", "TRAINING_RTOL"]

FORMAT = "servofmu-training-set"
SCHEMA_VERSION = 1
CHUNK = 250  # parameter sets per task
BROADBAND_CHUNK = 8  # of a broadband plan: each a whole run (the default plan's 120 000 samples)
# While the run goes on, the file is rewritten (whole, atomically) at most every WRITE_EVERY seconds: a killed run
# loses at most that much work, and rewriting after every chunk took a tenth of a 10 000-plant run.
WRITE_EVERY = 5.0
# Integrator tolerance of training sets: features to ~1e-5 (docs/bench-batch.md), far below what an ANN with
# validation errors near 1e-3 can use, and ~3x faster than 1e-8.
TRAINING_RTOL = 1e-6


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

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        a, f = self.amplitudes, self.frequencies
        figures = (figure("done", f"{int(np.sum(self.done))}/{self.parameters.shape[0]}"),
                   figure("usable", int(np.sum(self.usable()))),
                   figure("amplitudes", f"{a.min():.4g}–{a.max():.4g}" if a.size else "—", "N"),
                   figure("frequencies", f"{f.min():.4g}–{f.max():.4g}" if f.size else "—", "Hz"))
        return Shown(type(self).__name__, f"{self.path.name!r} of {self.structure.name!r}: {self.parameters.shape[0]} "
                     f"parameter sets × {a.size} experiments", figures)

    @property
    def plan(self) -> np.ndarray:
        """(2, n_exp): the amplitudes (N) over the frequencies (Hz) of the experiments."""
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
            store_array(f, name, a, unit=units.get(name, "1"))

    write_hdf5(path, fill)


def load_training_set(path: str | Path) -> TrainingSet:
    """Read a training set written by :func:`make_training_set`; anything else is refused naming the file."""
    import tomllib

    path = Path(path)

    def read(f, version):
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        structure = plant_from_dict(tomllib.loads(attrs["structure_toml"]), source=f"{path}:structure")
        a = {k: f[k][()] for k in ("amplitudes", "frequencies", "parameters", "H_re", "H_im", "dc", "converged",
                                    "done")}
        n, rows = a["amplitudes"].size, a["done"].size
        check_values(path, "amplitudes", a["amplitudes"], (None,))
        check_values(path, "frequencies", a["frequencies"], (n,))
        check_values(path, "parameters", a["parameters"], (rows, len(identified_names(structure))))
        for name in ("H_re", "H_im", "dc", "converged"):  # not yet simulated, or without steady state: NaN
            check_values(path, name, a[name], (rows, n), finite=False)
        return structure, attrs, a

    structure, attrs, arrays = read_hdf5(path, "training set", FORMAT, SCHEMA_VERSION, read)
    return TrainingSet(path=path, structure=structure, amplitudes=arrays["amplitudes"],
                       frequencies=arrays["frequencies"], parameters=arrays["parameters"],
                       H=arrays["H_re"] + 1j * arrays["H_im"], dc=arrays["dc"],
                       converged=arrays["converged"].astype(bool), done=arrays["done"].astype(bool), attributes=attrs)


def _take_resumed(output: Path, arrays: dict, structure: Plant, data: SineData, broadband_plan: str) -> None:
    """Copy into ``arrays`` what the training set ``output`` holds already, refusing one made with other arguments
    (its drawn parameters, plan, broadband plan or structure differ)."""
    old, theta = load_training_set(output), arrays["parameters"]
    same = (old.parameters.shape == theta.shape and np.array_equal(old.parameters, theta)
            and np.array_equal(old.plan, data.plan) and old.structure.to_toml() == structure.to_toml()
            and old.attributes.get("broadband_plan", "") == broadband_plan)
    if not same:
        raise UserError(f"{output}: made with other arguments (structure, plan, samples, spread or seed); "
                        "cannot resume it")
    for k, v in (("H_re", old.H.real), ("H_im", old.H.imag), ("dc", old.dc),
                 ("converged", old.converged.astype(np.uint8)), ("done", old.done.astype(np.uint8))):
        arrays[k][...] = v


def _simulate_chunk(simulator, item):
    """Worker task: features of one chunk of parameter sets (full vectors)."""
    params, amps, freqs, rtol = item
    feats = simulator.steady_state(params, amps, freqs, SteadyStateOptions(rtol=rtol))
    return feats.H, feats.dc, feats.converged


def training_data(path: str | Path):
    """What a training set's plan comes from (`servofmu dataset --like PATH`): the stepped-sine data of a data
    file, or a broadband file itself (its whole plan simulated, identification.broadband_ann)."""
    from ..measurement.datafile import read_data_file

    if read_data_file(path).kind == "broadband":
        from ..broadband.store import read_broadband

        return read_broadband(path)
    from .criterion import sine_data

    return sine_data(read_data_file(path))


@holds_outputs  # a long run: its outputs are its own until it ends (fileio.output_claims)
def make_training_set(structure: Plant, data: SineData | BroadbandData, samples: int, output: str | Path,
                      spread: float = 0.5, seed: int = 0, rtol: float = TRAINING_RTOL,
                      run: RunOptions | None = None) -> TrainingSet:
    """Draw plants around a structure, simulate them under a measurement's plan and write the training set.

    Parameters
    ----------
    structure : Plant
        The structure (order, friction model) and the centre of the prior.
    data : SineData or BroadbandData
        The measurement whose plan the plants are simulated under: stepped sines at its (amplitude, frequency)
        points, or a broadband file's whole plan from rest (servofmu.broadband.store.read_broadband), its features
        the BLA's bands (identification.broadband_ann).
    samples : int
        Number of plants.
    output : str or Path
        The training set (HDF5) to write; rewritten every few seconds (WRITE_EVERY), so a killed run loses
        little.
    spread : float
        Prior width: every identified quantity is scaled by a log-uniform factor in [1/(1+spread), 1+spread].
    seed : int
        Seed of the prior draw.
    rtol : float
        Integrator tolerance of the batch simulator.
    run : RunOptions, optional
        ``resume``: complete an existing ``output`` made with the same arguments instead of starting again;
        ``overwrite``: replace an existing ``output``; ``scheduler``: a Dask scheduler address (default: this
        machine, all cores, in this process: ``workers`` is not used); ``command``: the command line, for
        provenance; ``progress``: called with (plants done, samples).

    Returns
    -------
    TrainingSet
        The file read back.

    Raises
    ------
    UserError
        For bad arguments, a training set too large for this machine's memory, an existing ``output`` (without
        ``run.resume`` or ``run.overwrite``), ``output`` the data file itself, or a ``resume`` of a file made with
        other arguments.
    """
    from ..api_checks import check_arguments

    check_arguments(make_training_set, locals())  # a wrong type: UserError naming it
    check_identifiable(structure, "plant")
    check_int("samples", samples, 1)
    check_int("seed", seed, 0)
    run = run or RunOptions()
    if not isinstance(data, (SineData, BroadbandData)):
        raise UserError(f"make_training_set(): data must be a SineData or BroadbandData, not {type(data).__name__}")
    broadband = None if isinstance(data, SineData) else data.plan
    if broadband is not None:
        from .broadband_ann import broadband_sine_data

        data = broadband_sine_data(data)
    output = claim_output(output, output_mode(run.overwrite, run.resume), inputs=(data.source,),
                          can_continue="resume")
    # the arrays below, the file's image in memory and its copy on every write
    check_memory(f"a training set of {samples} plants", 4 * 8 * samples * (2 * len(structure.parameter_names())
                                                                            + 4 * data.amplitudes.size),
                 "use fewer --samples")
    theta = sample_identified(structure, samples, spread, np.random.default_rng(seed))
    full = full_vectors(structure, theta)
    attrs = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "structure_toml": structure.to_toml(),
             "parameter_names": json.dumps(identified_names(structure)), "spread": spread, "seed": seed,
             "samples": samples, "data_file": data.source, "rtol": rtol, "package_version": __version__,
             "command": run.command or " ".join(sys.argv),
             "broadband_plan": "" if broadband is None else broadband.to_json()}
    n_exp = data.amplitudes.size
    arrays = {"amplitudes": data.amplitudes, "frequencies": data.frequencies, "parameters": theta,
              "H_re": np.full((samples, n_exp), np.nan), "H_im": np.full((samples, n_exp), np.nan),
              "dc": np.full((samples, n_exp), np.nan), "converged": np.zeros((samples, n_exp), np.uint8),
              "done": np.zeros(samples, np.uint8)}
    if run.resume and output.exists():
        _take_resumed(output, arrays, structure, data, attrs["broadband_plan"])
    _simulate_into(output, arrays, attrs, structure, full, rtol, run, broadband)
    return load_training_set(output)


def _simulate_into(output: Path, arrays: dict, attrs: dict, structure: Plant, full: np.ndarray, rtol: float,
                   run: RunOptions, broadband=None) -> None:
    """Simulate the plants ``full`` (full parameter vectors) not yet done into ``arrays``, in chunks on the
    workers (under the ``broadband`` plan where given), writing the training set every WRITE_EVERY seconds and at
    the end (also when interrupted)."""
    from .broadband_ann import simulate_chunk

    samples = arrays["done"].size
    todo = np.flatnonzero(arrays["done"] == 0)
    size = CHUNK if broadband is None else BROADBAND_CHUNK
    chunks = [todo[i:i + size] for i in range(0, len(todo), size)]
    # written first once a chunk is done: a run that fails at its start (a memory limit, Ctrl-C) leaves the file
    # it was to replace as it was, and a resumed file as it is
    done = start = samples - len(todo)
    run.report(done, samples)
    workers = Workers(scheduler=run.scheduler, workers=0 if run.scheduler is None else None)
    resource = WorkerResource(key=f"batch:{structure.to_toml()}", factory=functools.partial(BatchSimulator, structure))
    if broadband is None:
        task, items = _simulate_chunk, [(full[rows], arrays["amplitudes"], arrays["frequencies"], rtol)
                                        for rows in chunks]
    else:
        task, items = simulate_chunk, [(full[rows], broadband, rtol) for rows in chunks]
    written = time.monotonic()
    with workers:
        try:
            for i, (H, dc, conv) in workers.imap(task, items, resource=resource):
                rows = chunks[i]
                arrays["H_re"][rows], arrays["H_im"][rows], arrays["dc"][rows] = H.real, H.imag, dc
                arrays["converged"][rows], arrays["done"][rows] = conv, 1
                if time.monotonic() - written >= WRITE_EVERY:
                    _write(output, arrays, attrs)
                    written = time.monotonic()
                done += len(rows)
                run.report(done, samples)
        finally:  # what is done is kept, also when the run is interrupted
            if done > start:
                _write(output, arrays, attrs)
