"""Conventions of the signals a plant is driven by and measured through (a light module: the command line
reads it to list choices)."""

__all__ = ["INTERSAMPLE"]

# How a sampled input behaves between its samples: "zoh" held (a digital drive updates its force command once
# per controller sample, and FMI Co-Simulation holds an input between communication points; MATLAB's iddata
# default) or "foh" linear from one sample to the next.
INTERSAMPLE = ("zoh", "foh")
