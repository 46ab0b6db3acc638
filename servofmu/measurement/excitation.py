"""The stepped-sine experiment plan: amplitudes × frequencies, and the default frequency grid around the bandwidth
estimated from a step response.

Experiment k of a plan drives the plant with u(t) = m_k·sin(2π·f_k·t) from rest at t = 0.  Experiments are
numbered amplitude-major: all frequencies of the first amplitude, then of the second, and so on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from ..simulation.fmpy_runs import EXCITATION
from ..simulation.fmu_runner import FmuRunner, FmuRunnerFactory

__all__ = ["ExperimentSpec", "Plan", "default_frequencies", "corner_frequency", "estimate_bandwidth", "run_step_response",
           "DEFAULT_AMPLITUDES", "MAX_STEPS"]

DEFAULT_AMPLITUDES = (2.0, 0.6)  # the paper's two magnitudes, m1 > m2 (N)
MAX_STEPS = 1e8  # FMU steps per experiment: about a quarter of an hour of a servofmu FMU, however absurd the plan


@dataclass(frozen=True)
class ExperimentSpec:
    """One stepped-sine experiment: excitation amplitude (N) and frequency (Hz)."""

    index: int
    amplitude: float
    frequency: float


@dataclass(frozen=True)
class Plan:
    """The grid of amplitudes (N) and frequencies (Hz) to measure."""

    amplitudes: tuple[float, ...]
    frequencies: tuple[float, ...]

    def __post_init__(self):
        object.__setattr__(self, "amplitudes", _checked("amplitude", self.amplitudes, "amplitudes"))
        object.__setattr__(self, "frequencies", _checked("frequency", self.frequencies, "frequencies"))

    @property
    def experiments(self) -> tuple[ExperimentSpec, ...]:
        """Every (amplitude, frequency) pair, amplitude-major, with its index."""
        return tuple(ExperimentSpec(index=i, amplitude=m, frequency=f)
                     for i, (m, f) in enumerate((m, f) for m in self.amplitudes for f in self.frequencies))

    def __len__(self) -> int:
        return len(self.amplitudes) * len(self.frequencies)


def _checked(what: str, values, option: str) -> tuple[float, ...]:
    values = tuple(float(v) for v in values)
    if not values:
        raise UserError(f"{option}: give at least one {what}")
    for v in values:
        if not math.isfinite(v) or v <= 0:
            raise UserError(f"{option}: every {what} must be a positive finite number, not {v:g}")
    if len(set(values)) != len(values):
        raise UserError(f"{option}: {what} {next(v for v in values if values.count(v) > 1):g} is given twice")
    return values


def default_frequencies(bandwidth: float, low: float = 0.25, high: float = 15.0) -> tuple[float, ...]:
    """A log-spaced grid on the 1-2-5 series from ``low``·bandwidth to ``high``·bandwidth (Hz).

    For G1 = 10/(s+10) (bandwidth 1.59 Hz) this is 0.5, 1, 2, 5, 10, 20 Hz: from well inside the pass band,
    where friction dominates the difference between magnitudes, to well beyond the corner.
    """
    if not (math.isfinite(bandwidth) and bandwidth > 0):
        raise UserError(f"bandwidth must be a positive number, not {bandwidth}")
    lo, hi = low * bandwidth, high * bandwidth
    out = []
    for decade in range(int(math.floor(math.log10(lo))) - 1, int(math.ceil(math.log10(hi))) + 1):
        for mantissa in (1.0, 2.0, 5.0):
            f = float(f"{mantissa * 10.0 ** decade:.6g}")
            if lo <= f <= hi:
                out.append(f)
    return tuple(out)


def corner_frequency(t: np.ndarray, v: np.ndarray) -> float:
    """The bandwidth 1/(2π·t63) of a step response v(t) from rest, t63 being the first time |v| reaches 63.2 %
    of its final value (the mean of the last quarter).  Exact for a first-order plant; for others a scale
    for the frequency grid."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    final = float(np.mean(v[len(v) * 3 // 4:]))
    if not abs(final) > 0:
        raise UserError("the step response does not move the output: cannot estimate the bandwidth "
                        "(give the frequencies)")
    reached = np.nonzero(np.abs(v) >= (1 - math.exp(-1)) * abs(final))[0]
    i = int(reached[0])
    if i == 0:
        return math.inf
    # interpolate the crossing between samples i-1 and i
    level = (1 - math.exp(-1)) * abs(final)
    a, b = abs(v[i - 1]), abs(v[i])
    t63 = t[i - 1] + (t[i] - t[i - 1]) * ((level - a) / (b - a) if b != a else 1.0)
    return 1.0 / (2 * math.pi * (t63 - t[0]))


def run_step_response(runner: FmuRunner, amplitude: float, tolerance: float, max_time: float = 1000.0):
    """v(t) after a step of ``amplitude`` on the input at t = 0, long enough to be settled
    (the horizon grows ×4 from 1 s until the last quarter varies by < 2 % and the 63 % point is early)."""
    values = {runner.input_name: amplitude}
    if runner.builtin:
        values[EXCITATION[0]] = 0.0
    runner.start(tolerance, values)
    ts, vs = [0.0], [runner.value()]
    horizon, t = 1.0, 0.0
    while True:
        grid = np.linspace(t, horizon, 1001)[1:]
        for tn in grid:
            vs.append(runner.step(t, tn - t))
            ts.append(tn)
            t = tn
        tt, vv = np.asarray(ts), np.asarray(vs)
        tail = vv[tt >= 0.75 * horizon]
        final = float(np.mean(tail))
        spread = float(np.max(tail) - np.min(tail))
        early = np.any(np.abs(vv[tt <= 0.25 * horizon]) >= (1 - math.exp(-1)) * abs(final))
        if abs(final) > 0 and spread < 0.02 * abs(final) and early:
            runner.finish()
            return tt, vv
        if horizon >= max_time:
            runner.finish()
            raise UserError(f"{runner.name}: the step response of {runner.output_name!r} does not settle within "
                            f"{max_time:g} s: cannot estimate the bandwidth (give the frequencies)")
        horizon *= 4


def estimate_bandwidth(factory: FmuRunnerFactory, amplitude: float, tolerance: float) -> float:
    """The plant's bandwidth (Hz) from its step response (excitation.corner_frequency)."""
    runner = factory()
    try:
        t, v = run_step_response(runner, amplitude, tolerance)
    finally:
        runner.close()
    return corner_frequency(t, v)
