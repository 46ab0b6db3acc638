"""Stage 3, simulation: FMU runs in FMPy (fmpy_runs, fmu_runner), the compiled batch simulator of many
parameter sets (batch) and local or Dask worker pools (parallel)."""

__all__: list[str] = []
