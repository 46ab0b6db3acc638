"""Stage 1, the model: plant files (TOML) and the plant as one CasADi symbolic model, the single source of
the equations (plant, symbolic)."""

__all__: list[str] = []
