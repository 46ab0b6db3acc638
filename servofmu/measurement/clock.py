"""The time stamps of a drive's log against its controller's clock.

A drive samples its loop on its own timer: the samples are one controller sample time apart.  The time stamps it
logs come from a clock that may run at a slightly different rate and jitter (a software clock, a logger's clock).
The loop is simulated on the nominal grid t_0 + k·Ts; the stamps are only checked to be that grid, within these
bounds (docs/measurement.md):

- every step between two stamps within ±STEP_BOUND of the record's median step (a larger one is a missing sample,
  a stamp out of place or a different sample rate),
- every stamp within ±STAMP_BOUND of a sample of the least-squares grid t_0 + k·T through the stamps,
- with the controller's sample time Ts known: the stamps' step T within ±RATE_BOUND of Ts (a constant clock-rate
  error; ±STEP_BOUND is taken as another sample rate).

Import checks the first two (and stores the stamps as logged with what :func:`fit_clock` measured); the
closed-loop data checks all three against the controller.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import UserError

__all__ = ["ClockFit", "fit_clock", "STEP_BOUND", "STAMP_BOUND", "RATE_BOUND"]

STEP_BOUND = 0.2    # a step may differ from the median step by this share of it
STAMP_BOUND = 0.1   # a stamp may lie this share of a step off the least-squares grid
RATE_BOUND = 1e-4   # the stamps' mean step may differ from the controller's sample time by this share


@dataclass(frozen=True)
class ClockFit:
    """The least-squares grid t_0 + k·step through a record's time stamps: ``step`` (s), ``rate_error`` (step/Ts − 1
    against the controller's sample time Ts; None without one), the stamps' deviation from the grid as ``jitter_rms``
    and ``jitter_max`` (s)."""

    start: float
    step: float
    rate_error: float | None
    jitter_rms: float
    jitter_max: float

    def summary(self) -> dict:
        """The measured clock as plain numbers (the jitter also in samples), for provenance and printing."""
        out = {"step": self.step, "jitter_rms": self.jitter_rms, "jitter_max": self.jitter_max,
               "jitter_rms_samples": self.jitter_rms / self.step, "jitter_max_samples": self.jitter_max / self.step}
        if self.rate_error is not None:
            out["rate_error"] = self.rate_error
        return out


def _sample(i: int, t: np.ndarray) -> str:
    return f"sample {i + 1} (t = {t[i]:.9g} s)"


def fit_clock(t: np.ndarray, sample_time: float | None = None,
              where: Callable[[int], str] | None = None) -> ClockFit:
    """Check the time stamps ``t`` (s) against the bounds of the module docstring and measure their grid.

    ``sample_time``: the controller's (s), for the rate check; ``where(i)`` names sample i (0-based) in an error
    (default "sample i+1 (t = …)").  A UserError names the first stamp out of bounds: a time that does not
    increase, a missing sample, a stamp off the grid, or a rate beyond RATE_BOUND.
    """
    where = where or (lambda i: _sample(i, t))
    t = np.asarray(t, dtype=float)
    if t.size < 2:
        raise UserError(f"a record needs at least two time stamps, has {t.size}")
    steps = np.diff(t)
    bad = np.nonzero(~(steps > 0))[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise UserError(f"{where(i)}: the time does not increase ({t[i - 1]:.9g} s before it)")
    median = float(np.median(steps))
    if sample_time is not None and abs(median / sample_time - 1) > STEP_BOUND:
        raise UserError(f"{where(1)}: the samples are {median:g} s apart, the controller's sample_time is "
                        f"{sample_time:g} s (--closed-loop): the loop needs one record sample per controller sample")
    off = np.nonzero(np.abs(steps / median - 1) > STEP_BOUND)[0]
    if off.size:
        i = int(off[0]) + 1
        ratio = steps[i - 1] / median
        why = "a missing sample" if ratio > 1.5 else "a stamp out of place"
        raise UserError(f"{where(i)}: {ratio:.3g} steps after the previous sample ({why}? a step may differ from "
                        f"the record's {median:.6g} s by {STEP_BOUND:.0%})")
    k = np.arange(t.size, dtype=float)
    step, start = np.polyfit(k, t - t[0], 1)
    start += t[0]
    deviation = t - (start + step * k)
    far = np.nonzero(np.abs(deviation) > STAMP_BOUND * step)[0]
    if far.size:
        i = int(far[0])
        raise UserError(f"{where(i)}: {deviation[i] / step:+.3g} of a sample off the record's grid (a stamp may be "
                        f"{STAMP_BOUND:.0%} of a sample off; a drifting clock?)")
    rate = None
    if sample_time is not None:
        rate = float(step / sample_time - 1)
        if abs(rate) > RATE_BOUND:
            raise UserError(f"{where(t.size - 1)}: the time stamps advance {step:.9g} s per sample, {rate:+.3g} "
                            f"relative to the controller's sample_time {sample_time:g} s (--closed-loop; a clock may "
                            f"be {RATE_BOUND:g} off): a different sample time, or a clock too far off to map the log "
                            "to the controller's samples")
    return ClockFit(start=float(start), step=float(step), rate_error=rate,
                    jitter_rms=float(np.sqrt(np.mean(deviation ** 2))), jitter_max=float(np.max(np.abs(deviation))))
