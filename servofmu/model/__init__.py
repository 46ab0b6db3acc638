"""Stage 1, the model: plant files (TOML) and the plant as one CasADi symbolic model, the single source of
the equations (plant, symbolic, signals), its friction curve (friction), and the drive's controller file
(controller), which the loop simulation, the controller FMU and the feed-forward all read."""

__all__: list[str] = []
