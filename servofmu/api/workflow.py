"""The pipeline on objects: select, identify, validate several models and tune, each taking what a notebook
holds (Records, a DataFile, a Plant, a ControllerSpec, a Result) and returning objects, with no file written.

These are the command line's computations (selection.run.select_files, identification.run.identify_to_file,
validation.replay.validate, tuning.run.tune_axis) called on objects: the same checks, the same numbers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from ..display import figure, short_repr
from ..api_checks import check_arguments
from ..errors import UserError
from ..identification.results import Result
from ..measurement.datafile import DataFile, read_data_file
from ..model.controller import ControllerSpec, load_controller
from ..model.plant import Plant
from ..validation.replay import Validation, validate
from ..runtime import Progress, RunOptions
from .records import Records

if TYPE_CHECKING:  # loaded where they are used: selection and tuning import much
    from matplotlib.figure import Figure

    from ..selection.select import SelectOptions
    from ..selection.store import Selection
    from ..tuning.run import Tuning
    from ..tuning.search import TuneOptions

__all__ = ["identify", "select", "compare_models", "ModelComparison", "tune", "as_data", "check_plant"]

# what the functions take as data and as a drive (with ``from __future__ import annotations``, names only)
DataLike = "Records | DataFile | str | Path"
DriveLike = "ControllerSpec | str | Path | None"


def as_data(data: DataLike) -> DataFile:
    """A DataFile from Records, a DataFile or the path of a data file."""
    if isinstance(data, Records):
        return data.to_data_file()
    if isinstance(data, DataFile):
        return data
    if isinstance(data, (str, Path)):
        return read_data_file(data)
    raise UserError(f"data: give Records, a DataFile or a data file's path, not {type(data).__name__}")


def _controller(controller) -> ControllerSpec | None:
    if controller is None or isinstance(controller, ControllerSpec):
        return controller
    if isinstance(controller, (str, Path)):
        return load_controller(controller)
    raise UserError(f"controller: give a ControllerSpec or a controller file, not {type(controller).__name__}")


def identify(data: DataLike, structure: Plant | str | Path, *, controller: DriveLike = None,
             method: str | None = None, ann: object = None, seed: int = 0, iterations: int | None = None,
             polish: bool = True, skip: float = 0.0, progress: Progress | None = None,
             threads: int | None = None) -> Result:
    """Identify the plant of ``data`` in ``structure`` (``servofmu identify``, nothing written).

    Parameters
    ----------
    data : Records, DataFile or path
        Stepped-sine data or records; with ``controller``, a drive's logs.
    structure : Plant, str or Path
        The structure: a Plant (e.g. a selection's ``chosen.result.structure``), a plant file or an example's name.
    controller : ControllerSpec or path, optional
        The drive whose logs ``data`` holds: the candidates are replayed in its loop (``--closed-loop``).
    method, ann, seed, iterations, polish, skip
        As ``servofmu identify`` (``ann`` a trained network or its file).
    progress : callable, optional
        Called with (swarm iterations done, iterations).

    Returns
    -------
    Result
        The identified plant, its 95 % intervals, its fit and provenance.
    """
    check_arguments(identify, locals())
    from ..identification.run import IdentifyOptions, identify_to_file

    options = IdentifyOptions(method=method, seed=seed, polish=polish, iterations=iterations, skip=skip,
                              closed_loop=_controller(controller))
    return identify_to_file(as_data(data), structure, None, ann_file=ann, options=options,
                            run=RunOptions(progress=progress, command="servofmu.identify"), threads=threads)


def select(data: DataLike | list, validation: DataLike, *, controller: DriveLike = None,
           options: SelectOptions | None = None, workers: int | None = 0, progress: Progress | None = None
           ) -> Selection:
    """Choose the structure of the axis (``servofmu select``, nothing written).

    Parameters
    ----------
    data : Records, DataFile or path, or a list of them
        The data every candidate is fitted to.
    validation : Records, DataFile or path
        Data of the same axis that no candidate is fitted to: the ranking is on it.
    controller : ControllerSpec or path, optional
        The drive whose logs the data are (the candidates are fitted in its loop).
    options : SelectOptions, optional
        Candidates, orders, seed, iterations ... (its ``closed_loop`` is set from ``controller``).
    workers : int or None
        Worker processes (0: this process, the default here; None: one per core).

    Returns
    -------
    Selection
        The candidates in rank order; ``chosen.result`` is the chosen structure's identification.
    """
    check_arguments(select, locals())
    from dataclasses import replace

    from ..selection.run import select_files
    from ..selection.select import SelectOptions  # noqa: F811

    parts = data if isinstance(data, (list, tuple)) else [data]
    options = replace(options or SelectOptions(), closed_loop=_controller(controller))
    return select_files([as_data(d) for d in parts], as_data(validation), None, options,
                        RunOptions(workers=workers, progress=progress, command="servofmu.select"))


@dataclass(frozen=True)
class ModelComparison:
    """Several models validated on the same data: one :class:`~servofmu.validation.replay.Validation` per model, by
    label, in the order given; :meth:`table` has a column per model."""

    validations: dict[str, Validation]

    def table(self) -> dict[str, dict[str, object]]:
        """Row -> model label -> value: the mean and worst fit (%), the verdict, the residual tests, and each
        identified parameter as "value [low, high]" (its 95 % interval): servofmu.output.model_comparison."""
        from ..output.model_comparison import comparison_rows

        return comparison_rows(list(self.validations.items()))

    def __repr__(self) -> str:
        fits = self.table()["fit % (mean)"]
        return short_repr("ModelComparison", f"{len(fits)} models on one data set",
                          [figure(f"{label} fit", value, "%", ".4g") for label, value in fits.items()])

    def _repr_html_(self) -> str:
        """One table, a column per model (servofmu.output.model_comparison.comparison_table)."""
        from ..output.model_comparison import comparison_table

        return (f'<div><p><b>ModelComparison</b> {len(self.validations)} models</p>'
                f"{comparison_table(list(self.validations.items()))}</div>")

    def overlay(self, ax: object = None, which: str | None = None) -> Figure:
        """Measured and simulated outputs of every model on one axes per record or experiment
        (servofmu.validation_overlay)."""
        from ..output.figures import validation_overlay

        return validation_overlay(self.validations, ax=ax, which=which)

    def residual_tests(self, ax: object = None) -> Figure:
        """Every model's residual autocorrelation and input cross-correlation with their bounds
        (servofmu.residual_tests)."""
        from ..output.figures import residual_tests

        return residual_tests(self.validations, ax=ax)

    def bode(self, ax: object = None, bands: bool = True) -> Figure:
        """Every model's G(jω) with its 95 % band over the data's measured points, if any (servofmu.bode)."""
        from ..output.figures import bode

        data = next(iter(self.validations.values())).data_file
        return bode({k: v.result for k, v in self.validations.items()}, data=data, bands=bands, ax=ax)

    def friction_curve(self, ax: object = None) -> Figure:
        """Every model's friction force against velocity in steady sliding (servofmu.friction_curve)."""
        from ..output.figures import friction_curve

        return friction_curve({k: v.result for k, v in self.validations.items()}, ax=ax)

    def best(self) -> str:
        """The label of the model with the highest mean fit."""
        fits = self.table()["fit % (mean)"]
        return max(fits, key=lambda k: -math.inf if math.isnan(fits[k]) else fits[k])


def compare_models(results: Sequence[Result] | dict[str, Result], data: DataLike, *, controller: DriveLike = None,
                   skip: float = 0.0, min_fit: float | None = None) -> ModelComparison:
    """Validate several identified models on the same data (``servofmu validate`` for each).

    Parameters
    ----------
    results : sequence of Result, or dict label -> Result
        The models; a sequence is labelled by each result's structure name (made unique).
    data : Records, DataFile or path
        Data to validate on (preferably none of the models was fitted to it).
    controller : ControllerSpec or path, optional
        The drive whose logs ``data`` holds: each model is replayed in its loop.
    skip, min_fit
        As ``servofmu validate``.

    Returns
    -------
    ModelComparison
        One Validation per model; ``table()`` has a column per model (mean fit %, verdicts, parameters with
        their 95 % intervals) and the notebook shows it as one table.
    """
    check_arguments(compare_models, locals())
    if isinstance(results, Result):
        results = [results]
    if isinstance(results, dict):
        labelled = dict(results)
    else:
        from ..validation.run import unique_labels

        results = list(results)
        labelled = dict(zip(unique_labels([getattr(r, "plant", None) and r.plant.name or "model" for r in results]),
                            results))
    if not labelled:
        raise UserError("results: give at least one Result")
    for label, r in labelled.items():
        if not isinstance(r, Result):
            raise UserError(f"results: {label!r} is a {type(r).__name__}, not a Result (servofmu.read_result, "
                            "servofmu.api.identify)")
    ds, ctrl = as_data(data), _controller(controller)
    extra = {} if min_fit is None else {"min_fit": min_fit}
    return ModelComparison({label: validate(r, ds, skip, ctrl, **extra) for label, r in labelled.items()})


def tune(result: Result, controller: DriveLike, *, stroke: float | None = None, speed: float | None = None,
         task: str | Path | None = None, method: str = "pso", options: TuneOptions | None = None,
         compensate: bool = False, progress: Progress | None = None) -> Tuning:
    """Tune the drive's gains on an identified axis (``servofmu tune``, nothing written).

    Parameters
    ----------
    result : Result
        The identified axis.
    controller : ControllerSpec or path
        The drive: its sample time, delay, limit and encoder stay; its gains are compared with.
    stroke, speed : float, optional
        The reversing stroke tuned for (m, m/s; defaults as ``servofmu tune``); or ``task``, a reference file.
    method : {"pso", "rule"}
        The swarm within the sensitivity bound, or the reference rule alone.
    options : TuneOptions, optional
        The bound on the sensitivity peak, the swarm's and the uncertainty set's settings.

    Returns
    -------
    Tuning
        Every controller's run (given, rule, tuned); ``controller`` is the one chosen.
    """
    check_arguments(tune, locals())
    from ..tuning.task import load_task
    from ..tuning.run import tune_axis
    from ..tuning.search import TuneOptions  # noqa: F811  (at run time: the one for the default)

    ctrl = _controller(controller)
    if ctrl is None:
        raise UserError("controller: give the drive's ControllerSpec or controller file")
    if not isinstance(result, Result):
        raise UserError(f"result: give a Result, not {type(result).__name__}")
    return tune_axis(result, ctrl, load_task(task, stroke, speed, ctrl.sample_time), options or TuneOptions(),
                     method=method, compensate=compensate, progress=progress)


def check_plant(plant: Plant | Result) -> Plant:
    """``plant`` as a Plant: a Result's identified plant, or a Plant."""
    if isinstance(plant, Result):
        return plant.plant
    if isinstance(plant, Plant):
        return plant
    raise UserError(f"plant: give a Plant or a Result, not {type(plant).__name__}")
