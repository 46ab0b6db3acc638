"""Stage 3, simulation: FMU runs in FMPy (fmpy_runs, fmu_runner), the compiled batch simulator of many
parameter sets (batch), the same plants closed in the drive's loop (closed_loop) and local or Dask worker pools
(parallel)."""

__all__: list[str] = []
