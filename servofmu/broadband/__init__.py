"""Broadband excitation and the best linear approximation (docs/broadband.md): periodic multisines, chirps and
PRBS (signals), the BLA with its noise and distortion levels and the H1 estimate (bla)."""
from __future__ import annotations

from .bla import BLA, H1Estimate, estimate_bla, h1_estimate, split_periods
from .signals import GRIDS, KINDS, BroadbandPlan, crest_factor

__all__ = ["BroadbandPlan", "KINDS", "GRIDS", "crest_factor", "BLA", "H1Estimate", "estimate_bla", "h1_estimate",
           "split_periods"]
