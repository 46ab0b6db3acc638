"""Stage after validation, output: what a person or another tool reads — the pages and their figures (report,
tune_report, compensation_report, validation_report, model_comparison, selection_report, plots, html, paper),
export to other tools (export, formats).  The commands' work is their stages' (tuning.run, control.compensation,
validation.run, identification.run, selection.run), and a stage's run written with its page, like the demo, is
the commands stage's; a page here runs none of it."""

__all__: list[str] = []
