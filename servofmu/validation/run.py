"""`servofmu validate` from files: one result file, or several side by side, replayed on one data file
(servofmu.validation.replay.validate); the pages are servofmu.output.validation_report's and
servofmu.output.model_comparison's."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

from ..errors import UserError
from ..identification.results import read_result
from ..measurement.datafile import read_data_file
from .replay import MIN_FIT, Validation, validate

__all__ = ["validate_files", "validate_several", "unique_labels"]


def _controller(controller):
    """The controller file of closed-loop records, read (None for open-loop data)."""
    if controller is None:
        return None
    from ..model.controller import load_controller

    return load_controller(controller)


def validate_files(result_path: str | Path, data_path: str | Path, skip: float = 0.0,
                   controller: str | Path | None = None, min_fit: float = MIN_FIT,
                   progress: Callable[[int, int], None] | None = None) -> Validation:
    """Validate the result file ``result_path`` on the data file ``data_path`` (closed-loop records with the
    controller file ``controller``; ``skip`` seconds left out at every record's start) with the minimum fit
    ``min_fit`` (%).  ``progress(done, total)`` (runtime.Progress): 0 of 1 before the model is simulated on the data,
    1 of 1 after.  Nothing is written."""
    report = progress or (lambda done, total: None)
    law = _controller(controller)
    report(0, 1)
    v = validate(read_result(result_path), read_data_file(data_path), skip, law, min_fit=min_fit)
    report(1, 1)
    return v


def unique_labels(names: Sequence[str]) -> list[str]:
    """``names`` with repeats numbered: a, a (2), b."""
    out: list[str] = []
    for name in names:
        label, n = name, 2
        while label in out:
            label, n = f"{name} ({n})", n + 1
        out.append(label)
    return out


def validate_several(result_paths: Sequence[str | Path], data_path: str | Path, skip: float = 0.0,
                     controller: str | Path | None = None, min_fit: float = MIN_FIT,
                     progress: Callable[[int, int], None] | None = None) -> list[tuple[str, Validation]]:
    """Validate several result files on one data file; (label, Validation) per result, labelled by its file's
    name (repeats numbered).  ``progress(done, total)`` counts the models.  Nothing is written."""
    paths = list(result_paths)
    if len(paths) < 2:
        raise UserError("give two or more result files to compare (one: servofmu validate RESULT.h5 DATA.h5)")
    law = _controller(controller)
    report = progress or (lambda done, total: None)
    data = read_data_file(data_path)
    pairs = []
    for k, (label, path) in enumerate(zip(unique_labels([Path(p).stem for p in paths]), paths)):
        report(k, len(paths))
        pairs.append((label, validate(read_result(path), data, skip, law, min_fit=min_fit)))
    report(len(paths), len(paths))
    return pairs
