"""Figures of identified models to place anywhere: Bode plots with uncertainty bands, friction curves, measured
against simulated output and the residual tests, for one model or several on the same axes.

Every function returns a matplotlib Figure and takes ``ax=`` (the Axes to draw into; the figure they belong to
is returned), and none touches pyplot: the user's backend, rcParams and open figures stay as they are.  In a
notebook a returned Figure shows itself; write one with ``fig.savefig(path)``.

Models are given as one object, a sequence, or a mapping label -> object: identified results
(servofmu.identification.results.Result), plants (servofmu.model.plant.Plant) where only the model is needed,
or validations (servofmu.validation.replay.Validation) for the views of a validation.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..api_checks import check_arguments
from ..errors import UserError
from ..identification.results import Result
from ..measurement.datafile import DataFile, read_data_file
from ..model.friction import steady_friction
from ..model.plant import Plant
from .bode_band import response_band
from .plots import MAX_PANELS, bode_points, draw_measured, figure_axes
from ..validation.replay import RecordValidation, Validation, validate

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from numpy.typing import ArrayLike

# what the figure functions take (names only, under ``from __future__ import annotations``): one model or several
# (a sequence, (label, model) pairs, a dict label -> model), data (a DataFile, its path, servofmu.Records), axes
Models = "Result | Plant | Validation | Sequence | Mapping"
DataLike = "DataFile | str | Path | Records"
AxesLike = "Axes | Sequence[Axes] | None"

__all__ = ["bode", "friction_curve", "validation_overlay", "residual_tests", "labelled", "item_title",
           "item_unit", "validation_items"]

CURVE_POINTS = 300  # frequencies of a Bode curve, velocities of a friction curve


def _default_label(model, k: int) -> str:
    if isinstance(model, Result):
        return model.method
    if isinstance(model, Plant):
        return model.name
    if isinstance(model, Validation):
        return model.result.method
    return f"model {k + 1}"


def labelled(models, labels: Sequence[str] | None = None) -> list[tuple[str, object]]:
    """[(label, model)] of one model, a sequence of models or of (label, model) pairs, or a mapping label ->
    model; ``labels`` replace the labels (one per model).  Default labels: a result's method, a plant's name, a
    validation's method; repeated labels are numbered."""
    if isinstance(models, Mapping):
        pairs = [(str(k), m) for k, m in models.items()]
    elif isinstance(models, (Result, Plant, Validation)) or not isinstance(models, Sequence):
        pairs = [(_default_label(models, 0), models)]
    elif all(isinstance(m, tuple) and len(m) == 2 and isinstance(m[0], str) for m in models):
        pairs = [(label, m) for label, m in models]  # (label, model) pairs
    else:
        pairs = [(_default_label(m, k), m) for k, m in enumerate(models)]
    if not pairs:
        raise UserError("no model to draw")
    if labels is not None:
        labels = [labels] if isinstance(labels, str) else list(labels)
        if len(labels) != len(pairs):
            raise UserError(f"labels: {len(labels)} labels for {len(pairs)} models")
        pairs = [(str(lab), m) for lab, (_, m) in zip(labels, pairs)]
    seen: dict[str, int] = {}
    out = []
    for label, m in pairs:
        seen[label] = seen.get(label, 0) + 1
        out.append((label if seen[label] == 1 else f"{label} ({seen[label]})", m))
    return out


def _plant(model) -> Plant:
    if isinstance(model, Result):
        return model.plant
    if isinstance(model, Plant):
        return model
    raise UserError(f"expected an identified result or a plant, got {type(model).__name__}")


def _data_file(data) -> DataFile | None:
    """A DataFile of ``data``: a DataFile, a data file's path, or records held in memory (servofmu.Records)."""
    if hasattr(data, "to_data_file"):
        return data.to_data_file()
    return data if data is None or isinstance(data, DataFile) else read_data_file(data)


def _frequencies(plants: Sequence[Plant], data_file: DataFile | None) -> np.ndarray:
    """A log grid (Hz) a factor 2 beyond the measured first harmonics, else a decade beyond the models' corner
    frequencies."""
    points = [f for f, _, _ in bode_points(data_file).values()] if data_file else []
    measured = np.concatenate(points) if points else np.array([])  # records without first harmonics have none
    if measured.size:
        lo, hi = measured.min() / 2, measured.max() * 2
    else:
        corners = [abs(r) / (2 * np.pi) for p in plants for r in (*p.poles, *p.zeros) if r != 0]
        lo, hi = (min(corners) / 10, max(corners) * 10) if corners else (0.1, 100.0)
    return np.geomspace(lo, hi, CURVE_POINTS)


def _bode_axes(ax):
    """(figure, magnitude axes, phase axes or None): a single Axes draws the magnitude only."""
    if ax is not None and not isinstance(ax, (Sequence, np.ndarray)):
        fig, (ax_mag,) = figure_axes(ax, 1, (8, 4))
        return fig, ax_mag, None
    fig, (ax_mag, ax_ph) = figure_axes(ax, 2, (8, 7), sharex=True)
    return fig, ax_mag, ax_ph


def bode(results_or_plants: Models, data: DataLike | None = None, bands: bool = True, ax: AxesLike = None,
         labels: Sequence[str] | None = None, frequencies: ArrayLike | None = None, level: float = 0.95) -> Figure:
    """Bode magnitude and phase of the linear part G(jω) of one or several models, each with its uncertainty
    band, over the measured first harmonics of a data file.

    Parameters
    ----------
    results_or_plants : Result, Plant, sequence of them, or mapping label -> Result/Plant
        The models; a Result draws the band from its covariance, a Plant (or a result without a covariance)
        the line alone.
    data : DataFile or path, optional
        Measured data: its first harmonics H = V1/U1 are drawn as grey markers, one shape per excitation
        amplitude (with friction they lie off G, more at low amplitudes).
    bands : bool
        Draw the bands (default True).
    ax : matplotlib Axes or sequence of two Axes, optional
        (magnitude, phase) to draw into; one Axes draws the magnitude only; default a new Figure.
    labels : sequence of str, optional
        Legend labels, one per model (default: the result's method or the plant's name).
    frequencies : array_like, optional
        Frequencies in Hz (default: a factor 2 beyond the measured ones, else a decade beyond the poles and
        zeros).
    level : float
        The band's probability (default 0.95).

    Returns
    -------
    matplotlib.figure.Figure

    Notes
    -----
    The band comes from linearisation: the parameter covariance C of the result carried to ln G(jω) through its
    Jacobian J (central differences), σ²(ln|G|) = Re J C Re Jᵀ, σ²(arg G) = Im J C Im Jᵀ, drawn as ± z·σ
    (z = 1.96 for 95 %) in dB and degrees (servofmu.output.bode_band).  It is the band of the linear part
    over the identified parameters; friction parameters do not enter G.
    """
    check_arguments(bode, locals())
    models = labelled(results_or_plants, labels)
    data_file = _data_file(data)
    plants = [_plant(m) for _, m in models]
    f = np.asarray(frequencies, dtype=float).ravel() if frequencies is not None else _frequencies(plants, data_file)
    fig, ax_mag, ax_ph = _bode_axes(ax)
    for k, ((label, model), plant) in enumerate(zip(models, plants)):
        color = f"C{k}"
        G = plant.frequency_response(2 * np.pi * f)
        phase = np.degrees(np.unwrap(np.angle(G)))
        band = response_band(model, f, level) if bands and isinstance(model, Result) else None
        note = f" ({level:.0%} band)" if band is not None else \
            " (no covariance: no band)" if bands and isinstance(model, Result) else ""
        ax_mag.semilogx(f, 20 * np.log10(np.abs(G)), color=color, lw=1.5, label=label + note)
        if ax_ph is not None:
            ax_ph.semilogx(f, phase, color=color, lw=1.5)
        if band is not None:
            ax_mag.fill_between(f, *band.magnitude_db(), color=color, alpha=0.2, lw=0)
            if ax_ph is not None:
                ax_ph.fill_between(f, *band.phase_deg(phase), color=color, alpha=0.2, lw=0)
    if data_file is not None and bode_points(data_file):  # records of no sine have no first harmonics to draw
        draw_measured(ax_mag, ax_ph, data_file, colors=False)
    ax_mag.set_ylabel("|G| [dB re 1 m/(N·s)]")
    ax_mag.set_title("identified G(jω)" + (f", {level:.0%} bands" if bands else ""))
    for a in (ax_mag, ax_ph):
        if a is not None:
            a.grid(True, which="both", alpha=0.4)
    (ax_ph or ax_mag).set_xlabel("frequency [Hz]")
    if ax_ph is not None:
        ax_ph.set_ylabel("phase [deg]")
    ax_mag.legend(fontsize=8)
    return fig


def _velocity_range(plants: Sequence[Plant], data_file: DataFile | None) -> float:
    """A tenth beyond the largest measured velocity, else ten times the laws' largest velocity scale (Stribeck,
    smoothing), else 1 m/s."""
    if data_file is not None:
        from .report_entries import velocity_range

        return velocity_range(data_file)
    scales = [p.friction.get(k) for p in plants for k in ("vs", "v_smooth")]
    scales = [s for s in scales if s]
    return 10 * max(scales) if scales else 1.0


def friction_curve(results: Models, ax: AxesLike = None, labels: Sequence[str] | None = None,
                   v_max: float | None = None, data: DataLike | None = None, truth: Plant | None = None) -> Figure:
    """Friction force against velocity in steady sliding (a law's states at rest) of one or several models.

    Parameters
    ----------
    results : Result, Plant, sequence of them, or mapping label -> Result/Plant
        The models.
    ax : matplotlib Axes or sequence of Axes, optional
        Where to draw; every Axes gets the same curves (e.g. a second one to zoom into); default a new Figure.
    labels : sequence of str, optional
        Legend labels, one per model.
    v_max : float, optional
        The curve spans −v_max..v_max m/s (log-spaced towards 0, v = 0 excluded).  Default: a tenth beyond the
        largest velocity of ``data``, else ten times the largest velocity scale of the laws, else 1 m/s.
    data : DataFile or path, optional
        Data whose velocities set the default ``v_max``.
    truth : Plant, optional
        A true plant, drawn as a thick grey line beneath the models.

    Returns
    -------
    matplotlib.figure.Figure

    Notes
    -----
    F(v) comes from the model's own friction expression (servofmu.model.friction.steady_friction); the viscous
    friction a first-order G holds in its pole is not in it.
    """
    check_arguments(friction_curve, locals())
    models = labelled(results, labels)
    plants = [_plant(m) for _, m in models]
    if v_max is None:
        v_max = _velocity_range(plants + ([truth] if truth is not None else []), _data_file(data))
    half = np.geomspace(v_max * 1e-4, v_max, CURVE_POINTS)
    v = np.concatenate([-half[::-1], half])
    panels = np.asarray(ax, dtype=object).size if isinstance(ax, (Sequence, np.ndarray)) else 1
    fig, axes = figure_axes(ax, panels, (7, 4.5))
    curves = [(f"true ({truth.name})", truth, "-", "0.6", 4)] if truth is not None else []
    curves += [(label, plant, "--" if truth is not None else "-", f"C{k}", 1.5)
               for k, ((label, _), plant) in enumerate(zip(models, plants))]
    for label, plant, style, color, width in curves:
        force = steady_friction(plant, v)
        for a in axes:
            a.plot(v, force, style, color=color, lw=width, label=label)
    for a in axes:
        a.axhline(0, color="k", lw=0.5)
        a.axvline(0, color="k", lw=0.5)
        a.set_xlabel("velocity v [m/s]")
        a.grid(True, alpha=0.4)
    axes[0].set_ylabel("friction force F(v) [N]")
    axes[0].legend(fontsize=8)
    return fig


def item_title(item) -> str:
    """A record's name (and output) or an experiment's magnitude and frequency."""
    if isinstance(item, RecordValidation):
        return f"{item.name} ({item.output})"
    return f"{item.amplitude:g} N, {item.frequency:g} Hz"


def item_unit(item) -> str:
    """The unit of the compared signal."""
    output = getattr(item, "output", "v")
    return "m" if output == "position" else "N" if output == "force" else "m/s"


def _validations(models, data, labels, skip: float, controller) -> list[tuple[str, Validation]]:
    """(label, Validation) of validations, or of results validated on ``data`` (also given as (results, data))."""
    pair = isinstance(models, tuple) and len(models) == 2 and (isinstance(models[1], (DataFile, str, Path))
                                                               or hasattr(models[1], "to_data_file"))
    if data is None and pair:
        models, data = models
    pairs = labelled(models, labels)
    if data is None:
        bad = [label for label, m in pairs if not isinstance(m, Validation)]
        if bad:
            raise UserError(f"{bad[0]}: give validations, or results with data=")
        return pairs
    data_file = _data_file(data)
    if isinstance(controller, (str, Path)):
        from ..model.controller import load_controller

        controller = load_controller(controller)
    return [(label, m if isinstance(m, Validation) else validate(m, data_file, skip, controller, min_fit=0.0))
            for label, m in pairs]


def validation_items(v: Validation, which: str | None = None, max_panels: int = MAX_PANELS) -> list:
    """The records (``which="records"``), experiments (``"experiments"``) or both (None) of a validation, at most
    ``max_panels``: the panels of :func:`validation_overlay` and :func:`residual_tests`."""
    if which not in (None, "records", "experiments"):
        raise UserError(f"which: 'records', 'experiments' or None, got {which!r}")
    items = [*(v.records if which != "experiments" else ()), *(v.experiments if which != "records" else ())]
    return items[:max_panels]


def _rows(vals: list[tuple[str, Validation]], which, max_panels: int) -> list[list]:
    """Per panel the items of every validation (the same data: the same records and experiments)."""
    per_model = [validation_items(v, which, max_panels) for _, v in vals]
    n = len(per_model[0])
    if not n:
        raise UserError(f"{vals[0][1].data_file.path}: no {which or 'records or experiments'} to draw")
    if any(len(items) != n for items in per_model):
        raise UserError("the validations are on different data: give validations of the same data file")
    return [[items[i] for items in per_model] for i in range(n)]


def validation_overlay(validations: Models, data: DataLike | None = None, ax: AxesLike = None,
                       labels: Sequence[str] | None = None, which: str | None = None, skip: float = 0.0,
                       controller: object = None, max_panels: int = MAX_PANELS) -> Figure:
    """Measured against simulated output of one or several models: one Axes per record or experiment, the
    models overlaid.

    Parameters
    ----------
    validations : Validation, Result, sequence of them, or mapping label -> Validation/Result
        Validations (servofmu.validation.replay.validate) of the same data, or results with ``data`` (or the
        pair ``(results, data)``).
    data : DataFile or path, optional
        Data to validate results on (each simulated as `servofmu validate` does).
    ax : matplotlib Axes or sequence of Axes, optional
        One Axes per record/experiment drawn (see ``max_panels``); default a new Figure.
    labels : sequence of str, optional
        Legend labels, one per model.
    which : {"records", "experiments", None}
        Draw the records, the experiments' windows, or both (default; records first).
    skip : float
        Seconds at the start of each record left out (with ``data``).
    controller : optional
        The controller law of closed-loop records (with ``data``).
    max_panels : int
        At most this many records/experiments (default 8).

    Returns
    -------
    matplotlib.figure.Figure
    """
    check_arguments(validation_overlay, locals())
    vals = _validations(validations, data, labels, skip, controller)
    rows = _rows(vals, which, max_panels)
    fig, axes = figure_axes(ax, len(rows), (9, 2.8 * len(rows)))
    for a, items in zip(axes, rows):
        first = items[0]
        a.plot(first.time, first.y, color="k", lw=1, label="measured")
        for k, ((label, _), item) in enumerate(zip(vals, items)):
            a.plot(item.time, item.y_model, color=f"C{k}", ls="--", lw=1, label=f"{label}: fit {item.fit:.3f} %")
        unit = item_unit(first)
        a.set_title(item_title(first), fontsize=10)
        a.set_ylabel({"m": "position [m]", "N": "force [N]"}.get(unit, "v [m/s]"))
        a.set_xlabel("time [s]")
        a.grid(True, alpha=0.4)
        a.legend(fontsize=8, loc="upper right")
    return fig


def _correlation_pair(ax_auto, ax_cross, tests: list[tuple[int, str, object]]) -> None:
    """The residuals' autocorrelation and cross-correlation with the input of every model (grouped bars), with
    the joint bounds (red dashed; the same for every model on the same data)."""
    width = 0.8 / max(len(tests), 1)
    for j, (k, label, r) in enumerate(tests):
        shift = (j - (len(tests) - 1) / 2) * width
        color = f"C{k}" if len(tests) > 1 else "C0"
        lags = np.arange(r.autocorrelation.size)
        ax_auto.bar(lags[1:] + shift, r.autocorrelation[1:], width=width, color=color, label=label)
        ax_cross.bar(r.cross_lags + shift, r.cross_correlation, width=width, color=color)
    r = tests[0][2]
    exact = all(t.exact for _, _, t in tests)  # noise-free: the correlations are the simulation's rounding
    for a, bound, title in ((ax_auto, r.z * r.auto_sigma, "autocorrelation of e"),
                            (ax_cross, r.z * r.cross_sigma, "cross-correlation of e and u")):
        a.axhline(bound, color="r", ls="--", lw=1)
        a.axhline(-bound, color="r", ls="--", lw=1)
        a.set_title(title + (" (noise-free: tests do not apply)" if exact else ""), fontsize=9)
        a.set_xlabel("lag [samples]")
        a.grid(True, alpha=0.4)
    if len(tests) > 1:
        ax_auto.legend(fontsize=7)


def residual_tests(validations: Models, data: DataLike | None = None, ax: AxesLike = None,
                   labels: Sequence[str] | None = None, which: str | None = None, skip: float = 0.0,
                   controller: object = None, max_panels: int = MAX_PANELS) -> Figure:
    """The residual tests of one or several models: per record or experiment the autocorrelation of the
    residuals e = ŷ − y and their cross-correlation with the input, with the joint 99 % bounds.

    Parameters
    ----------
    validations : Validation, Result, sequence of them, or mapping label -> Validation/Result
        As for :func:`validation_overlay`.
    data : DataFile or path, optional
        Data to validate results on.
    ax : sequence of matplotlib Axes, optional
        Two Axes per record/experiment drawn, row by row (autocorrelation, cross-correlation); default a new
        Figure.
    labels, which, skip, controller, max_panels
        As for :func:`validation_overlay`.

    Returns
    -------
    matplotlib.figure.Figure

    Notes
    -----
    The bounds are ±z·σ with σ the correlation's standard deviation when e is white and independent of u and z
    the joint (Bonferroni) 99 % quantile over the lags (servofmu.identification.residuals); bars outside them
    fail the test.  A noise-free experiment has no residual test and gets a note instead.
    """
    check_arguments(residual_tests, locals())
    vals = _validations(validations, data, labels, skip, controller)
    rows = _rows(vals, which, max_panels)
    fig, axes = figure_axes(ax, 2 * len(rows), (9, 2.6 * len(rows)), nrows=len(rows), ncols=2)
    for i, items in enumerate(rows):
        ax_auto, ax_cross = axes[2 * i], axes[2 * i + 1]
        tests = [(k, label, item.residuals) for k, ((label, _), item) in enumerate(zip(vals, items))
                 if item.residuals is not None]
        if tests:
            _correlation_pair(ax_auto, ax_cross, tests)
            ax_auto.set_ylabel(item_title(items[0]), fontsize=8)
        else:
            for a in (ax_auto, ax_cross):
                a.text(0.5, 0.5, "noise-free: nothing to test", ha="center", va="center", fontsize=8,
                       transform=a.transAxes)
                a.set_xticks([])
                a.set_yticks([])
    return fig

