"""`servofmu validate`: an identified model checked on data it was not fitted to (docs/validation.md).

The identified plant is simulated on every record of a data file — driven by the recorded input with the
record's own intersample behaviour, from rest at its first sample, compared on the signal the record measures
(the velocity, or the raw position with its unknown zero removed) — and on every stepped-sine experiment (the
exact sine from rest through the stored window).  Per record or experiment:

- the fit as MATLAB's ``compare`` defines it, 100·(1 − ‖y − ŷ‖/‖y − mean(y)‖);
- for records, the residual analysis of MATLAB's ``resid``: the autocorrelation of the residuals e (lags
  1..25) and their cross-correlation with the input u (lags −25..25), with 99 % bounds.  Under the hypothesis
  of a right model, e is white and independent of u: the normalised autocorrelation has standard deviation
  1/√N at every lag, the cross-correlation √(Σ_k r_e(k)·r_u(k))/√N.  The bounds are drawn for all lags together
  (each lag at 1 − 0.01/K for K lags, Bonferroni), so that a right model stays within them with 99 %
  probability however smooth the input; MATLAB draws the same bounds per lag (z = 2.58), which a right model
  leaves at some lag of 25 one time in five.  The per-lag count is reported as well.  Residuals below
  ``EXACT`` times the spread of the signal are the simulation's own error (noise-free data): there is no noise
  to test, and the tests count as passed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import atomic_write, check_output_path
from ..identification.criterion import POLISH_RTOL, check_structure, fit_percent, record_data, record_errors
from ..identification.results import Result, read_result
from ..measurement.datafile import DataFile, ExperimentResult, read_data_file
from ..measurement.frf import harmonics
from ..runtime import utc_now
from ..simulation.batch import BatchSimulator
from .html import escape, figure, number, page, png_bytes, table
from .plots import MAX_PANELS, pyplot

__all__ = ["ResidualTest", "RecordValidation", "ExperimentValidation", "Validation", "residual_test", "validate",
           "validate_files", "validation_json", "validation_text", "validation_html", "validation_figure", "LAGS",
           "LEVEL", "EXACT"]

LAGS = 25      # lags of the correlation functions (MATLAB's resid default)
LEVEL = 0.99   # confidence of the bounds
EXACT = 1e-7   # residuals below this fraction of the signal's spread: the model reproduces noise-free data


# ---------------------------------------------------------------------------
# Residual analysis
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ResidualTest:
    """Correlations of the residuals e and the input u, with their bounds under "e white and independent of u".

    ``autocorrelation`` r_e(k), k = 0..LAGS (r_e(0) = 1); ``cross_lags`` −LAGS..LAGS and ``cross_correlation``
    r_eu(k) = corr(e(t + k), u(t)); ``auto_sigma``, ``cross_sigma``: their standard deviations under the
    hypothesis; ``z``: the joint 99 % quantile (Bonferroni over all lags of one function); ``z_per_lag``: the
    per-lag one (MATLAB's); ``exact``: the residuals are below EXACT times the signal's spread.
    """

    samples: int
    exact: bool
    autocorrelation: np.ndarray
    cross_lags: np.ndarray
    cross_correlation: np.ndarray
    auto_sigma: float
    cross_sigma: float
    z: float
    z_per_lag: float

    @property
    def white(self) -> bool:
        """The autocorrelation stays within the bounds at every lag 1..LAGS."""
        return self.exact or bool(np.all(np.abs(self.autocorrelation[1:]) <= self.z * self.auto_sigma))

    @property
    def independent(self) -> bool:
        """The cross-correlation with the input stays within the bounds at every lag."""
        return self.exact or bool(np.all(np.abs(self.cross_correlation) <= self.z * self.cross_sigma))

    @property
    def passed(self) -> bool:
        return self.white and self.independent

    def outside_per_lag(self) -> tuple[int, int]:
        """Lags outside MATLAB's per-lag 99 % bounds: (autocorrelation, cross-correlation)."""
        return (int(np.sum(np.abs(self.autocorrelation[1:]) > self.z_per_lag * self.auto_sigma)),
                int(np.sum(np.abs(self.cross_correlation) > self.z_per_lag * self.cross_sigma)))


def _correlation(a: np.ndarray, b: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """(1/N)·Σ_t a(t + k)·b(t) / (σ_a·σ_b) for every lag k (means removed)."""
    a, b = a - a.mean(), b - b.mean()
    n, scale = a.size, math.sqrt(float(a @ a) * float(b @ b)) / a.size
    out = np.empty(lags.size)
    for i, k in enumerate(lags):
        out[i] = (a[k:] @ b[:n - k] if k >= 0 else a[:n + k] @ b[-k:]) / n
    return out / scale if scale > 0 else np.full(lags.size, np.nan)


def residual_test(e: np.ndarray, u: np.ndarray, y: np.ndarray, lags: int = LAGS,
                  level: float = LEVEL) -> ResidualTest:
    """The residual analysis of ``e`` against the input ``u`` (equal lengths, uniform sampling) for a measured
    output ``y``."""
    from scipy.stats import norm

    e, u = np.asarray(e, dtype=float), np.asarray(u, dtype=float)
    n = e.size
    lags = min(lags, n // 4)
    auto = _correlation(e, e, np.arange(lags + 1))
    cross_lags = np.arange(-lags, lags + 1)
    cross = _correlation(e, u, cross_lags)
    r_u = _correlation(u, u, cross_lags)
    r_e = np.concatenate([auto[:0:-1], auto])
    cross_var = max(float(np.sum(r_e * r_u)), 1.0 / n) if np.all(np.isfinite(r_u)) else 1.0
    exact = bool(np.sqrt(np.mean(e**2)) <= EXACT * np.std(y))
    return ResidualTest(samples=n, exact=exact, autocorrelation=auto, cross_lags=cross_lags, cross_correlation=cross,
                        auto_sigma=1 / math.sqrt(n), cross_sigma=math.sqrt(cross_var / n),
                        z=float(norm.ppf(1 - (1 - level) / 2 / max(lags, 1))),
                        z_per_lag=float(norm.ppf(1 - (1 - level) / 2)))


# ---------------------------------------------------------------------------
# Simulating the model on the data
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RecordValidation:
    """The model on one record: ``y`` measured and ``y_model`` simulated (the velocity, or the position with the
    best constant offset) at the compared samples, the input there, the fit (%) and the residual analysis."""

    name: str
    output: str
    hold: str
    time: np.ndarray
    u: np.ndarray
    y: np.ndarray
    y_model: np.ndarray
    fit: float
    residuals: ResidualTest
    closed_loop: bool = False  # the disturbances reach the outputs through the loop: residuals are not white

    @property
    def passed(self) -> bool:
        """The residual tests that apply: independence from the input always, whiteness for open-loop records."""
        return self.residuals.independent if self.closed_loop else self.residuals.passed


@dataclass(frozen=True)
class ExperimentValidation:
    """The model on one stepped-sine experiment: the analysed window measured (noisy if the file has noise) and
    simulated, the fit (%), and the relative error of the first-harmonic response H."""

    index: int
    amplitude: float
    frequency: float
    converged: bool
    time: np.ndarray
    y: np.ndarray
    y_model: np.ndarray
    fit: float
    H_error: float


@dataclass(frozen=True)
class Validation:
    """Everything :func:`validate` found."""

    result: Result
    data_file: DataFile
    records: tuple[RecordValidation, ...]
    experiments: tuple[ExperimentValidation, ...]

    @property
    def passed(self) -> bool:
        """Every record's residuals within their bounds (stepped-sine experiments have no residual test)."""
        return all(r.passed for r in self.records)


def _validate_records(sim: BatchSimulator, params: np.ndarray, data_file: DataFile, skip: float):
    out = []
    for rec in record_data(data_file, skip).records:
        response = sim.simulate_record(params[None], rec.time, rec.u, hold=rec.hold, rtol=POLISH_RTOL)
        e = record_errors(rec, response)[0]
        if not np.all(np.isfinite(e)):
            raise UserError(f"{data_file.path}: the identified model cannot be simulated on record {rec.name}")
        y = rec.y[rec.fitted]
        out.append(RecordValidation(name=rec.name, output=rec.output, hold=rec.hold, time=rec.time[rec.fitted],
                                    u=rec.u[rec.fitted], y=y, y_model=y + e, fit=fit_percent(y, e),
                                    residuals=residual_test(e, rec.u[rec.fitted], y)))
    return out


def _validate_closed_loop(structure, params: np.ndarray, data_file: DataFile, controller, skip: float):
    """Closed-loop records replayed in the loop from their reference: the position and the force command, each
    with its residuals tested against the reference (the loop's input)."""
    from ..identification.closed_loop import closed_loop_data
    from ..simulation.closed_loop import LoopSimulator

    data = closed_loop_data(data_file, controller, skip)
    sim = LoopSimulator(structure)
    out = []
    for rec in data.records:
        loop = sim.simulate_loop(params[None], rec.time, rec.reference, data.controller, rtol=POLISH_RTOL)
        f, r = rec.fitted, rec.reference[rec.fitted]
        for output, y, y_model in (("position", rec.position, loop.position[0]), ("force", rec.command,
                                                                                  loop.command[0])):
            e = y_model[f] - y[f]
            if not np.all(np.isfinite(e)):
                raise UserError(f"{data_file.path}: the identified model cannot be simulated in the loop of "
                                f"record {rec.name}")
            out.append(RecordValidation(name=rec.name, output=output, hold="zoh", time=rec.time[f], u=r, y=y[f],
                                        y_model=y_model[f], fit=fit_percent(y[f], e),
                                        residuals=residual_test(e, r, y[f]), closed_loop=True))
    return out


def _validate_experiment(sim: BatchSimulator, params: np.ndarray, e: ExperimentResult) -> ExperimentValidation:
    grid = np.union1d(e.transient.time, e.window.time)
    response = sim.simulate_sine(params[None], grid, e.amplitude, e.frequency, rtol=POLISH_RTOL)
    v_model = np.interp(e.window.time, grid, response.v[0])  # the window's times are grid points
    y = e.window.v_noisy if e.window.v_noisy is not None else e.window.v
    h = harmonics(e.window.time, v_model, e.frequency, start=e.window_start, periods=e.window_periods,
                  n_harmonics=1)
    H_data = e.H_noisy if e.H_noisy is not None else e.H
    return ExperimentValidation(index=e.index, amplitude=e.amplitude, frequency=e.frequency, converged=e.converged,
                                time=e.window.time, y=y, y_model=v_model, fit=fit_percent(y, v_model - y),
                                H_error=abs(h.first / e.U1 - H_data) / abs(H_data))


def validate(result: Result, data_file: DataFile, skip: float = 0.0, controller=None) -> Validation:
    """Simulate an identified model on every record and stepped-sine experiment of a data file.

    Parameters
    ----------
    result : Result
        An identification (:func:`servofmu.read_result`).
    data_file : DataFile
        Data the model was (preferably) not fitted to: records, a measurement, or both.
    skip : float
        Seconds left out at the start of every record (as ``identify --skip``).
    controller : ControllerSpec, optional
        The records are closed-loop logs of this controller: they are replayed in the loop from their reference,
        and the position and the force command are compared (as ``identify --closed-loop``).

    Returns
    -------
    Validation
        Per record the fit (%) and the residual analysis; per experiment the fit (%) over the analysed window
        and the error of the first-harmonic response.

    Raises
    ------
    UserError
        When the result's structure does not match the plant the data was measured on, the file holds nothing
        to validate on, or the model cannot be simulated on it.
    """
    check_structure(result.structure, data_file, "the result's structure")
    if not data_file.records and not data_file.experiments:
        raise UserError(f"{data_file.path}: holds no records and no experiments to validate on")
    sim = BatchSimulator(result.structure)
    params = result.plant.parameter_vector()
    if controller is not None:
        records = _validate_closed_loop(result.structure, params, data_file, controller, skip)
    else:
        records = _validate_records(sim, params, data_file, skip) if data_file.records else []
    experiments = [_validate_experiment(sim, params, e) for e in data_file.experiments]
    return Validation(result=result, data_file=data_file, records=tuple(records), experiments=tuple(experiments))


# ---------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------
def validation_json(v: Validation) -> dict:
    """One object for scripts."""
    def test(r: ResidualTest) -> dict:
        auto_out, cross_out = r.outside_per_lag()
        return {"exact": r.exact, "white": r.white, "independent_of_input": r.independent, "passed": r.passed,
                "max_autocorrelation_over_bound": float(np.max(np.abs(r.autocorrelation[1:])) / (r.z * r.auto_sigma)),
                "max_cross_correlation_over_bound": float(np.max(np.abs(r.cross_correlation)) / (r.z * r.cross_sigma)),
                "lags_outside_per_lag_bounds": {"autocorrelation": auto_out, "cross_correlation": cross_out},
                "autocorrelation": r.autocorrelation.tolist(), "cross_correlation": r.cross_correlation.tolist(),
                "autocorrelation_bound": r.z * r.auto_sigma, "cross_correlation_bound": r.z * r.cross_sigma}

    return {"method": v.result.method, "structure": v.result.structure.name, "data_file": str(v.data_file.path), "passed": v.passed,
            "records": [{"name": r.name, "output": r.output, "intersample": r.hold, "samples": int(r.y.size),
                         "fit_percent": r.fit, "closed_loop": r.closed_loop, "passed": r.passed,
                         "residual_test": test(r.residuals)} for r in v.records],
            "experiments": [{"index": e.index, "amplitude": e.amplitude, "frequency": e.frequency,
                             "converged": e.converged, "fit_percent": e.fit, "H_relative_error": e.H_error}
                            for e in v.experiments]}


def validation_text(v: Validation) -> str:
    """A plain-text table per record and experiment."""
    lines = [f"model {v.result.structure.name} ({v.result.method}) on {v.data_file.path}"]
    if v.records:
        lines.append(f"{'record':<24}{'output':>10}{'samples':>9}{'fit %':>12}{'white':>7}{'indep.':>8}")
        for r in v.records:
            white = ("yes" if r.residuals.white else "no") if r.closed_loop else ("yes" if r.residuals.white else "NO")
            lines.append(f"{r.name:<24}{r.output:>10}{r.y.size:>9}{r.fit:>12.4f}"
                         f"{white:>7}{'yes' if r.residuals.independent else 'NO':>8}")
        loop = any(r.closed_loop for r in v.records)
        lines.append("residual tests: " + ("cross-correlation with the reference (lags -25..25; in a closed loop "
                                           "the residuals are not white)" if loop else
                                           "autocorrelation (lags 1-25) and cross-correlation with the input (lags "
                                           "-25..25)") + " within their joint 99 % bounds: "
                     + ("passed" if v.passed else "FAILED"))
    if v.experiments:
        lines.append(f"{'experiment':<12}{'amplitude N':>12}{'frequency Hz':>14}{'fit %':>12}{'|dH|/|H|':>12}")
        for e in v.experiments:
            lines.append(f"{e.index:<12}{e.amplitude:>12g}{e.frequency:>14g}{e.fit:>12.4f}{e.H_error:>12.3e}"
                         + ("" if e.converged else "  (no steady state)"))
    return "\n".join(lines)


def validation_figure(v: Validation, which: str) -> bytes | None:
    """PNG: measured against simulated for every record (``which="records"``; with the residual correlations and
    their bounds) or every experiment's window (``"experiments"``), at most MAX_PANELS each."""
    items = (v.records if which == "records" else v.experiments)[:MAX_PANELS]
    if not items:
        return None
    plt = pyplot()
    cols = 3 if which == "records" else 1
    fig, axes = plt.subplots(len(items), cols, figsize=(12 if cols == 3 else 9, 2.8 * len(items)), squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1, 1]} if cols == 3 else None)
    for row, item in zip(axes, items):
        unit = "m" if getattr(item, "output", "v") == "position" else "m/s"
        row[0].plot(item.time, item.y, lw=1, label="measured")
        row[0].plot(item.time, item.y_model, "k--", lw=1, label="model")
        title = item.name if which == "records" else f"{item.amplitude:g} N, {item.frequency:g} Hz"
        row[0].set_title(f"{title}: fit {item.fit:.3f} %")
        row[0].set_ylabel(f"{'position' if unit == 'm' else 'v'} [{unit}]")
        row[0].set_xlabel("time [s]")
        row[0].legend(fontsize=8, loc="upper right")
        if which == "records":
            r = item.residuals
            lags = np.arange(r.autocorrelation.size)
            row[1].bar(lags[1:], r.autocorrelation[1:], width=0.6)
            row[1].axhline(r.z * r.auto_sigma, color="r", ls="--", lw=1)
            row[1].axhline(-r.z * r.auto_sigma, color="r", ls="--", lw=1)
            row[1].set_title("autocorrelation of e", fontsize=9)
            row[2].bar(r.cross_lags, r.cross_correlation, width=0.6)
            row[2].axhline(r.z * r.cross_sigma, color="r", ls="--", lw=1)
            row[2].axhline(-r.z * r.cross_sigma, color="r", ls="--", lw=1)
            row[2].set_title("cross-correlation of e and u", fontsize=9)
            for ax in row[1:]:
                ax.set_xlabel("lag [samples]")
        for ax in row:
            ax.grid(True, alpha=0.4)
    return png_bytes(fig)


def validation_html(v: Validation) -> list[str]:
    """The validation section of an HTML page (tables and figures)."""
    parts = []
    if v.records:
        rows = []
        for r in v.records:
            t = r.residuals
            auto_out, cross_out = t.outside_per_lag()
            rows.append([r.name, r.output, r.hold, str(r.y.size), number(r.fit, ".4f"),
                         "yes" if t.white else "no", "yes" if t.independent else "no", f"{auto_out} / {cross_out}"])
        parts += [table("validation-records", ["record", "output", "input", "samples", "fit %", "e white",
                                               "e independent of u", "lags outside per-lag 99 % bounds"], rows,
                        numeric_from=3),
                  '<p class="note">Fit: 100·(1 − ‖y − ŷ‖/‖y − mean y‖). Residual tests: autocorrelation (lags 1–25) '
                  "and cross-correlation with the input (lags −25..25) within their joint 99 % bounds.</p>"]
        parts.append(figure("Measured and simulated output of every record, with the residuals' correlations and "
                            "their joint 99 % bounds.", validation_figure(v, "records"), "validation of records"))
    if v.experiments:
        rows = [[str(e.index), number(e.amplitude, "g"), number(e.frequency, "g"), number(e.fit, ".4f"),
                 number(e.H_error, ".3e")] for e in v.experiments]
        parts += [table("validation-experiments", ["experiment", "amplitude [N]", "frequency [Hz]", "fit %",
                                                   "|H_model − H|/|H|"], rows, numeric_from=1),
                  figure("The analysed window of every experiment, measured and simulated from rest.",
                         validation_figure(v, "experiments"), "validation of experiments")]
    return parts


def validate_files(result_path: str | Path, data_path: str | Path, output: str | Path | None = None,
                   skip: float = 0.0, controller: str | Path | None = None) -> Validation:
    """Validate a result file on a data file (closed-loop records with the controller file ``controller``);
    write ``output`` (.html page or .png figure) if given."""
    if output is not None:
        output = check_output_path(output)
        if output.suffix.lower() not in (".html", ".png"):
            raise UserError(f"{output}: write an .html page or a .png figure")
    law = None
    if controller is not None:
        from ..model.controller import load_controller
        law = load_controller(controller)
    v = validate(read_result(result_path), read_data_file(data_path), skip, law)
    if output is None:
        return v
    if output.suffix.lower() == ".png":
        image = validation_figure(v, "records" if v.records else "experiments")
        atomic_write(output, image)
    else:
        title = f"Validation of {v.result.structure.name} on {Path(data_path).name}"
        parts = [f"<h1>{escape(title)}</h1>",
                 f"<p>Result <code>{escape(Path(result_path).name)}</code> ({escape(v.result.method)}), data "
                 f"<code>{escape(Path(data_path).name)}</code>: {len(v.records)} records, {len(v.experiments)} "
                 "experiments.</p>", *validation_html(v),
                 f'<p class="note">Made by servofmu on {escape(utc_now())}.</p>']
        atomic_write(output, page(title, parts))
    return v
