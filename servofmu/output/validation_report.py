"""`servofmu validate`'s page and figure: the verdict, the fits, the residuals and their correlation functions of a
validation (servofmu.validation.replay; the command's work: servofmu.validation.run)."""
from __future__ import annotations

from pathlib import Path

from ..errors import UserError
from ..fileio import atomic_write
from ..runtime import utc_now
from ..validation.replay import Validation, own_data_warning, residual_tests_phrase
from .html import escape, figure, number, page, png_bytes, table
from .figures import item_title, item_unit, residual_tests, validation_items, validation_overlay
from .plots import MAX_PANELS, figure_axes

__all__ = ["check_page_suffix", "write_validation", "validation_html", "validation_figure", "residual_figure",
           "plot_validation", "plot_residuals"]


def _pairs(v) -> list[tuple[str, Validation]]:
    """A validation, or several as (label, validation) pairs."""
    return [(v.result.method, v)] if isinstance(v, Validation) else list(v)


def plot_validation(v, which: str, ax=None):
    """Measured against simulated for every record (``which="records"``; with the residual correlations and
    their bounds beside) or every experiment's window (``"experiments"``), at most MAX_PANELS each.

    ``v``: a Validation, or (label, Validation) pairs of the same data, overlaid.  ``ax``: the Axes to draw into,
    row by row (three per record, one per experiment), else a new Figure.  Returns the Figure.
    """
    vals = _pairs(v)
    n = len(validation_items(vals[0][1], which))
    cols = 3 if which == "records" else 1
    fig, axes = figure_axes(ax, n * cols, (12 if cols == 3 else 9, 2.8 * n), nrows=n, ncols=cols,
                            gridspec_kw={"width_ratios": [2, 1, 1]} if cols == 3 else None)
    validation_overlay(vals, ax=axes[::cols], which=which)
    if which == "records":
        residual_tests(vals, ax=[a for i, a in enumerate(axes) if i % 3], which=which)
    return fig


def validation_figure(v, which: str) -> bytes | None:
    """PNG of :func:`plot_validation`; None when there is nothing of ``which`` to draw."""
    first = _pairs(v)[0][1]
    return png_bytes(plot_validation(v, which)) if validation_items(first, which) else None


def plot_residuals(v, ax=None):
    """The residuals e = ŷ − y over time of every record and experiment (at most MAX_PANELS), beside their
    autocorrelation and cross-correlation with the input and the joint bounds where they are tested.

    ``v``: a Validation, or (label, Validation) pairs of the same data, overlaid.  ``ax``: three Axes per record
    or experiment, row by row, else a new Figure.  Returns the Figure.
    """
    vals = _pairs(v)
    items = validation_items(vals[0][1])
    fig, axes = figure_axes(ax, 3 * len(items), (12, 2.6 * len(items)), nrows=len(items), ncols=3,
                            gridspec_kw={"width_ratios": [2, 1, 1]})
    for i, first in enumerate(items):
        a = axes[3 * i]
        for k, (label, other) in enumerate(vals):
            item = validation_items(other)[i]
            a.plot(item.time, item.y_model - item.y, lw=0.8, color="C3" if len(vals) == 1 else f"C{k}",
                   label=f"{label}: fit {item.fit:.3f} % ({'passed' if item.passed else 'FAILED'})")
        a.axhline(0, color="k", lw=0.5)
        a.set_title(f"residuals, {item_title(first)}", fontsize=9)
        a.set_ylabel(f"e = ŷ − y [{item_unit(first)}]")
        a.set_xlabel("time [s]")
        a.grid(True, alpha=0.4)
        a.legend(fontsize=7, loc="upper right")
    residual_tests(vals, ax=[a for i, a in enumerate(axes) if i % 3])
    return fig


def residual_figure(v) -> bytes | None:
    """PNG of :func:`plot_residuals`; None without records and experiments."""
    return png_bytes(plot_residuals(v)) if validation_items(_pairs(v)[0][1]) else None


def validation_html(v: Validation) -> list[str]:
    """The validation section of an HTML page: the verdict, the warning when the data is the model's own fitting
    data, tables of records and experiments, the figures of measured against simulated and of the residuals."""
    verdict = "passed" if v.passed else "failed"
    parts = [f'<p id="verdict" class="verdict {verdict}"><strong>Verdict: {verdict}.</strong> Every record and '
             f"experiment must fit at least {escape(format(v.min_fit, 'g'))} % and pass the residual tests that "
             f"apply (docs/validation.md){'; ' + escape(residual_tests_phrase(v)) if v.noise_free[0] else ''}.</p>"]
    if not v.passed:
        parts.append('<ul id="failures">' + "".join(f"<li>{escape(f)}</li>" for f in v.failures()) + "</ul>")
    warning = own_data_warning(v)
    if warning:
        parts.append(f'<p id="own-data-warning" class="warning"><strong>Warning:</strong> {escape(warning)}</p>')
    if v.records:
        rows = []
        for r in v.records:
            t = r.residuals
            auto_out, cross_out = t.outside_per_lag()
            tests = ["—" if r.closed_loop else ("yes" if t.white else "no"), "yes" if t.independent else "no",
                     f"{auto_out} / {cross_out}"] if r.residuals_apply else ["n/a (noise-free)"] * 3
            rows.append([r.name, r.output, r.hold, str(r.y.size), number(r.fit, ".4f"), *tests,
                         "passed" if r.passed else "failed"])
        parts += [table("validation-records", ["record", "output", "input", "samples", "fit %", "e white",
                                               "e independent of u", "lags outside per-lag 99 % bounds",
                                               "verdict"], rows, numeric_from=3),
                  '<p class="note">Fit: 100·(1 − ‖y − ŷ‖/‖y − mean y‖). Residual tests: autocorrelation (lags 1–25; '
                  "not for closed-loop records, whose disturbances the loop feeds back) and cross-correlation with "
                  "the input (lags −25..25) within their joint 99 % bounds.</p>"]
        parts.append(figure("Measured and simulated output of every record, with the residuals' correlations and "
                            "their joint 99 % bounds.", validation_figure(v, "records"), "validation of records"))
    if v.experiments:
        rows = [[str(e.index), number(e.amplitude, "g"), number(e.frequency, "g"), number(e.fit, ".4f"),
                 number(e.H_error, ".3e"),
                 "n/a (noise-free)" if not e.residuals_apply else ("passed" if e.residuals.passed else "failed"),
                 "passed" if e.passed else "failed"] for e in v.experiments]
        parts += [table("validation-experiments", ["experiment", "amplitude [N]", "frequency [Hz]", "fit %",
                                                   "|H_model − H|/|H|", "residual tests", "verdict"], rows,
                        numeric_from=1),
                  '<p class="note">Residual tests of an experiment: on noisy windows only (a right model leaves the '
                  "noise, white and independent of the sine); a noise-free window has no noise to test.</p>",
                  figure("The analysed window of every experiment, measured and simulated from rest.",
                         validation_figure(v, "experiments"), "validation of experiments")]
    n = len(v.records) + len(v.experiments)
    more = f" (the first {MAX_PANELS} of {n})" if n > MAX_PANELS else ""
    parts.append(figure(f"Residuals e = ŷ − y of every record and experiment{more}, with their autocorrelation and "
                        "cross-correlation with the input and the joint 99 % bounds where they are tested.",
                        residual_figure(v), "residuals"))
    return parts


def check_page_suffix(output: str | Path) -> None:
    """Refuse a page or figure that is neither .html nor .png (before any work)."""
    if Path(output).suffix.lower() not in (".html", ".png"):
        raise UserError(f"{output}: write an .html page or a .png figure")


def write_validation(output: str | Path, v: Validation, result_path: str | Path, data_path: str | Path) -> Path:
    """Write a validation (servofmu.validation.run.validate_files) as the .html page or .png figure ``output``
    (claimed by the caller)."""
    check_page_suffix(output)
    output = Path(output)
    if output.suffix.lower() == ".png":
        return atomic_write(output, validation_figure(v, "records" if v.records else "experiments"))
    title = f"Validation of {v.result.structure.name} on {Path(data_path).name}"
    parts = [f"<h1>{escape(title)}</h1>",
             f"<p>Result <code>{escape(Path(result_path).name)}</code> ({escape(v.result.method)}), data "
             f"<code>{escape(Path(data_path).name)}</code>: {len(v.records)} records, {len(v.experiments)} "
             "experiments.</p>", *validation_html(v),
             f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>']
    return atomic_write(output, page(title, parts))
