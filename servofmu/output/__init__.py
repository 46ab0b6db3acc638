"""Stage 8, output: what a person or another tool reads — validation (validate), the HTML report and its
figures (report, compensation_report, plots, html, paper), export to other tools (export, formats) and the demo."""

__all__: list[str] = []
