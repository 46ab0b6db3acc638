"""`servofmu compare`: every identification method on the same data, side by side in the paper's layout.

Methods: the hybrid and its search variants (servofmu.identification.identifier: pso-ann, pso, ga-ann,
aga-ann), Chen 2002's describing-function method and CasADi nonlinear least squares started from the ANN's
estimate (casadi-nls-ann) and from the structure file's own values (casadi-nls).  Each entry is a
servofmu.identification.results.Result, scored by the same output-error fitness; intervals come from the same Gauss–Newton covariance at each method's answer.
"""
from __future__ import annotations

import time

import numpy as np

from ..baselines import BASELINE_METHODS, BASELINE_NEEDS_ANN
from ..baselines.casadi_nls import fit_casadi_nls
from ..baselines.chen2002 import fit_chen2002
from ..errors import UserError, check_int
from ..identification import methods as identifier_methods
from ..identification.criterion import POLISH_RTOL, SineCriterion, central_jacobian, intervals_from_jacobian
from ..identification.identifier import PSOANNIdentifier
from ..identification.prior import full_vectors, identified_mask, identified_names
from ..identification.results import Result, Stage, paper_rows, result_from_estimator, to_json
from ..model.plant import Plant
from ..runtime import Progress
from ..simulation.batch import BatchSimulator

__all__ = ["METHODS", "NEEDS_ANN", "run_methods", "check_methods", "check_truth", "max_relative_errors",
           "comparison_json", "comparison_markdown", "compare_files"]

METHODS = identifier_methods.METHODS + BASELINE_METHODS
NEEDS_ANN = identifier_methods.NEEDS_ANN + BASELINE_NEEDS_ANN


def check_methods(methods: list[str], have_ann: bool) -> list[str]:
    """Refuse unknown methods, and methods that need a network when there is none."""
    for m in methods:
        if m not in METHODS:
            raise UserError(f"unknown method {m!r} (choose from {', '.join(METHODS)})")
    if not have_ann:
        missing = [m for m in methods if m in NEEDS_ANN]
        if missing:
            raise UserError(f"methods {', '.join(missing)} need a trained network")
    return methods


def check_truth(structure: Plant, truth: Plant, truth_source: str) -> None:
    """Refuse a true plant whose structure differs from the one identified (relative errors need the same names)."""
    same = (identified_names(truth) == identified_names(structure)
            and truth.friction.model == structure.friction.model
            and [r.imag != 0 for r in truth.poles] == [r.imag != 0 for r in structure.poles]
            and [r.imag != 0 for r in truth.zeros] == [r.imag != 0 for r in structure.zeros])
    if not same:
        raise UserError(f"{truth_source}: the true plant has another structure than the one identified "
                        f"({', '.join(identified_names(truth))} vs {', '.join(identified_names(structure))}, "
                        f"{truth.friction.model} vs {structure.friction.model} friction)")


def run_methods(structure: Plant, data, methods: list[str], ann=None, seed: int = 0, provenance: dict | None = None,
                progress: Progress | None = None) -> dict[str, Result]:
    """Run every method on the same data; each result is scored by the same output-error criterion.

    Parameters
    ----------
    structure : Plant
        The structure identified.
    data : SineData
        Stepped-sine data.
    methods : list of str
        Methods from :data:`METHODS`, run in this order.
    ann : AnnModel, optional
        The trained network for the methods in :data:`NEEDS_ANN`.
    seed : int
        Seed of the searches.
    provenance : dict, optional
        Stored with every result.
    progress : Progress, optional
        Called with (methods done, methods) before and after each method.

    Returns
    -------
    dict
        method -> :class:`~servofmu.identification.results.Result`, in the order given.
    """
    check_int("seed", seed, 0)
    provenance = dict(provenance or {})
    out, ann_theta = {}, None
    crit = SineCriterion(structure, data, BatchSimulator(structure))
    for i, method in enumerate(methods):
        if progress:
            progress(i, len(methods))
        if method in identifier_methods.METHODS:
            est = PSOANNIdentifier(structure, ann=ann if method != "pso" else None, method=method, seed=seed).fit(data)
            if method != "pso" and ann_theta is None:
                ann_theta = est.stages_[0].theta
            out[method] = result_from_estimator(est, method, provenance)
            continue
        if method == "chen2002":
            base = fit_chen2002(structure, data)
        else:
            if method == "casadi-nls-ann" and ann_theta is None:
                ann_theta = PSOANNIdentifier(structure, ann=ann).ann_theta(data)
            base = fit_casadi_nls(structure, data, ann_theta if method == "casadi-nls-ann" else None)
        theta = np.asarray(base.theta, dtype=float)
        t0 = time.perf_counter()
        r = crit.residuals(theta, POLISH_RTOL)[0]
        intervals = intervals_from_jacobian(theta, r, central_jacobian(crit, theta)) if np.all(np.isfinite(r)) \
            else np.full((theta.size, 2), np.nan)
        full = full_vectors(structure, theta)[0]
        # a baseline may return a physically invalid plant (e.g. negative friction): reported as it is
        out[method] = Result(method=method, structure=structure, plant=structure.with_parameters(full),
                             names=tuple(base.names), theta=theta, intervals=intervals, fitness=float(base.fitness),
                             seconds=float(base.seconds), evaluations=int(base.evaluations),
                             stages=(Stage(method, theta, float(base.fitness), float(base.seconds),
                                           int(base.evaluations)),),
                             history=np.zeros(0), provenance={**provenance, "message": base.message,
                                                              "success": bool(base.success),
                                                              "interval_seconds": time.perf_counter() - t0})
    if progress:
        progress(len(methods), len(methods))
    return out


def max_relative_errors(results: dict[str, Result], truth: Plant) -> dict[str, float]:
    """Per method, the largest |θ/θ_true − 1| over the identified parameters (inf where a fit has no finite
    result)."""
    t = truth.parameter_vector()[identified_mask(truth)]
    return {m: float(np.max(np.abs(r.theta / t - 1))) if np.all(np.isfinite(r.theta)) else float("inf")
            for m, r in results.items()}


def comparison_json(results: dict[str, Result], truth: Plant | None) -> dict:
    """The comparison as JSON-ready data: per method its result (:func:`to_json`), and with a ``truth`` its
    ``max_relative_error``."""
    errors = max_relative_errors(results, truth) if truth is not None else {}
    out = {}
    for m, r in results.items():
        entry = to_json(r)
        if truth is not None:
            entry["max_relative_error"] = errors[m]
        out[m] = entry
    return out


def comparison_markdown(results: dict[str, Result], truth: Plant | None) -> str:
    """One column per method, one row per parameter (the paper's layout), then error, fitness, time, evaluations."""
    methods = list(results)
    rows = [dict(paper_rows(r.plant)) for r in results.values()]
    labels = [label for label, _ in paper_rows(next(iter(results.values())).plant)]
    head = ["parameter"] + (["target"] if truth is not None else []) + methods
    truth_rows = dict(paper_rows(truth)) if truth is not None else {}
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label in labels:
        cells = [label] + ([truth_rows.get(label, "")] if truth is not None else []) + [r.get(label, "") for r in rows]
        lines.append("| " + " | ".join(cells) + " |")
    def row(label, values):
        lines.append("| " + " | ".join([label] + ([""] if truth is not None else []) + values) + " |")

    if truth is not None:
        errors = max_relative_errors(results, truth)
        row("max relative error", [f"{errors[m]:.2e}" for m in methods])
    row("fitness", [f"{results[m].fitness:.2e}" for m in methods])
    row("wall time [s]", [f"{results[m].seconds:.2f}" for m in methods])
    row("model evaluations", [str(results[m].evaluations) for m in methods])
    return "\n".join(lines) + "\n"


def compare_files(data_file, structure_file, ann_file=None, truth=None, methods: list[str] | None = None,
                  seed: int = 0, output=None, command: str = "", announce=None,
                  overwrite: bool = False, progress=None) -> tuple[dict[str, Result], Plant | None]:
    """`servofmu compare`: every method (default: all that the inputs allow) on one data file.

    ``truth``: the true plant's file, when known (relative errors); ``output``: where to write every result
    (.h5, for `servofmu report`) or the table (any other suffix, Markdown), an existing one only with
    ``overwrite``; ``command`` is recorded as provenance; ``announce(method)`` is called before each method runs,
    ``progress(done, total)`` (runtime.Progress) as methods finish.
    Returns the results by method and the true plant (or None)."""
    from ..fileio import atomic_write, claim_output, output_mode
    from ..identification.inputs import load_identification_inputs
    from ..identification.results import write_comparison
    from ..identification.run import default_method
    from ..model.plant import load_plant

    if output is not None:
        claim_output(output, output_mode(overwrite), inputs=(data_file, structure_file, ann_file, truth))
    methods = check_methods(methods or [m for m in METHODS if ann_file or m not in NEEDS_ANN], bool(ann_file))
    structure, data, ann, provenance = load_identification_inputs(data_file, structure_file, ann_file,
                                                                  default_method(ann_file), command=command)
    true_plant = load_plant(truth) if truth is not None else None
    if true_plant is not None:
        check_truth(structure, true_plant, str(truth))
    def report(done, total):
        if announce is not None and done < total:
            announce(methods[done])
        if progress is not None:
            progress(done, total)

    results = run_methods(structure, data, methods, ann=ann, seed=seed, provenance=provenance, progress=report)
    if output is not None and str(output).endswith(".h5"):
        write_comparison(output, results, overwrite=True)
    elif output is not None:
        atomic_write(output, comparison_markdown(results, true_plant))
    return results, true_plant
