"""servofmu: servo drives with friction — CasADi plant models as FMUs, stepped-sine measurement,
PSO-ANN identification and export."""
__version__ = "0.1.0"
