"""`servofmu compare`: every identification method on the same data, side by side in the paper's layout.

Methods: the hybrid and its search variants (servofmu.identify: pso-ann, pso, ga-ann, aga-ann), Chen 2002's
describing-function method and CasADi nonlinear least squares started from the ANN's estimate (casadi-nls-ann)
and from the structure file's own values (casadi-nls).  Each entry is a servofmu.results.Result, scored by the
same output-error fitness; intervals come from the same Gauss–Newton covariance at each method's answer.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from .errors import UserError
from .plant import Plant
from .prior import identified_mask, identified_names
from .results import Result, paper_rows, to_json

IDENTIFIER_METHODS = ("pso-ann", "pso", "ga-ann", "aga-ann")
BASELINE_METHODS = ("chen2002", "casadi-nls-ann", "casadi-nls")
METHODS = IDENTIFIER_METHODS + BASELINE_METHODS
NEEDS_ANN = ("pso-ann", "ga-ann", "aga-ann", "casadi-nls-ann")


def check_methods(methods: list[str], have_ann: bool) -> list[str]:
    for m in methods:
        if m not in METHODS:
            raise UserError(f"unknown method {m!r} (choose from {', '.join(METHODS)})")
    if not have_ann:
        missing = [m for m in methods if m in NEEDS_ANN]
        if missing:
            raise UserError(f"methods {', '.join(missing)} need a trained network (--ann ANN.h5)")
    return methods


def check_truth(structure: Plant, truth: Plant, truth_source: str) -> None:
    same = (identified_names(truth) == identified_names(structure)
            and truth.friction.model == structure.friction.model
            and [r.imag != 0 for r in truth.poles] == [r.imag != 0 for r in structure.poles]
            and [r.imag != 0 for r in truth.zeros] == [r.imag != 0 for r in structure.zeros])
    if not same:
        raise UserError(f"{truth_source}: --truth has another structure than --structure "
                        f"({', '.join(identified_names(truth))} vs {', '.join(identified_names(structure))}, "
                        f"{truth.friction.model} vs {structure.friction.model} friction)")


def run_methods(structure: Plant, data, methods: list[str], ann=None, seed: int = 0, provenance: dict | None = None,
                progress: Callable[[str], None] | None = None) -> dict[str, Result]:
    """Run each method on ``data``; returns method -> Result (in the order given)."""
    from .baselines.casadi_nls import fit_casadi_nls
    from .baselines.chen2002 import fit_chen2002
    from .batch import BatchSimulator
    from .identify import PSOANNIdentifier, SineCriterion, _central_jacobian, POLISH_RTOL, intervals_from_jacobian
    from .results import result_from_estimator

    provenance = dict(provenance or {})
    out, ann_theta = {}, None
    crit = SineCriterion(structure, data, BatchSimulator(structure))
    for method in methods:
        if progress:
            progress(method)
        if method in IDENTIFIER_METHODS:
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
        intervals = intervals_from_jacobian(theta, r, _central_jacobian(crit, theta)) if np.all(np.isfinite(r)) \
            else np.full((theta.size, 2), np.nan)
        full = structure.parameter_vector().copy()
        full[identified_mask(structure)] = theta
        # a baseline may return a physically invalid plant (e.g. negative friction): reported as it is
        out[method] = Result(method=method, structure=structure, plant=structure.with_parameters(full),
                             names=tuple(base.names), theta=theta, intervals=intervals, fitness=float(base.fitness),
                             seconds=float(base.seconds), evaluations=int(base.evaluations),
                             stages=((method, float(base.fitness), float(base.seconds), int(base.evaluations)),),
                             history=np.zeros(0), provenance={**provenance, "message": base.message,
                                                              "success": bool(base.success),
                                                              "interval_seconds": time.perf_counter() - t0})
    return out


def max_relative_errors(results: dict[str, Result], truth: Plant) -> dict[str, float]:
    t = truth.parameter_vector()[identified_mask(truth)]
    return {m: float(np.max(np.abs(r.theta / t - 1))) if np.all(np.isfinite(r.theta)) else float("inf")
            for m, r in results.items()}


def comparison_json(results: dict[str, Result], truth: Plant | None) -> dict:
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
