"""Stage 7, control: the drive's controller (controller file → C law → FMU), reference sources, systems of FMUs
described in SSP and co-simulated on libcosim or FMPy, closed-loop identification and friction compensation."""

__all__: list[str] = []
