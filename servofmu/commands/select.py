"""`servofmu select`'s work with its page: the selection (selection.run) and, when asked for, its HTML page
(output.selection_report), written together with the selection's files or none of them."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from ..fileio import all_or_none, atomic_write, claim_outputs, holds_outputs, output_mode
from ..output.selection_report import selection_page
from ..runtime import RunOptions
from ..selection.run import select_files, selection_outputs
from ..selection.store import Selection
from ..selection.select import SelectOptions

__all__ = ["select_with_report"]


@holds_outputs
def select_with_report(data_files: Sequence[str | Path], validation_file: str | Path, output: str | Path,
                       options: SelectOptions | None = None, run: RunOptions | None = None,
                       plant_output: str | Path | None = None, result_output: str | Path | None = None,
                       report: str | Path | None = None) -> Selection:
    """Select a structure (:func:`servofmu.select_files`) and, with ``report``, write the selection's HTML page
    (:func:`servofmu.output.selection_report.selection_page`): what `servofmu select` does.

    Parameters
    ----------
    data_files, validation_file, output, options, run, plant_output, result_output
        As for :func:`servofmu.select_files`.
    report : str or Path, optional
        The HTML page to write; claimed with the other outputs before any work.

    Returns
    -------
    Selection
        The ranked candidates and the outputs written.
    """
    from ..api_checks import check_arguments

    check_arguments(select_with_report, locals())  # a wrong type: UserError naming it
    run = run or RunOptions()
    outputs = claim_outputs({**selection_outputs(output, plant_output, result_output), "report": report},
                            output_mode(run.overwrite), inputs=(*data_files, validation_file,
                                                                options.closed_loop if options else None))
    with all_or_none(outputs.values()):  # the selection's files and its page, or none of them
        selection = select_files(data_files, validation_file, output, options, run, plant_output, result_output)
        if report is not None:
            atomic_write(report, selection_page(selection))
            selection = replace(selection, outputs={**selection.outputs, "report": str(report)})
    return selection
