"""Stage after output, commands: the work of a command together with what it writes of the later stages — a
stage's run and its page, all or none (select_with_report: selection.run and output.selection_report's page),
and the demo, which runs every stage end to end.  The stages below run no command's page; output/ draws pages
and runs no stage's work."""

__all__: list[str] = []
