"""A selection's outcome (Selection) and SELECT.h5, the file that holds it: every fitted candidate's result and the
ranking (docs/selection.md), with the chosen structure's plant file and result beside it."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..fileio import atomic_write, store_array, write_hdf5
from ..text_digest import with_digest
from ..identification.results import write_comparison, write_result
from ..identification.roughness import ROUGH_RISE
from ..runtime import temporary_folder
from .select import CandidateScore, SelectOptions

__all__ = ["Selection", "write_selection", "SELECT_FORMAT"]

SELECT_FORMAT = "servofmu-selection"


@dataclass(frozen=True)
class Selection:
    """A selection's outcome: the candidates' scores in rank order (``scores[0]`` is chosen when it was fitted),
    the files fitted and validated on, the kind of data, the options and the outputs written."""

    scores: tuple[CandidateScore, ...]
    data_files: tuple[str, ...]
    validation_file: str
    kind: str
    options: SelectOptions
    outputs: dict
    # identification.roughness.response_roughness of the fits ranked first and of the lowest BIC, the larger (NaN:
    # not checked), on the records as fitted and on all of them
    roughness: float = math.nan
    horizon: float = 1.0  # the share of every record's fitted span the candidates were fitted and ranked on
    roughness_whole: float = math.nan
    horizon_seconds: float = math.nan  # that share of the longest record, in seconds
    # long records (more than RANKED_SAMPLES fitted samples): the share of their fitted samples the candidates were
    # ranked on, and the chosen structure polished again from its fit there on the whole records (its result written)
    ranked_share: float = 1.0
    final: CandidateScore | None = None
    ranked_levels: bool = False  # broadband data ranked on every level's first realisation (selection.data)

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        chosen = self.chosen
        head = (f"of {len(self.scores)} candidates on {len(self.data_files)} {self.kind} data file"
                f"{'s' * (len(self.data_files) != 1)}: " + (f"chosen {chosen.name!r} ({chosen.parameters} parameters)"
                                                          if chosen else "no fit succeeded"))
        fitted = [s for s in self.scores if s.status == "fitted" and math.isfinite(s.bic)]
        figures = ()
        if chosen is not None:
            figures += (figure("BIC", chosen.bic, "", ".6g"),)
            if len(fitted) > 1:
                figures += (figure(f"ΔBIC to {fitted[1].name}", fitted[1].bic - chosen.bic, "", ".3g"),)
            figures += (figure("worst validation fit", chosen.worst_validation_fit, "%", ".4g"),)
        table = tuple(figure(f"#{s.rank} {s.name} ({s.parameters} parameters): BIC", s.bic, "", ".6g")
                      for s in self.scores[:12])
        notes = ((f"{len(self.scores) - 12} more candidates",) if len(self.scores) > 12 else ()) + \
            ((f"validated on {self.validation_file}",) if self.validation_file else ())
        return Shown(type(self).__name__, head, figures, figures + table, notes)

    @property
    def rough(self) -> bool:
        """Whether the chosen fit's response is chaotic in its parameters (roughness.ROUGH_RISE): its intervals do not
        hold, and the ranking of the structures that share its rough terms is by where their polishes ended."""
        return bool(self.roughness > ROUGH_RISE)

    @property
    def chosen(self) -> CandidateScore | None:
        """The first-ranked candidate, None when no fit succeeded."""
        first = self.scores[0] if self.scores else None
        return first if first is not None and first.status == "fitted" and math.isfinite(first.bic) else None


def _controller_name(controller) -> str | None:
    """The controller of a closed-loop selection as its file (a ControllerSpec by where it was read from)."""
    return None if controller is None else str(getattr(controller, "source", controller))


def _key(score: CandidateScore) -> str:
    """The group of a candidate in SELECT.h5's /methods: its name with '/' as '_' (coulomb_2z)."""
    return score.name.replace("/", "_")


def write_selection(selection: Selection, outputs: dict[str, Path]) -> Selection:
    """SELECT.h5 (a comparison file of the fitted candidates' results plus /selection), and for a chosen candidate
    its plant file and result."""
    fitted = {_key(s): s.result for s in selection.scores if s.status == "fitted"}
    written = {"selection": str(outputs["selection"])}
    with temporary_folder("select") as tmp:
        base = tmp / "candidates.h5"
        write_comparison(base, fitted)
        write_hdf5(outputs["selection"], lambda f: _fill_ranking(f, selection), start_from=base)
    chosen = selection.chosen
    if chosen is not None:
        chosen = selection.final or chosen  # where it was ranked on a share: its fit on the whole records
        plant = replace(chosen.result.plant, name="selected")
        header = (f"# chosen by servofmu select: {chosen.name} (rank 1 of {len(selection.scores)}; BIC "
                  f"{chosen.bic:.6g}); identified from {', '.join(selection.data_files)}\n")
        atomic_write(outputs["plant"], with_digest(header + plant.to_toml()))
        write_result(outputs["result"], chosen.result, overwrite=True)  # claimed before any work
        written.update(plant=str(outputs["plant"]), result=str(outputs["result"]))
    return replace(selection, outputs=written)


def _fill_ranking(f, selection: Selection) -> None:
    """/selection: the ranking as columns in rank order, and the run's settings as attributes."""
    g = f.create_group("selection")
    s = selection.scores
    chosen = selection.chosen
    g.attrs.update({"format": SELECT_FORMAT, "schema_version": 1, "kind": selection.kind,
                    "chosen": chosen.name if chosen else "", "criterion": "bic", "roughness": selection.roughness,
                    "roughness_whole": selection.roughness_whole, "horizon": selection.horizon,
                    "ranked_share": selection.ranked_share, "ranked_levels": selection.ranked_levels,
                    "final_bic": selection.final.bic if selection.final else math.nan,
                    "data_files": json.dumps(list(selection.data_files)),
                    "validation_file": selection.validation_file,
                    "options": json.dumps({"candidates": selection.options.candidates,
                                           "orders": list(selection.options.orders), "seed": selection.options.seed,
                                           "iterations": selection.options.iterations,
                                           "spread": selection.options.spread, "skip": selection.options.skip,
                                           "closed_loop": _controller_name(selection.options.closed_loop),
                                           "screen": selection.options.screen,
                                           "budget": selection.options.budget})})
    store_array(g, "name", [x.name for x in s])
    store_array(g, "group", [_key(x) if x.status == "fitted" else "" for x in s])
    store_array(g, "status", [x.status for x in s])
    store_array(g, "message", [x.message for x in s])
    store_array(g, "flags", [",".join(x.flags) for x in s])
    store_array(g, "undetermined", [",".join(x.undetermined) for x in s])
    for column in ("parameters", "samples", "rank"):
        store_array(g, column, np.array([getattr(x, column) for x in s], dtype=np.int64))
    for column in ("neg2loglik", "aic", "bic", "validation_neg2loglik", "seconds", "worst_validation_fit"):
        store_array(g, column, np.array([getattr(x, column) for x in s], dtype=float))
    store_array(g, "screened", np.array([int(x.screened) for x in s], dtype=np.int8))
    store_array(g, "white", np.array([-1 if x.white is None else int(x.white) for x in s], dtype=np.int8))
    store_array(g, "validation_fit", [json.dumps(x.validation_fit) for x in s])
