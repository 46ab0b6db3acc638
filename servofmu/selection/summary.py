"""A selection's outcome for people and scripts: the ranking as a plain-text table, as one JSON object, and the
one-line note of a selection on chaotic records."""
from __future__ import annotations

import math

from .run import RANKED_SAMPLES, SHORTEST_SHARE, Selection

__all__ = ["selection_text", "selection_json", "rough_warning"]


def selection_json(selection: Selection) -> dict:
    """One object for scripts: the chosen candidate, the outputs, and every candidate's scores in rank order."""
    return {"chosen": selection.chosen.name if selection.chosen else None, "kind": selection.kind,
            "outputs": selection.outputs, "roughness": selection.roughness, "horizon": selection.horizon,
            "roughness_whole": selection.roughness_whole, "ranked_share": selection.ranked_share,
            "ranked_levels": selection.ranked_levels,
            "final_bic": selection.final.bic if selection.final else None,
            "undetermined": list((selection.final or selection.chosen).undetermined) if selection.chosen else [],
            "candidates": [{"rank": s.rank, "name": s.name, "status": s.status, "message": s.message,
                            "parameters": s.parameters, "samples": s.samples, "bic": s.bic, "aic": s.aic,
                            "neg2loglik": s.neg2loglik, "validation_fit_percent": s.validation_fit,
                            "validation_neg2loglik": s.validation_neg2loglik, "white": s.white,
                            "undetermined": list(s.undetermined), "flags": list(s.flags), "seconds": s.seconds,
                            "screened": s.screened}
                           for s in selection.scores]}


def rough_warning(selection: Selection) -> str | None:
    """What a chaotic response means for the user, in one line: the records were cut where the whole of them was
    chaotic (the selection made on their predictable start), or the chosen fit is still rough; None otherwise."""
    if selection.chosen is None:
        return None
    if selection.horizon < 1:
        over = "the whole records" if selection.ranked_share == 1 else "the ranked records (above)"
        return (f"note: the response is chaotic in the parameters over {over} (one standard error from "
                f"the best fits −2·ln L rose by {selection.roughness_whole:.3g}, not about 1): the candidates "
                f"were fitted and ranked on the first {selection.horizon:g} of every record "
                f"({selection.horizon_seconds:.3g} s of the longest), where it rises by {selection.roughness:.3g} "
                "(docs/selection.md, chaotic records)")
    if selection.rough:
        return (f"warning: the response of {selection.chosen.name} is chaotic in its parameters on these records: "
                f"one standard error from its fit −2·ln L rises by {selection.roughness:.3g}, not about 1, and over "
                f"no start of the records down to {SHORTEST_SHARE:g} of them is it regular: its intervals do not "
                "hold, and structures are ranked by where their polishes happened to end (docs/selection.md, chaotic "
                "records)")
    return None


def long_records_lines(selection: Selection) -> list[str]:
    """Where the candidates were ranked on a share of long records: that share and the chosen structure's fit on
    the whole records; and what the chosen fit does not determine (the combinations the data fixes instead)."""
    lines = []
    if selection.ranked_share < 1 and selection.chosen is not None:
        final = selection.final
        how = "every level's first realisation after its transient periods" if selection.ranked_levels else \
            "at a reduced rate, then their first share" if selection.kind == "records" else \
            "their first share: a loop runs at its drive's rate"
        if final is not None:
            then = (f"{final.name} then polished on the whole records (BIC {final.bic:.6g}, worst validation fit "
                    f"{final.worst_validation_fit:.3f} %)")
        elif selection.horizon < 1:  # chaotic over the share: no polish over the whole records either
            then = ("not polished on the whole records, whose response is chaotic (the note below): the share's fit is "
                    "written")
        else:
            then = "its polish on the whole records failed: the share's fit is written"
        lines.append(f"ranked on {selection.ranked_share:.3g} of the records' fitted samples ({RANKED_SAMPLES}, "
                     f"{how}); {then}")
    chosen = selection.final or selection.chosen
    if chosen is not None and chosen.result is not None:
        for group in chosen.result.confounded():
            lines.append(group.line())
    return lines


def selection_text(selection: Selection) -> str:
    """The ranking as a plain-text table, the chosen candidate and the files written."""
    lines = [f"{'rank':>4}  {'candidate':<22}{'p':>3}{'BIC':>13}{'ΔBIC':>10}{'val. fit %':>12}{'Δ val.':>9}"
             f"{'white':>7}  flags"]
    fitted = [s for s in selection.scores if s.status == "fitted" and math.isfinite(s.bic)]
    best_bic = min((s.bic for s in fitted), default=math.nan)
    best_val = min((s.validation_neg2loglik for s in fitted), default=math.nan)
    for s in selection.scores:
        if s.status != "fitted":
            lines.append(f"{s.rank:>4}  {s.name:<22}  fit failed: {s.message}")
            continue
        white = "-" if s.white is None else ("yes" if s.white else "no")
        flags = ", ".join(s.flags) + (f" ({', '.join(s.undetermined)})" if s.undetermined else "")
        flags = "; ".join(x for x in (flags, "screened" if s.screened else "", s.message) if x)
        lines.append(f"{s.rank:>4}  {s.name:<22}{s.parameters:>3}{s.bic:>13.6g}{s.bic - best_bic:>10.1f}"
                     f"{s.worst_validation_fit:>12.3f}{s.validation_neg2loglik - best_val:>9.1f}{white:>7}  {flags}")
    chosen = selection.chosen
    lines.append(f"chosen: {chosen.name}" if chosen else "no candidate could be fitted")
    lines += long_records_lines(selection)
    if rough_warning(selection):
        lines.append(rough_warning(selection))
    lines.append("wrote " + ", ".join(selection.outputs.values()))
    return "\n".join(lines)
