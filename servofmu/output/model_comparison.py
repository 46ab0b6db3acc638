"""Several identified models validated on the same data (`servofmu validate A.h5 B.h5 … DATA.h5`, and
servofmu.compare_models): one table with a column per model — the fits, the verdicts, the residual tests and the
parameters with their 95 % intervals — as text, JSON and an HTML page whose figures overlay the models."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

from ..display import json_safe
from ..fileio import atomic_write
from ..runtime import utc_now
from ..validation.replay import Validation, validation_json
from .html import escape, figure, page, png_bytes
from .validation_report import check_page_suffix, plot_residuals, plot_validation

__all__ = ["comparison_rows", "comparison_text", "comparison_json", "comparison_table", "comparison_html",
           "write_comparison"]

Pairs = Sequence[tuple[str, Validation]]


def comparison_rows(pairs: Pairs) -> dict[str, dict[str, object]]:
    """Row -> model label -> value: the mean and worst fit (%), the verdict, whether the residual tests pass
    where they apply, and each identified parameter as "value [low, high]" (its 95 % interval)."""
    rows: dict[str, dict[str, object]] = {}
    for label, v in pairs:
        items = (*v.records, *v.experiments)
        fits = [i.fit for i in items if math.isfinite(i.fit)]
        rows.setdefault("fit % (mean)", {})[label] = sum(fits) / len(fits) if fits else math.nan
        rows.setdefault("fit % (worst)", {})[label] = min(fits) if fits else math.nan
        rows.setdefault("verdict", {})[label] = "passed" if v.passed else "failed"
        applies = [i for i in items if i.residuals_apply]
        rows.setdefault("residual tests", {})[label] = ("n/a (noise-free)" if not applies else
                                                        "passed" if all(i.residuals_passed for i in applies)
                                                        else "failed")
        r = v.result
        for name, value, (low, high) in zip(r.names, r.theta, r.intervals):
            rows.setdefault(name, {})[label] = f"{float(value):.6g} [{float(low):.6g}, {float(high):.6g}]"
    return rows


def _cell(value) -> str:
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def comparison_text(pairs: Pairs) -> str:
    """The table as plain text: a column per model."""
    rows = comparison_rows(pairs)
    labels = [label for label, _ in pairs]
    width = max(14, *(len(label) + 2 for label in labels),
                *(len(_cell(v)) + 2 for values in rows.values() for v in values.values()))
    first = max(len(k) for k in rows) + 2
    lines = [f"{len(pairs)} models on {pairs[0][1].data_file.path}",
             f"{'':<{first}}" + "".join(f"{label:>{width}}" for label in labels)]
    lines += [f"{row:<{first}}" + "".join(f"{_cell(values.get(label, '—')):>{width}}" for label in labels)
              for row, values in rows.items()]
    return "\n".join(lines)


def comparison_json(pairs: Pairs) -> dict:
    """One object: the table by row and model, and every model's own validation (validation_json)."""
    rows = comparison_rows(pairs)
    return {"data_file": str(pairs[0][1].data_file.path), "models": [label for label, _ in pairs],
            "passed": all(v.passed for _, v in pairs),
            "table": json_safe(rows),
            "validations": {label: validation_json(v) for label, v in pairs}}


def comparison_table(pairs: Pairs) -> str:
    """The table as HTML: a row per quantity, a column per model."""
    rows = comparison_rows(pairs)
    labels = [label for label, _ in pairs]
    head = "".join(f"<th>{escape(label)}</th>" for label in labels)
    body = "".join(f"<tr><td>{escape(row)}</td>" + "".join(f'<td class="num">{escape(_cell(values.get(label, "—")))}'
                                                           "</td>" for label in labels) + "</tr>"
                   for row, values in rows.items())
    return f'<table id="model-comparison"><thead><tr><th></th>{head}</tr></thead><tbody>{body}</tbody></table>'


def comparison_html(pairs: Pairs) -> list[str]:
    """The page's sections: the table (a column per model) and the figures, the models overlaid."""
    first = pairs[0][1]
    parts = [comparison_table(pairs),
             '<p class="note">Fit: 100·(1 − ‖y − ŷ‖/‖y − mean y‖) per record or experiment; parameters: the value '
             "and its 95 % interval (docs/validation.md).</p>"]
    for which in ("records", "experiments"):
        if getattr(first, which):
            parts.append(figure(f"Measured and simulated, every model overlaid ({which}).",
                                png_bytes(plot_validation(list(pairs), which)), f"validation of {which}"))
    parts.append(figure("Residuals e = ŷ − y of every model, with their correlations and joint 99 % bounds.",
                        png_bytes(plot_residuals(list(pairs))), "residuals"))
    return parts


def write_comparison(output: str | Path, pairs: Pairs, data_path: str | Path) -> Path:
    """Write several models' validations (servofmu.validation.run.validate_several) as the .html page (the table
    and the overlaid figures) or the .png figure ``output`` (claimed by the caller)."""
    check_page_suffix(output)
    output = Path(output)
    if output.suffix.lower() == ".png":
        first = pairs[0][1]
        return atomic_write(output, png_bytes(plot_validation(list(pairs), "records" if first.records
                                                              else "experiments")))
    title = f"{len(pairs)} models validated on {Path(data_path).name}"
    return atomic_write(output, page(title, [f"<h1>{escape(title)}</h1>", *comparison_html(pairs),
                                             f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>']))
