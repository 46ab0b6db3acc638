"""Stage 2, FMU: C generated from the CasADi model, the FMI 2.0/3.0 wrappers (Model Exchange and
Co-Simulation), the model description and the build into an .fmu (sources, variables, description, build)."""
from .build import BuildError, build_fmu

__all__ = ["BuildError", "build_fmu"]
