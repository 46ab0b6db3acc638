"""Stage 8, output: comparison of methods, the HTML report, figures, export to other tools, and the demo."""

__all__: list[str] = []
