"""The export formats by name and file suffix (a light module: the command line lists them without loading the
exporters)."""

__all__ = ["FORMATS", "SUFFIX_FORMATS"]

FORMATS = ("fmu", "control", "mat", "json", "toml")
SUFFIX_FORMATS = {".fmu": "fmu", ".mat": "mat", ".json": "json", ".toml": "toml"}
