"""Identification results: RESULT.h5 (layout in docs/hdf5.md), the `--json` object and the paper's tables."""
from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from ..display import Shown, figure, format_interval, parameter_figures, shown_html, shown_repr
from ..errors import MAX_MAGNITUDE, UserError
from ..fileio import check_values, claim_output, hdf5_attr, output_mode, read_hdf5, store_array, write_hdf5
from ..measurement.datafile import DataFile, read_data_file
from ..model.friction import viscous_damping
from ..model.laws.viscous import viscous_note
from ..model.plant import Plant, parameter_info, plant_from_dict
from ..simulation.batch import valid_parameter_sets
from ..version import __version__
from .confounding import Confounded, confounded_groups
from .roughness import rough_line
from .prior import full_vectors, identified_names

__all__ = ["Result", "Stage", "EstimatorDisplay", "result_from_estimator", "write_result", "write_comparison",
           "read_result", "read_results", "to_json", "to_json_text", "table_text", "paper_rows", "parameters_json",
           "find_data_file", "read_identified_data"]

FORMAT = "servofmu-result"
COMPARE_FORMAT = "servofmu-comparison"
SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Stage:
    """One stage of an identification: its name, the parameters it ended with (``theta``, may be None when read
    back from a file, which stores only the last stage's), its fitness, wall time and model evaluations."""

    name: str
    theta: np.ndarray | None
    fitness: float
    seconds: float
    evaluations: int

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        return Shown(type(self).__name__, repr(self.name), (figure("fitness", self.fitness, "", ".3e"),
                     figure("time", self.seconds, "s", ".3g"), figure("model evaluations", self.evaluations, "", "d")))


@dataclass(frozen=True)
class Result:
    """One identification: the identified plant and how it was obtained.

    theta, intervals (p,), (p, 2): identified parameters in ``names`` order and their 95 % intervals;
    stages: one :class:`Stage` per stage; history: the search's best cost per iteration.
    """

    method: str
    structure: Plant
    plant: Plant
    names: tuple[str, ...]
    theta: np.ndarray
    intervals: np.ndarray
    fitness: float
    seconds: float
    evaluations: int
    stages: tuple[Stage, ...]
    history: np.ndarray
    provenance: dict
    fit_percent: dict | None = None  # records: record name -> fit (%), as MATLAB's compare defines it
    sha256: str = ""  # of the bytes of the file it was read from ("" for one not read from a file)
    covariance: np.ndarray | None = None  # (p, p) the estimates' covariance the intervals come from (None: unknown)

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        units = [parameter_info(n, self.structure)[0] for n in self.names]
        table = parameter_figures(self.names, self.theta, units, self.intervals)
        fits = (figure("fitness", self.fitness, "", ".3e"), figure("time", self.seconds, "s", ".3g"))
        if self.fit_percent:
            fits += (figure("worst record fit", min(self.fit_percent.values()), "%", ".4g"),)
        # the repr's parameters as value ± half-width, to the digits the interval makes distinct
        short = fits + tuple(figure(f.label, format_interval(f.value, *f.interval), f.unit) for f in table)
        head = (f"{self.method} fit of {self.structure.name!r} ({self.structure.friction.model} friction), "
                f"{len(self.names)} parameters")
        notes = tuple(f"{s.name}: fitness {s.fitness:.3e} in {s.seconds:.3g} s" for s in self.stages)
        return Shown(type(self).__name__, head, short, table + fits + (figure("model evaluations",
                                                                               self.evaluations, "", "d"),), notes)

    def confounded(self) -> list[Confounded]:
        """The groups of parameters the data does not separate, with the combinations it determines
        (servofmu.identification.confounding; none without a covariance)."""
        units = {n: parameter_info(n, self.structure)[0] for n in self.names}
        return confounded_groups(self.names, self.theta, self.covariance, self.intervals, units)


class EstimatorDisplay:
    """How an identifier (:class:`servofmu.PSOANNIdentifier`) shows itself: its settings before a fit, its result
    (parameters with units and 95 % intervals, fitness) after one."""

    def _shown(self) -> Shown:
        kind, name = type(self).__name__, self.structure.name
        if not hasattr(self, "theta_"):
            return Shown(kind, f"{self.method} of {name!r}, not fitted", (
                figure("swarm", f"{self.pso.particles} particles × {self.pso.iterations} iterations"),
                figure("seed", self.seed), figure("polish", str(self.polish)), figure("box", self.box, "", ".3g")))
        shown = result_from_estimator(self, self.method, {})._shown()
        return replace(shown, kind=kind, head=f"{self.method} of {name!r}, fitted: {len(self.names_)} parameters")

    __repr__, _repr_html_ = shown_repr, shown_html


def result_from_estimator(est, method: str, provenance: dict) -> Result:
    """The Result of a fitted :class:`servofmu.PSOANNIdentifier` (``method`` and ``provenance`` as stored); the
    provenance also records the fit's settings — seed, polish, swarm iterations — which a fleet's resume compares."""
    provenance = {"seed": est.seed, "polish": est.polish, "iterations": est.pso.iterations,
                  **restart_provenance(est), **provenance}
    return Result(method=method, structure=est.structure, plant=est.plant_, names=tuple(est.names_),
                  theta=np.asarray(est.theta_), intervals=np.asarray(est.intervals_), fitness=float(est.fitness_),
                  seconds=float(est.seconds_), evaluations=int(est.evaluations_),
                  stages=tuple(est.stages_),
                  fit_percent=getattr(est, "fit_percent_", None),
                  covariance=getattr(est, "covariance_", None),
                  history=np.asarray(est.history_), provenance=provenance)


def restart_provenance(est) -> dict:
    """What a result records of the searches repeated because a fit stopped above the noise floor
    (servofmu.identification.restarts): ``restarts``, and for data with a known noise level ``noise_ratio``, the
    kept fit's RMS residual over the noise's (about 1 at the floor; null when not finite); for a polished records
    fit ``roughness`` too (servofmu.identification.roughness: about 1 where the intervals hold)."""
    floor = getattr(est, "floor_", None)
    if not hasattr(est, "restarts_"):
        return {}
    ratio = None if floor is None or not np.isfinite(floor.ratio) else float(floor.ratio)
    rough = getattr(est, "roughness_", math.nan)
    return {"restarts": int(est.restarts_), **({"noise_ratio": ratio} if floor is not None else {}),
            **({"roughness": float(rough)} if np.isfinite(rough) else {})}


def restarts_line(provenance: dict) -> str | None:
    """The table's line on restarts (None for a result that records none: older files, other estimators)."""
    if "restarts" not in provenance:
        return None
    n, ratio = provenance["restarts"], provenance.get("noise_ratio")
    noise = f"; residuals {ratio:.3g}× the noise floor" if ratio is not None else ""
    return f"swarm restarts: {n}" + (" (first fit at the noise floor)" if n == 0 and ratio is not None else "") + noise


# ---------------------------------------------------------------------------
# JSON
# ---------------------------------------------------------------------------
def _pairs(roots) -> list[list[float]]:
    return [[float(r.real), float(r.imag)] for r in roots]


def parameters_json(plant: Plant) -> dict:
    """A plant as JSON-ready data: poles and zeros as [re, im] pairs (1/s), the DC gain (m/(N·s); None for an
    integrating plant), the numerator gain K, the friction model with its values (N, N·s/m, m/s) and, for a plant
    with a load, its terms (``load``: offset N, stiffness N/m, x0 m, ripple_amplitude N, ripple_period m,
    ripple_phase rad)."""
    fr = plant.friction.values()
    dc = None
    if not any(p == 0 for p in plant.all_poles()):
        num, den = plant.transfer_function()
        dc = float(num[-1] / den[-1])
    return {"poles": _pairs(plant.all_poles()), "zeros": _pairs(plant.all_zeros()), "dc_gain": dc,
            "gain": plant.numerator_gain(), "friction": {"model": plant.friction.model, **fr},
            **({"load": plant.load.values()} if plant.load.keys() else {})}


def to_json(result: Result) -> dict:
    """A result as JSON-ready data (the ``--json`` output of identify): method, the identified plant
    (:func:`parameters_json`), fitness, time (s), 95 % intervals by parameter, evaluations, the stages, for
    records the fit % of each, and — for a result with its covariance — ``names``, ``covariance`` (rows and
    columns in that order) and ``not_separated``, the groups of parameters the data does not separate
    (servofmu.identification.confounding.Confounded.to_json; empty when it separates them all)."""
    extra = {"names": list(result.names), "covariance": result.covariance.tolist(),
             "not_separated": [g.to_json() for g in result.confounded()]} if result.covariance is not None else {}
    return {**extra, "method": result.method, "parameters": parameters_json(result.plant), "fitness": result.fitness,
            "seconds": result.seconds,
            "intervals": {n: [float(lo), float(hi)] for n, (lo, hi) in zip(result.names, result.intervals)},
            "evaluations": result.evaluations,
            "stages": [{"stage": s.name, "fitness": s.fitness, "seconds": s.seconds, "evaluations": s.evaluations}
                       for s in result.stages], **({"fit_percent": result.fit_percent} if result.fit_percent else {})}


def to_json_text(result: Result) -> str:
    """:func:`to_json` as text (NaN written as NaN)."""
    return json.dumps(to_json(result), allow_nan=True)


# ---------------------------------------------------------------------------
# The paper's tables
# ---------------------------------------------------------------------------
def paper_rows(plant: Plant) -> list[tuple[str, str]]:
    """(row label, value) in the layout of the paper's Table II (first order) or Table III (roots)."""
    rows = []
    if plant.order == 1 and not plant.zeros:
        rows.append(("pole", f"{plant.all_poles()[0].real:.6g}"))
        rows.append(("constant", f"{plant.numerator_gain():.6g}"))
    else:
        for i, r in enumerate(plant.all_poles(), 1):
            rows.append((f"root {i}", _complex(r)))
        for i, z in enumerate(plant.all_zeros(), 1):
            rows.append((f"zero {i}", _complex(z)))
    p = parameters_json(plant)
    rows.append(("DC gain", f"{p['dc_gain']:.6g}" if p["dc_gain"] is not None else "—"))
    fr = plant.friction
    rows += [("Fc+", f"{fr.fc_pos:.6g}"), ("Fc−", f"{fr.fc_neg:.6g}")]
    rows += fr.law.rows({**fr.structure(), **fr.values()})
    labels = {"offset": "offset", "stiffness": "k", "x0": "x0", "ripple_amplitude": "ripple A",
              "ripple_period": "ripple period", "ripple_phase": "ripple phase"}
    rows += [(labels[key], f"{value:.6g}") for key, value in plant.load.values().items()]
    return rows


def _complex(z: complex) -> str:
    if z.imag == 0:
        return f"{z.real:.6g}"
    return f"{z.real:.6g} {'+' if z.imag > 0 else '−'} {abs(z.imag):.6g}j"


def table_text(result: Result, truth: Plant | None = None) -> str:
    """A plain-text table: parameter, identified value (and truth), then fitness and time."""
    rows = paper_rows(result.plant)
    truth_rows = dict(paper_rows(truth)) if truth is not None else {}
    width = max(len(r[0]) for r in rows) + 2
    head = f"{'parameter':<{width}}{'identified':>24}" + (f"{'target':>24}" if truth is not None else "")
    lines = [head, "-" * len(head)]
    for label, value in rows:
        lines.append(f"{label:<{width}}{value:>24}" + (f"{truth_rows.get(label, ''):>24}" if truth else ""))
    lines.append("")
    lines.append(f"method {result.method}; fitness (RMS relative output error) {result.fitness:.3e}; "
                 f"{result.seconds:.2f} s; {result.evaluations} model evaluations")
    if result.fit_percent:
        lines.append("fit (%, 100·(1 − ‖y − ŷ‖/‖y − mean y‖)): "
                     + ", ".join(f"{name} {fit:.4f}" for name, fit in result.fit_percent.items()))
    for s in result.stages:
        lines.append(f"  stage {s.name:<7} fitness {s.fitness:.3e}  {s.seconds:7.3f} s  {s.evaluations} evaluations")
    if restarts_line(result.provenance):
        lines.append(restarts_line(result.provenance))
    if rough_line(result.provenance.get("roughness")):
        lines.append(rough_line(result.provenance["roughness"]))
    lines.append("95 % intervals: " + ", ".join(f"{n} [{lo:.6g}, {hi:.6g}]"
                                              for n, (lo, hi) in zip(result.names, result.intervals)))
    lines += [group.line() for group in result.confounded()]
    note = viscous_note(result.plant.friction.values(), viscous_damping(result.plant))
    return "\n".join(lines + ([note] if note else []))


# ---------------------------------------------------------------------------
# RESULT.h5
# ---------------------------------------------------------------------------
def _fill(group, result: Result) -> None:
    group.attrs.update({"method": result.method, "structure_toml": result.structure.to_toml(),
                        "plant_toml": result.plant.to_toml(), "fitness": result.fitness, "seconds": result.seconds,
                        "evaluations": result.evaluations, "provenance": json.dumps(result.provenance)})
    if result.fit_percent:
        group.attrs["fit_percent"] = json.dumps(result.fit_percent)
    store_array(group, "names", list(result.names))
    store_array(group, "theta", result.theta)
    store_array(group, "intervals", result.intervals)
    cov = result.covariance
    if cov is not None and np.all(np.abs(cov[np.isfinite(cov)]) <= MAX_MAGNITUDE):  # optional (older files lack it)
        store_array(group, "covariance", cov)
    store_array(group, "history", result.history)
    st = group.create_group("stages")
    store_array(st, "name", [s.name for s in result.stages])
    store_array(st, "fitness", np.array([s.fitness for s in result.stages]))
    store_array(st, "seconds", np.array([s.seconds for s in result.stages]))
    store_array(st, "evaluations", np.array([s.evaluations for s in result.stages]))


def write_result(path: str | Path, result: Result, overwrite: bool = False) -> Path:
    """Write an identification result (RESULT.h5, layout in docs/hdf5.md), atomically.

    Parameters
    ----------
    path : str or Path
        The file to write.
    result : Result
        The result (:meth:`servofmu.PSOANNIdentifier.result`).
    overwrite : bool
        Replace an existing file; without it an existing ``path`` is refused.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    UserError
        When the file cannot be written, or exists (without ``overwrite``).
    """
    from ..api_checks import check_arguments

    check_arguments(write_result, locals())  # a wrong type: UserError naming it
    def fill(f):
        f.attrs.update({"format": FORMAT, "schema_version": SCHEMA_VERSION, "package_version": __version__})
        _fill(f, result)

    return write_hdf5(claim_output(path, output_mode(overwrite)), fill)


def write_comparison(path: str | Path, results: dict[str, Result], overwrite: bool = False) -> Path:
    """COMPARE.h5: one group per method under /methods, each laid out like a RESULT.h5 root (an existing ``path``
    is refused unless ``overwrite``)."""
    def fill(f):
        f.attrs.update({"format": COMPARE_FORMAT, "schema_version": SCHEMA_VERSION, "package_version": __version__,
                        "methods": json.dumps(list(results))})
        for method, result in results.items():
            _fill(f.create_group(f"methods/{method}"), result)

    return write_hdf5(claim_output(path, output_mode(overwrite)), fill)


def _read(group, path: Path) -> Result:
    a = dict(group.attrs)
    names = tuple(n.decode() if isinstance(n, bytes) else str(n) for n in group["names"][()])
    st = group["stages"]
    stage_names = st["name"][()]
    arrays = {k: check_values(path, f"stages/{k}", st[k][()], (len(stage_names),), finite=False)
              for k in ("fitness", "seconds", "evaluations")}
    stages = tuple(Stage(n.decode() if isinstance(n, bytes) else str(n), None, float(fi), float(se), int(ev))
                   for n, fi, se, ev in zip(stage_names, arrays["fitness"], arrays["seconds"], arrays["evaluations"]))
    structure = plant_from_dict(tomllib.loads(a["structure_toml"]), source=f"{path}:structure")
    if list(names) != identified_names(structure):
        raise UserError(f"{path}: parameter names do not match its structure")
    theta = check_values(path, "theta", group["theta"][()], (len(names),)).astype(float)
    full = full_vectors(structure, theta)
    if not valid_parameter_sets(structure, full)[0]:
        raise UserError(f"{path}: the identified parameters are not a plant the plant file format accepts (a damaged "
                        "or foreign file)")
    intervals = check_values(path, "intervals", group["intervals"][()], (len(names), 2), finite=False)
    history = check_values(path, "history", group["history"][()], (None,), finite=False)
    covariance = check_values(path, "covariance", group["covariance"][()], (len(names), len(names)),
                              finite=False).astype(float) if "covariance" in group else None
    fitness = float(check_values(path, "fitness", a["fitness"], (), finite=False))
    return Result(method=str(a["method"]), structure=structure, plant=structure.with_parameters(full[0]), names=names,
                  theta=theta, intervals=intervals, fitness=fitness, seconds=float(a["seconds"]),
                  evaluations=int(a["evaluations"]), stages=stages, history=history,
                  provenance=json.loads(a["provenance"]),
                  fit_percent=json.loads(a["fit_percent"]) if "fit_percent" in a else None, covariance=covariance)


def read_results(path: str | Path) -> dict[str, Result]:
    """RESULT.h5 (one entry, keyed by its method) or COMPARE.h5 (one per method)."""
    return _results_and_selection(path)[0]


def _results_and_selection(path: str | Path) -> tuple[dict[str, Result], bool]:
    """(read_results(path), whether the file is a selection: a comparison with `servofmu select`'s ranking)."""
    path = Path(path)

    def read(f, version):
        if hdf5_attr(f, "format") == FORMAT:
            result = _read(f, path)
            return {result.method: result}, False
        selection = "selection" in f  # (select adds its ranking to a comparison)
        return {m: _read(f["methods"][m], path) for m in json.loads(f.attrs["methods"])}, selection

    (results, selection), sha256 = read_hdf5(path, "result file", (FORMAT, COMPARE_FORMAT), SCHEMA_VERSION, read,
                                             with_sha256=True)
    return {m: dataclasses.replace(r, sha256=sha256) for m, r in results.items()}, selection


def read_result(path: str | Path) -> Result:
    """Read an identification result.

    Parameters
    ----------
    path : str or Path
        A result file (RESULT.h5) written by ``servofmu identify`` or :func:`write_result`.

    Returns
    -------
    Result
        The identified plant, its parameters and intervals, fitness, stages and provenance.

    Raises
    ------
    UserError
        For a missing, foreign, newer or damaged file, or a comparison file of several methods.
    """
    from ..api_checks import check_arguments

    check_arguments(read_result, locals())  # a wrong type: UserError naming it
    results, selection = _results_and_selection(path)
    if selection:  # (even of one fitted candidate: its fit may be on a share of the records, not the chosen one)
        chosen = Path(path).with_name(f"{Path(path).stem}-result.h5")
        raise UserError(f"{path}: is a selection file (`servofmu select`, {len(results)} fitted candidates), not one "
                        f"result: give the chosen structure's result, which select wrote beside it ({chosen.name} "
                        "unless its --result named another file)")
    if len(results) != 1:
        raise UserError(f"{path}: holds a comparison of {len(results)} methods (`servofmu compare`), not one "
                        "result: `servofmu report` reads it; for one method's result run `servofmu identify`")
    return next(iter(results.values()))


def find_data_file(results: Sequence[Result], source: Path, data: str | Path | None) -> Path:
    """The data file the results were identified from: ``data`` if given, else the path their provenance
    records (as given, then beside the result file).  :func:`read_identified_data` also reads and checks it."""
    recorded = {r.provenance.get("data_file", "") for r in results}
    if data is None:
        name = next(iter(recorded))
        candidates = [Path(name), source.parent / name, source.parent / Path(name).name] if name else []
        found = [c for c in candidates if c.is_file()]
        if not found:
            raise UserError(f"{source}: the data file it was identified from ({name or 'not recorded'}) is not "
                            "found; give the data file")
        data = found[0]
    data = Path(data)
    if not data.is_file():
        raise UserError(f"{data}: no such file")
    return data


def read_identified_data(results: Sequence[Result], source: Path, data: str | Path | None) -> DataFile:
    """The data file the results were identified from (:func:`find_data_file`), read; the SHA-256 of the bytes
    read must be the one their provenance records."""
    hashes = {r.provenance.get("data_sha256", "") for r in results}
    if len(hashes) > 1:
        raise UserError(f"{source}: its results were identified from different data files")
    path = find_data_file(results, source, data)
    read = read_data_file(path)
    expected = next(iter(hashes))
    if expected and read.sha256 != expected:
        raise UserError(f"{path}: is not the data file {source} was identified from (its SHA-256 differs from the "
                        "one recorded in the result)")
    return read
