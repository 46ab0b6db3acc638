"""Stage after control, before output: tuning, the drive's gains for an identified axis — the loop linearised
about motion with its sensitivity peak and margins (loop), the task it is tuned for (task), the reference rule
(rule), the swarm's search across the model's uncertainty (search), the check on the axis's co-simulation
(check) and the whole tuning (run; `servofmu tune` from files: tune_files)."""

__all__: list[str] = []
