"""Stage 4, measurement: excitation plans (excitation), steady state and harmonics (frf), stepped-sine
measurement of an FMU (measure), import of machine records (records) and the data file they are stored in
(datafile)."""

__all__: list[str] = []
