"""`servofmu validate`'s page and figure: the verdict, the fits, the residuals and their correlation functions of a
validation (servofmu.output.validate), and the command that writes them."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode
from ..identification.residuals import ResidualTest
from ..identification.results import read_result
from ..measurement.datafile import read_data_file
from ..runtime import utc_now
from .html import escape, figure, number, page, png_bytes, table
from .plots import MAX_PANELS, pyplot
from .validate import MIN_FIT, RecordValidation, Validation, own_data_warning, residual_tests_phrase, validate

__all__ = ["validate_files", "validation_html", "validation_figure", "residual_figure"]


def _correlation_panels(ax_auto, ax_cross, r: ResidualTest) -> None:
    """The residuals' autocorrelation and cross-correlation with the input, with their joint bounds (titled as not
    applying where the residuals are at the simulation's precision: noise-free data)."""
    lags = np.arange(r.autocorrelation.size)
    ax_auto.bar(lags[1:], r.autocorrelation[1:], width=0.6)
    ax_cross.bar(r.cross_lags, r.cross_correlation, width=0.6)
    for ax, bound, title in ((ax_auto, r.z * r.auto_sigma, "autocorrelation of e"),
                             (ax_cross, r.z * r.cross_sigma, "cross-correlation of e and u")):
        ax.axhline(bound, color="r", ls="--", lw=1)
        ax.axhline(-bound, color="r", ls="--", lw=1)
        ax.set_title(title + (" (noise-free: tests do not apply)" if r.exact else ""), fontsize=9)
        ax.set_xlabel("lag [samples]")


def _item_title(item) -> str:
    """A record's name (and output) or an experiment's magnitude and frequency."""
    if isinstance(item, RecordValidation):
        return f"{item.name} ({item.output})"
    return f"{item.amplitude:g} N, {item.frequency:g} Hz"


def _unit(item) -> str:
    """The unit of the compared signal."""
    return "m" if getattr(item, "output", "v") == "position" else "N" if getattr(item, "output", "") == "force" \
        else "m/s"


def validation_figure(v: Validation, which: str) -> bytes | None:
    """PNG: measured against simulated for every record (``which="records"``; with the residual correlations and
    their bounds) or every experiment's window (``"experiments"``), at most MAX_PANELS each."""
    items = (v.records if which == "records" else v.experiments)[:MAX_PANELS]
    if not items:
        return None
    plt = pyplot()
    cols = 3 if which == "records" else 1
    fig, axes = plt.subplots(len(items), cols, figsize=(12 if cols == 3 else 9, 2.8 * len(items)), squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1, 1]} if cols == 3 else None)
    for row, item in zip(axes, items):
        unit = _unit(item)
        row[0].plot(item.time, item.y, lw=1, label="measured")
        row[0].plot(item.time, item.y_model, "k--", lw=1, label="model")
        row[0].set_title(f"{_item_title(item)}: fit {item.fit:.3f} %")
        row[0].set_ylabel({"m": "position [m]", "N": "force [N]"}.get(unit, "v [m/s]"))
        row[0].set_xlabel("time [s]")
        row[0].legend(fontsize=8, loc="upper right")
        if which == "records":
            _correlation_panels(row[1], row[2], item.residuals)
        for ax in row:
            ax.grid(True, alpha=0.4)
    return png_bytes(fig)


def residual_figure(v: Validation) -> bytes | None:
    """PNG: the residuals e = ŷ − y over time of every record and experiment (at most MAX_PANELS), beside their
    autocorrelation and cross-correlation with the input and the joint bounds where they are tested."""
    items = [*v.records, *v.experiments][:MAX_PANELS]
    if not items:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(len(items), 3, figsize=(12, 2.6 * len(items)), squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1, 1]})
    for row, item in zip(axes, items):
        e = item.y_model - item.y
        row[0].plot(item.time, e, lw=0.8, color="C3")
        row[0].axhline(0, color="k", lw=0.5)
        row[0].set_title(f"residuals, {_item_title(item)}: fit {item.fit:.3f} % "
                         f"({'passed' if item.passed else 'FAILED'})", fontsize=9)
        row[0].set_ylabel(f"e = ŷ − y [{_unit(item)}]")
        row[0].set_xlabel("time [s]")
        if item.residuals is not None:
            _correlation_panels(row[1], row[2], item.residuals)
        else:
            for ax in row[1:]:
                ax.text(0.5, 0.5, "noise-free: nothing to test", ha="center", va="center", fontsize=8,
                        transform=ax.transAxes)
                ax.set_xticks([])
                ax.set_yticks([])
        for ax in row:
            ax.grid(True, alpha=0.4)
    return png_bytes(fig)


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


def validate_files(result_path: str | Path, data_path: str | Path, output: str | Path | None = None,
                   skip: float = 0.0, controller: str | Path | None = None, min_fit: float = MIN_FIT,
                   overwrite: bool = False, progress=None) -> Validation:
    """Validate a result file on a data file (closed-loop records with the controller file ``controller``) with
    the minimum fit ``min_fit`` (%); write ``output`` (.html page or .png figure) if given (an existing one only
    with ``overwrite``).  ``progress(done, total)`` (runtime.Progress) counts the two steps: the model simulated
    on the data, the output written."""
    steps = 1 if output is None else 2
    report = progress or (lambda done, total: None)
    if output is not None:
        output = claim_output(output, output_mode(overwrite), inputs=(result_path, data_path, controller))
        if output.suffix.lower() not in (".html", ".png"):
            raise UserError(f"{output}: write an .html page or a .png figure")
    law = None
    if controller is not None:
        from ..model.controller import load_controller
        law = load_controller(controller)
    report(0, steps)
    v = validate(read_result(result_path), read_data_file(data_path), skip, law, min_fit=min_fit)
    report(1, steps)
    if output is None:
        return v
    if output.suffix.lower() == ".png":
        image = validation_figure(v, "records" if v.records else "experiments")
        atomic_write(output, image)
    else:
        title = f"Validation of {v.result.structure.name} on {Path(data_path).name}"
        parts = [f"<h1>{escape(title)}</h1>",
                 f"<p>Result <code>{escape(Path(result_path).name)}</code> ({escape(v.result.method)}), data "
                 f"<code>{escape(Path(data_path).name)}</code>: {len(v.records)} records, {len(v.experiments)} "
                 "experiments.</p>", *validation_html(v),
                 f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>']
        atomic_write(output, page(title, parts))
    report(2, steps)
    return v
