"""Stage after output, commands: a stage's work together with what output/ makes of it — select's run and its
page, all or none (select: selection.run and output.selection_report), an export measured again (roundtrip:
output.export and measurement.measure), and the demo, which runs every stage end to end.  output/ draws pages
and writes exports and runs no stage's work."""

__all__: list[str] = []
