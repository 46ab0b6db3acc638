"""The package's version, on the ground floor: every stage may import it (it imports nothing)."""

__version__ = "0.1.0"
