"""Structure selection: which friction law and which order of G(s) — candidate structures fitted to a user's
data and ranked on data they were not fitted to (docs/selection.md)."""

__all__: list[str] = []
