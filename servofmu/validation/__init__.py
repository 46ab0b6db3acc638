"""Stage after tuning, before output: validation, an identified model replayed on data it was not fitted to —
open-loop from the recorded input or in its drive's loop from the recorded reference — with its fits, residual
tests and verdict (replay), and `servofmu validate` from files, one model or several side by side (run).  The
pages are servofmu.output.validation_report's and servofmu.output.model_comparison's."""

__all__: list[str] = []
