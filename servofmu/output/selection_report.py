"""The page of a structure selection (`servofmu select … --report select.html`): the ranking, the chosen structure,
and the best candidates' fits on the validation data side by side (each simulated there as ``validate`` does).
Writing it with the selection's files, all or none, is commands.select's."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path


from ..measurement.datafile import read_data_file
from ..runtime import utc_now
from ..selection.store import Selection
from ..selection.summary import rough_warning
from ..selection.select import STRONG_EVIDENCE
from ..selection.validation import VALIDATION_LEVEL
from .html import escape, figure, number, page, png_bytes, table
from .plots import figure_axes
from ..validation.replay import Validation, validate

__all__ = ["selection_page", "plot_side_by_side", "SIDE_BY_SIDE"]

SIDE_BY_SIDE = 4  # candidates drawn beside each other (the best fitted ones)
ROWS = 3          # records or experiments drawn per candidate


def _validations(selection: Selection) -> list[tuple[str, Validation]]:
    """The best fitted candidates validated on the validation file, as ``validate`` simulates a result (the plant
    the file may record is not compared: every structure is a candidate)."""
    data = replace(read_data_file(selection.validation_file), parameters={})
    controller = None
    if selection.options.closed_loop is not None:
        from ..model.controller import load_controller

        controller = load_controller(selection.options.closed_loop)
    out = []
    for s in [s for s in selection.scores if s.status == "fitted"][:SIDE_BY_SIDE]:
        out.append((s.name, validate(s.result, data, selection.options.skip, controller, min_fit=0.0)))
    return out


def plot_side_by_side(validations: list[tuple[str, Validation]], ax=None):
    """One column per candidate (name, validation), one row per record or experiment (at most ROWS): measured
    and simulated output.  ``ax``: rows × candidates matplotlib Axes (row by row) to draw into, else a new Figure.
    Returns the Figure."""
    rows = max(min(len(v.records) + len(v.experiments), ROWS) for _, v in validations)
    cols = len(validations)
    fig, flat = figure_axes(ax, rows * cols, (3.6 * cols, 2.6 * rows), nrows=rows, ncols=cols, sharey="row")
    axes = [flat[r * cols:(r + 1) * cols] for r in range(rows)]
    for col, (name, v) in enumerate(validations):
        items = [*v.records, *v.experiments][:rows]
        for row, item in enumerate(items):
            ax = axes[row][col]
            ax.plot(item.time, item.y, lw=0.8, label="measured")
            ax.plot(item.time, item.y_model, "k--", lw=0.8, label="model")
            ax.set_title(f"{name}: fit {item.fit:.2f} %", fontsize=9)
            ax.grid(True, alpha=0.4)
            if row == len(items) - 1:
                ax.set_xlabel("time [s]")
            if col == 0:
                ax.set_ylabel({"position": "position [m]", "force": "force [N]"}.get(getattr(item, "output", "v"),
                                                                                     "v [m/s]"))
        axes[0][col].legend(fontsize=7, loc="upper right")
    return fig


def _side_by_side(validations: list[tuple[str, Validation]]) -> bytes | None:
    """PNG of :func:`plot_side_by_side`; None without candidates."""
    return png_bytes(plot_side_by_side(validations)) if validations else None


def _ranking_rows(selection: Selection) -> list[list[str]]:
    fitted = [s for s in selection.scores if s.status == "fitted" and math.isfinite(s.bic)]
    best_bic = min((s.bic for s in fitted), default=math.nan)
    best_val = min((s.validation_neg2loglik for s in fitted), default=math.nan)
    rows = []
    for s in selection.scores:
        if s.status != "fitted":
            rows.append([str(s.rank), s.name, "—", "—", "—", "—", "—", "—", f"fit failed: {s.message}"])
            continue
        white = "—" if s.white is None else ("yes" if s.white else "no")
        flags = ", ".join(s.flags) + (f" ({', '.join(s.undetermined)})" if s.undetermined else "")
        flags = "; ".join(x for x in (flags, "screened" if s.screened else "", s.message) if x)
        rows.append([str(s.rank), s.name, str(s.parameters), number(s.bic, ".6g"), number(s.bic - best_bic, ".1f"),
                     number(s.worst_validation_fit, ".3f"), number(s.validation_neg2loglik - best_val, ".1f"), white,
                     flags or "—"])
    return rows


def selection_page(selection: Selection) -> str:
    """The HTML page: the chosen structure and its plant file, the ranking table, and the best candidates' fits
    on the validation data side by side."""
    chosen = selection.chosen
    title = f"Structure selection: {chosen.name if chosen else 'no candidate fitted'}"
    parts = [f"<h1>{escape(title)}</h1>",
             f"<p>Fitted to {escape(', '.join(Path(p).name for p in selection.data_files))}, ranked on "
             f"{escape(Path(selection.validation_file).name)} ({escape(selection.kind)} data), every candidate by "
             "the swarm alone (method pso) from its linear least-squares estimate, then polished.</p>"]
    if chosen is not None:
        parts.append(f'<p id="chosen">Chosen: <strong>{escape(chosen.name)}</strong>, {chosen.parameters} '
                     f"identified parameters. Its plant file:</p><pre>{escape(chosen.result.plant.to_toml())}</pre>")
        if rough_warning(selection):
            parts.append(f'<p id="rough" class="warning">{escape(rough_warning(selection))}</p>')
    parts += [table("ranking", ["rank", "candidate", "parameters", "BIC", "ΔBIC", "worst validation fit %",
                                "Δ validation −2 ln L", "residuals white", "flags"], _ranking_rows(selection),
                    numeric_from=2),
              f'<p class="note">BIC from the output-error residuals of the fitted data, each signal\'s noise '
              f"variance estimated from them; flags: validation −2 ln L more than the {100 * VALIDATION_LEVEL:g} % "
              "quantile of χ²(p) above the best (p the candidate's parameters; on records, for a candidate within "
              f"{STRONG_EVIDENCE:g} of the best BIC, the same quantile of its own estimation error's cost on the "
              "validation data if larger), a parameter whose 95 % interval "
              "reaches past zero (undetermined), a pole-zero cancellation, a zero at the origin whose spring was "
              "fitted, residual tests failed where another candidate passes them. "
              "Flagged candidates rank after the others (docs/selection.md).</p>"]
    image = _side_by_side(_validations(selection))
    if image is not None:
        parts.append(figure(f"The best {min(SIDE_BY_SIDE, len(selection.scores))} candidates on the validation "
                            "data, side by side: measured and simulated output.", image, "candidates side by side"))
    parts.append(f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>')
    return page(title, parts)
