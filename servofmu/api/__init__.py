"""The pipeline on objects, for notebooks and scripts: records from arrays or a DataFrame (:class:`Records`),
selection, identification, several models validated side by side, tuning, and the drive's loops as
python-control systems — each taking and returning objects, with no file written (docs/notebook.md)."""
from .control_loops import ControlLoops, control_loops
from .records import Records
from .workflow import ModelComparison, compare_models, identify, select, tune

__all__ = ["Records", "identify", "select", "compare_models", "ModelComparison", "tune", "control_loops",
           "ControlLoops"]
