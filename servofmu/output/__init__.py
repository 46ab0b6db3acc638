"""Stage after validation, output: what a person or another tool reads — the pages and their figures (report,
tune_report, compensation_report, validation_report, model_comparison, selection_report, plots, html, paper),
export to other tools (export, formats) and the demo.  The commands' work is their stages' (tuning.run,
control.compensation, validation.run, identification.run, selection.run); a page here runs none of it, but for
the demo (every stage end to end) and select's page writer (select_with_report, around selection.run)."""

__all__: list[str] = []
