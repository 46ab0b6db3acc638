"""`servofmu identify` on broadband data (docs/broadband.md, "Fitting G(s)"): the frequency-domain fit of G to the
BLA of every level (servofmu.identification.frequency_fit), then the time-domain output-error fit of the whole
plant — G and the friction — on the file's records, the swarm's box the prior's widened to hold the frequency-domain
G's neighbourhood, and that G, with the structure's friction, its first particle.

The records are fitted as they were played: one run from rest, level after level, realisation after realisation
(servofmu.broadband.store), so the model starts at rest at the first sample, as it does for any record.  The
frequency-domain fit's G and intervals are stored in the result's provenance (``frequency_fit``); the result's
parameters and intervals are the time-domain fit's, as for records of any kind.
"""
from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np

from ..broadband.bla import split_periods
from ..broadband.frf import frf_of_file
from ..errors import ServofmuWarning, UserError
from ..measurement.datafile import read_data_file
from ..model.plant import Plant, load_plant
from ..runtime import RunOptions, utc_now
from .criterion import RecordData, RecordSeries, check_structure
from .features import prior_box, to_targets
from .frequency_fit import FrequencyFit, fit_bla
from .ann import AnnModel, load_ann
from .broadband_ann import broadband_sine_data
from .identifier import PSOANNIdentifier, swarm_options
from .methods import NEEDS_ANN
from .inputs import identification_provenance
from .prior import canonical_order, identified_mask, identified_names
from .results import Result, Stage, result_from_estimator, write_result
from .shortening import SEARCH_SAMPLES

__all__ = ["identify_broadband", "broadband_records", "period_noise", "broadband_start", "frequency_summary",
           "frequency_lines", "BIAS_NOTE"]

# Residuals above this many times the periods' noise are reported: a fit at the noise is within a few 1e-3 of 1 on
# records of 10⁴ samples and more (tests/test_frequency_fit.py)
ABOVE_NOISE = 1.05
# The polishes of a broadband fit with the law's sign smoothed these many times, before the structure's own: plain,
# stribeck_servo's default plan (stick and slip at 0.6 N) stopped a stick event from the best at 1.35 times the
# noise; smoothed 3 times first, it reached the best; its 60 s plan then stopped at 1.017 times the truth's residual
# in 20 of 20 seeds, where 3 then 1.5 reached it; 10 first moved fs by 20 % (docs/broadband.md)
SMOOTHING_CONTINUATION = (3.0, 1.5)

BIAS_NOTE = ("with friction the BLA is the best linear approximation of the whole plant at each level, not G: G "
             "fitted to it is biased (a lower gain, poles moved; most at the lowest level); the time-domain fit of G "
             "and the friction on the records is the result")


def broadband_records(data, skip: float = 0.0) -> RecordData:
    """The records of a broadband data file as one record, in the order they were played (the noisy output when
    the file has one); ``skip`` seconds at its start left out of the fit."""
    u = np.concatenate([lv.u.ravel() for lv in data.levels])
    y = np.concatenate([(lv.v if lv.v_noisy is None else lv.v_noisy).ravel() for lv in data.levels])
    t = np.arange(u.size) / data.plan.rate
    if not (math.isfinite(skip) and skip >= 0):
        raise UserError(f"skip must be 0 or a positive number of seconds, not {skip}")
    fitted = t >= skip
    if fitted.sum() < 10:
        raise UserError(f"{data.path}: {fitted.sum()} samples after skipping {skip:g} s; it needs at least 10")
    series = RecordSeries(name="broadband", time=t, u=u, y=y, output="v", hold="zoh", fitted=fitted)
    return RecordData(records=(series,), source=str(data.path))


def level_pieces(data, samples: int, skip: float = 0.0) -> RecordData | None:
    """The first realisation of every level as a record of its own, each fitted on the first ``samples`` / levels
    samples after its transient periods (and after ``skip`` seconds of the run): a short stand-in for the whole run
    that holds every level — the run's own start holds only the first level's transient.  Each piece is simulated
    from rest at its start, which the transient periods absorb as they absorb the run's state there (the premise of
    the BLA too); None where the plan has none (the pieces' starts would be fitted) or a level's response is not
    periodic (a limit cycle: its phase at a piece's end depends on the state the piece started in)."""
    plan = data.plan
    if plan.transient_periods < 1 or not all(lv.bla.periodic for lv in data.levels):
        return None
    per_level = max(samples // len(data.levels), 10)
    start = plan.transient_periods * plan.samples
    records, offset = [], 0
    for lv in data.levels:
        y = lv.v if lv.v_noisy is None else lv.v_noisy
        n = min(start + per_level, lv.u.shape[1])
        t = np.arange(n) / plan.rate
        fitted = (np.arange(n) >= start) & (offset + np.arange(n) >= skip * plan.rate)
        offset += lv.u.size  # the level's realisations, played one after the other
        if fitted.sum() >= 10:
            records.append(RecordSeries(name=f"{lv.level:g} N", time=t, u=lv.u[0, :n].astype(float),
                                        y=y[0, :n].astype(float), output="v", hold="zoh", fitted=fitted))
    return RecordData(records=tuple(records), source=str(data.path)) if records else None


def period_noise(data, periodic=None) -> float:
    """σ of the output's noise on one sample from the analysed periods of the levels marked ``periodic`` (all by
    default): a realisation's periods hold one response but for the noise (their deviations from its mean,
    M·N·(P − 1) degrees of freedom per level); NaN with P = 1 or no such level (where a limit cycle makes the periods
    differ, their deviations are its, not the sensor's)."""
    plan = data.plan
    used = [lv for lv, ok in zip(data.levels, periodic or [True] * len(data.levels)) if ok]
    if plan.periods < 2 or not used:
        return math.nan
    squares = 0.0
    for lv in used:
        y = split_periods(lv.v if lv.v_noisy is None else lv.v_noisy, plan.samples, plan.periods,
                          plan.transient_periods)
        squares += float(np.sum((y - y.mean(axis=1, keepdims=True)) ** 2))
    return math.sqrt(squares / (len(used) * plan.realisations * plan.samples * (plan.periods - 1)))


def broadband_start(structure: Plant, fit: FrequencyFit, spread: float):
    """(lower, upper, y0) in target coordinates: the prior's box widened so that G's part also holds the box of the
    prior's widths centred on the frequency-domain fit (a G biased by friction may lie far from the truth: the
    prior's box is kept), and the fit's G with the structure's friction (and load) as the first particle."""
    names = identified_names(structure)
    theta = structure.parameter_vector()[identified_mask(structure)]
    g = [names.index(n) for n in fit.names]
    theta[g] = fit.theta
    y0 = to_targets(structure, canonical_order(structure, theta))[0]
    lower, upper = prior_box(structure, spread)
    centre = (lower + upper) / 2
    bad = ~np.isfinite(y0)  # an unstable or overdamped fit has no log coordinates: the structure's instead
    y0[bad] = centre[bad]
    shift = np.zeros_like(y0)
    shift[g] = (y0 - centre)[g]
    return np.minimum(lower, lower + shift), np.maximum(upper, upper + shift), y0


def frequency_summary(fit: FrequencyFit, levels, seconds: float) -> dict:
    """What a result records of the frequency-domain fit (its provenance's ``frequency_fit``)."""
    return {"names": list(fit.names), "theta": fit.theta.tolist(), "intervals": fit.intervals.tolist(),
            "lines": int(sum(b.frequencies.size for _, b in levels)), "cost_ratio": fit.cost_ratio,
            "levels": [{"level": level, "cost_ratio": r} for (level, _), r in zip(levels, fit.cost_ratios)],
            "weights": fit.weights, "start": fit.start, "relative_error": fit.relative_error, "seconds": seconds,
            "note": BIAS_NOTE}


def frequency_lines(provenance: dict) -> list[str]:
    """The identify table's lines on the frequency-domain fit and the residuals against the periods' noise (none
    for other data)."""
    fd = provenance.get("frequency_fit")
    if not fd:
        return []
    noise = provenance.get("records_noise")  # results of older versions have none
    head = [] if noise is None else ["no noise level: no level's response is periodic"] if not noise["levels"] else [
        f"residuals {noise['residual_ratio']:.3g} times the noise of the periods (σ {noise['sigma']:.3g} from the "
        f"periodic levels {', '.join(f'{x:g}' for x in noise['levels'])} N; about 1 when the model fits)"]
    levels = ", ".join(f"{x['level']:g} N: {x['cost_ratio']:.3g}" for x in fd["levels"])
    lines = [f"frequency-domain fit of G to the BLA ({fd['lines']} lines; weights: {fd['weights']} variance): "
             f"relative error ‖G − G_BLA‖/‖G_BLA‖ {fd['relative_error']:.3g}, cost/dof {fd['cost_ratio']:.3g} ({levels}; about 1 "
             "when a linear G explains the BLA)",
             "  G from the BLA: " + ", ".join(f"{n} {v:.6g} [{lo:.6g}, {hi:.6g}]" for n, v, (lo, hi)
                                              in zip(fd["names"], fd["theta"], fd["intervals"]))]
    return head + lines + [f"  note: {fd['note']}"]


def _network(ann_file, method: str, structure: Plant):
    """The network of a method that needs one, refused where there is none or it estimates other parameters."""
    if ann_file is None:
        raise UserError(f"method {method} needs a network trained on this broadband plan (`servofmu dataset "
                        "BROADBAND.h5 ...` and `servofmu train`); or use method pso")
    ann = ann_file if isinstance(ann_file, AnnModel) else load_ann(ann_file)
    names = identified_names(structure)
    if list(ann.layout.parameter_names) != names:
        raise UserError(f"{ann_file if not isinstance(ann_file, AnnModel) else 'the network'} estimates "
                        f"{', '.join(ann.layout.parameter_names)}; the structure has {', '.join(names)}")
    return ann


def identify_broadband(data_file, structure_file, output, options, run: RunOptions, method: str,
                       threads: int | None = None, ann_file=None) -> Result:
    """Identify the plant of a broadband data file and write its result (module docstring); ``options`` as
    identification.run.IdentifyOptions, ``method`` the one chosen: the swarm from the frequency-domain G (pso),
    or the network ``ann_file`` (trained on the file's bands, identification.broadband_ann) and its search."""
    if options.closed_loop is not None:
        raise UserError(f"{data_file}: broadband data is open loop (the plant driven by the excitation): identify "
                        "without --closed-loop")
    structure = load_plant(structure_file)
    ann = None if method not in NEEDS_ANN else _network(ann_file, method, structure)
    ds = read_data_file(data_file)
    check_structure(structure, ds, f"the structure {structure_file}")
    data, levels = frf_of_file(data_file)
    t0 = time.perf_counter()
    fit = fit_bla(structure, [b for _, b in levels], data.plan.rate)
    seconds = time.perf_counter() - t0
    est = PSOANNIdentifier(structure, ann=ann, method=method, seed=options.seed, polish=options.polish,
                           pso=swarm_options(options.iterations), progress=run.progress, threads=threads)
    est.work_limit = options.work_limit
    est.smoothing_continuation = SMOOTHING_CONTINUATION
    if ann is None:
        est.start = broadband_start(structure, fit, est.spread)
    else:  # the paper's first stage: the network's estimate and box, read from the BLA's bands
        est.ann_data = broadband_sine_data(data)
    est.search_data = level_pieces(data, SEARCH_SAMPLES, options.skip)  # None: the run's start, as for records
    records = broadband_records(data, options.skip)
    est.fit(records)
    periodic = [bla.periodic for _, bla in levels]
    fitted, sigma = records.records[0], period_noise(data, periodic)
    ratio = est.fitness_ * float(np.std(fitted.y[fitted.fitted])) / sigma
    noise = None if data.plan.periods < 2 else {  # one period: no noise level
        "sigma": sigma if math.isfinite(sigma) else None, "residual_ratio": ratio if math.isfinite(ratio) else None,
        "levels": [lv for lv, ok in zip(data.plan.levels, periodic) if ok]}
    if math.isfinite(ratio) and ratio > ABOVE_NOISE:
        warnings.warn(f"{data_file}: the fit's residuals are {ratio:.3g} times the noise of the periods (σ "
                      f"{sigma:.3g}): a minimum beside the best, a structure that does not fit, "
                      "or a response that is not periodic (frf names such levels)", ServofmuWarning, stacklevel=2)
    elif noise is not None and not noise["levels"]:
        warnings.warn(f"{data_file}: no level's response is periodic in the excitation's period (a limit cycle or a "
                      "transient; frf names the component): the fit's residuals are not compared with a noise "
                      "level, and its intervals assume a response smooth in the parameters", ServofmuWarning,
                      stacklevel=2)
    theta0 = structure.parameter_vector()[identified_mask(structure)]
    theta0[[identified_names(structure).index(n) for n in fit.names]] = fit.theta
    est.stages_ = [Stage("frequency", theta0, fit.relative_error, seconds, fit.evaluations), *est.stages_]
    est.seconds_ += seconds
    provenance = identification_provenance(ds, structure_file, run.command,
                                           ann_file if isinstance(ann_file, (str, Path)) else None, options.skip,
                                           data_kind="broadband",
                                           frequency_fit=frequency_summary(fit, levels, seconds))
    provenance["records_noise"] = noise
    provenance["date"] = utc_now()
    result = result_from_estimator(est, method, provenance)
    if output is not None:  # None: nothing written, as for other data
        write_result(output, result, overwrite=True)  # claimed by the caller
    return result
