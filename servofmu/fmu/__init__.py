"""FMI export of servofmu plants (FMI 2.0 and 3.0, Model Exchange and Co-Simulation)."""
from .build import BuildError, build_fmu

__all__ = ["BuildError", "build_fmu"]
