"""Broadband measurement of an FMU (docs/broadband.md): the plan's whole signal played into the FMU's input port in
one Co-Simulation run from rest, the input held for one sample interval at a time (as a drive plays
``servofmu excitation``'s file), the output sampled at the same instants; then, per level, the BLA of the
analysed periods, stored with the records in a data file of kind ``broadband``.

Sample k of the output is the value at t_k = k/rate, before u[k] acts: what a drive's log holds and what the
zero-order-hold discretisation of the plant relates, so that on a linear plant the BLA is G_zoh(e^{jωT}) exactly.
Servofmu FMUs' built-in sine is switched off (excitation_amplitude = 0).
"""
from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, replace

import numpy as np

from ..fileio import claim_output, holds_outputs, output_mode
from ..measurement.measure import MeasureOptions, check_fmu, fmu_parameters, provenance_for
from ..runtime import RunOptions, check_memory, stop_if_asked
from ..simulation.fmpy_runs import EXCITATION, read_fmu
from ..simulation.fmu_runner import FmuRunner, FmuRunnerFactory
from .bla import estimate_bla, split_periods
from .signals import BroadbandPlan
from .store import BroadbandData, BroadbandLevel, read_broadband, write_broadband

__all__ = ["measure_broadband", "play", "PROGRESS_SCALE"]

PROGRESS_SCALE = 1000  # progress in thousandths of the whole signal
REPORT_EVERY = 0.5     # s between progress reports


def play(runner: FmuRunner, u: np.ndarray, rate: float, tolerance: float, progress=None) -> np.ndarray:
    """The FMU's output at t_k = k/rate for the input u[k] held on [t_k, t_k+1), from rest at t = 0."""
    values = {runner.input_name: 0.0}
    if runner.builtin:
        values[EXCITATION[0]] = 0.0
    runner.start(tolerance, values)
    v = np.empty(u.size)
    v[0] = runner.value()
    h, reported = 1.0 / rate, time.monotonic()
    for k in range(u.size - 1):
        runner.set_input(float(u[k]))
        v[k + 1] = runner.step(k * h, h)
        if progress is not None and time.monotonic() - reported > REPORT_EVERY:
            progress(int(PROGRESS_SCALE * (k + 1) / u.size), PROGRESS_SCALE)
            reported = time.monotonic()
        if k % 4096 == 0:
            stop_if_asked()
    runner.finish()
    return v


def _levels(plan: BroadbandPlan, u: np.ndarray, v: np.ndarray, noisy: np.ndarray | None) -> list[BroadbandLevel]:
    out = []
    for i, level in enumerate(plan.levels):
        y = v[i] if noisy is None else noisy[i]
        cut = (split_periods(x, plan.samples, plan.periods, plan.transient_periods, "record") for x in (u[i], y))
        bla = estimate_bla(*cut, plan.lines, plan.rate, plan.free_lines)
        out.append(BroadbandLevel(level, u[i], v[i], None if noisy is None else noisy[i], bla))
    return out


def _noise(v: np.ndarray, options: MeasureOptions) -> np.ndarray | None:
    """White Gaussian noise on v at the SNR of ``options`` (variance of v over the whole run / noise variance)."""
    if options.noise_snr_db is None:
        return None
    rng = np.random.default_rng([options.seed or 0, 0xB0AD])
    sigma = math.sqrt(float(np.var(v)) / 10 ** (options.noise_snr_db / 10))
    return v + sigma * rng.standard_normal(v.shape)


@holds_outputs  # its output is its own until it ends (fileio.output_claims)
def measure_broadband(fmu, output, plan: BroadbandPlan, options: MeasureOptions | None = None,
                      run: RunOptions | None = None) -> BroadbandData:
    """Broadband measurement of an FMU into a data file of kind ``broadband``.

    Parameters
    ----------
    fmu : str or Path
        A Co-Simulation FMU with a real input and output (``options.input``, ``options.output``).
    output : str or Path
        The data file to write (written once, at the end; nothing is written if the run fails).
    plan : BroadbandPlan
        Levels, band, rate, periods and realisations.
    options : MeasureOptions, optional
        Variable names, the solver's tolerance, measurement noise (``noise_snr_db``, ``seed``); the stepped
        sine's other options do not apply.
    run : RunOptions, optional
        ``overwrite``, ``command`` (provenance) and ``progress`` (thousandths of the signal, PROGRESS_SCALE).

    Returns
    -------
    BroadbandData
        The file read back: per level the records and the BLA.
    """
    options = (options or MeasureOptions()).validate()
    if options.noise_snr_db is not None and options.seed is None:
        options = replace(options, seed=0)
    run = run or RunOptions()
    out = claim_output(output, output_mode(run.overwrite, False), inputs=(fmu,))
    info = read_fmu(fmu)
    check_fmu(info, options)
    data = info.path.read_bytes()
    u = plan.signals()
    check_memory(f"a broadband measurement of {u.size} samples", 8 * 5 * u.size, "fewer periods or a lower --rate")
    runner = FmuRunnerFactory(data=data, name=info.path.name, input=options.input, output=options.output)()
    try:
        v = play(runner, u.ravel(), plan.rate, options.tolerance, run.report).reshape(u.shape)
    finally:
        runner.close()
    noisy = _noise(v, options)
    prov = provenance_for(info, hashlib.sha256(data).hexdigest(), options, run.command, "broadband plan")
    prov = {k: val for k, val in prov.items() if k not in _STEPPED_ONLY}
    prov.update(excitation="input", broadband=plan.to_json())
    write_broadband(out, plan, _levels(plan, u, v, noisy), prov, fmu_parameters(info))
    return read_broadband(out)


# the stepped sine's options that say nothing about a broadband run
_STEPPED_ONLY = {k for k in asdict(MeasureOptions()) if k not in ("input", "output", "tolerance", "noise_snr_db",
                                                                     "seed")} | {"frequency_source"}
