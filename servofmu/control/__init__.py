"""Stage 7, control: what puts an identified model to use in its drive's loop — the controller and reference
sources as FMUs (fmus), systems of FMUs in SSP (system) co-simulated on libcosim or FMPy (cosim), and friction
compensation measured on the axis (compensation; `servofmu compensate` from files: compensate_files).  The
controller file itself is part of the model (servofmu.model.controller), its loop simulation part of the
simulators (servofmu.simulation.closed_loop)."""

__all__: list[str] = []
