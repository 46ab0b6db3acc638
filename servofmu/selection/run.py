"""A selection from files to files (`servofmu select DATA.h5 … --validate OTHER.h5 -o SELECT.h5`): the data read
and checked, the candidates started from their linear estimates and fitted in worker processes or on a Dask
cluster, ranked, and written: SELECT.h5 (every candidate's result and the ranking, docs/selection.md), the chosen
structure as a plant file and its result as a RESULT.h5."""
from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import UserError, check_int
from ..fileio import all_or_none, claim_outputs, file_sha256, holds_outputs, output_mode
from ..identification.shortening import fitted_total
from ..identification.identifier import swarm_options
from ..identification.roughness import ROUGH_RISE, finite_covariance
from ..measurement.datafile import DataFile, data_name
from ..runtime import RunOptions, check_work, utc_now
from ..simulation.parallel import Workers
from .candidates import Candidate, candidate_plant, parse_candidates, term_candidates, with_second_stage
from .data import (check_validation, data_kind, estimation_series, first_share, fitted_seconds,
                   load_selection_data, ranked_data)
from .estimate import data_bandwidth, start_estimates
from .store import SELECT_FORMAT, Selection, write_selection
from .fitting import SAME_FIT, fit_all, fit_groups, keep_better, threads_per_job, with_new
from .select import (SCREEN_MARGIN, CandidateJob, CandidateScore, SelectOptions, could_win, rank,
                     response_roughness, start_neg2loglik)
from .starts import from_winner, nested_law_starts, reduced_starts, spring_starts, term_leader, within_first
from .terms import fewer_friction_terms, friction_terms_on_final, more_friction_terms, ranked_term_starts

__all__ = ["Selection", "select_files", "selection_outputs", "linear_starts", "frequency_starts", "RANKED_SAMPLES",
           "SELECT_FORMAT"]

def selection_outputs(output: str | Path, plant_output=None, result_output=None) -> dict[str, Path]:
    """The files a selection writes: SELECT.h5, the chosen plant file (default SELECT.toml beside it) and the
    chosen result (default SELECT-result.h5)."""
    output = Path(output)
    return {"selection": output, "plant": Path(plant_output or output.with_suffix(".toml")),
            "result": Path(result_output or output.with_name(output.stem + "-result.h5"))}


def _check_options(options: SelectOptions) -> list[Candidate]:
    check_int("seed", options.seed, 0)
    swarm_options(options.iterations)
    if not (isinstance(options.spread, (int, float)) and math.isfinite(options.spread) and options.spread > 0):
        raise UserError(f"spread must be a positive number, not {options.spread!r}")
    if not (isinstance(options.budget, (int, float)) and not isinstance(options.budget, bool) and options.budget > 0
            and math.isfinite(options.budget)):
        raise UserError(f"--budget (seconds a candidate's swarm may take) must be a positive number, not "
                        f"{options.budget!r}")
    candidates = parse_candidates(options.candidates, options.orders)
    check_work(f"{len(candidates)} candidates' swarms of up to --budget {options.budget:g} s each",
               len(candidates) * options.budget, options.work_limit, "give a smaller --budget or fewer --candidates")
    return candidates


def linear_starts(candidates: list[Candidate], data, files) -> dict[Candidate, object]:
    """Each candidate's start plant from the linear estimate of its order and zeros; an exception in its place
    where the data does not give one."""
    try:
        estimates = start_estimates(estimation_series(data, files), [(c.order, c.zeros) for c in candidates])
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise UserError(f"{', '.join(str(f.path) for f in files)}: no linear estimate of G ({exc}): does the input "
                        "excite the axis?") from exc
    out = {}
    for c in candidates:
        try:
            out[c] = candidate_plant(c, estimates[(c.order, c.zeros)])
        except UserError as exc:
            out[c] = exc
    return out


def frequency_starts(pool: Workers, job: CandidateJob, starts: dict, files) -> dict[Candidate, object]:
    """Broadband data: each start with its G fitted to the file's BLAs (identification.frequency_fit, the
    friction the linear estimate's) where that fits the ranked records better (−2·ln L at the start): the BLA
    holds every line of every level, the linear estimate's equation error the friction (docs/selection.md); other
    data: ``starts`` as they are."""
    if len(files) != 1 or files[0].kind != "broadband":
        return starts
    from ..broadband.store import read_broadband
    from ..identification.frequency_fit import fit_bla

    bb = read_broadband(files[0].path)
    blas = [lv.bla for lv in bb.levels]
    fitted = {}
    for c, plant in starts.items():
        if not isinstance(plant, Exception):
            try:
                with warnings.catch_warnings():  # a start, not a result: what fails falls back to the linear one
                    warnings.simplefilter("ignore")
                    fitted[c] = fit_bla(plant, blas, bb.plan.rate).plant
            except (UserError, ValueError, np.linalg.LinAlgError):
                continue
    jobs = [replace(job, candidate=c, start=p) for c, p in (*fitted.items(), *((c, starts[c]) for c in fitted))]
    costs = dict(pool.imap(start_neg2loglik, jobs))
    k = len(fitted)
    better = {c: p for i, (c, p) in enumerate(fitted.items()) if costs[i] < costs[k + i]}
    return {c: better.get(c, p) for c, p in starts.items()}


@holds_outputs
def select_files(data_files: Sequence[str | Path | DataFile], validation_file: str | Path | DataFile,
                 output: str | Path | None,
                 options: SelectOptions | None = None, run: RunOptions | None = None,
                 plant_output: str | Path | None = None, result_output: str | Path | None = None) -> Selection:
    """Fit every candidate structure to ``data_files``, rank them on ``validation_file`` and write the outputs.

    Parameters
    ----------
    data_files : list of str, Path or DataFile
        Data of one axis: stepped-sine measurements, or records (open-loop, or closed-loop with
        ``options.closed_loop``), fitted jointly; files or data held in memory.
    validation_file : str, Path or DataFile
        Data of the same axis and signals that no candidate is fitted to.
    output : str, Path or None
        SELECT.h5: every candidate's result and the ranking (docs/selection.md); None writes nothing.
    options : SelectOptions, optional
        Candidates, orders, seed, swarm iterations and box, skip, closed loop.
    run : RunOptions, optional
        ``workers`` (local processes, default one per core; 0: this process) or ``scheduler`` (Dask),
        ``overwrite``, ``progress`` (candidates done, candidates), ``command`` (provenance).
    plant_output, result_output : str or Path, optional
        The chosen structure's plant file (default SELECT.toml) and result (default SELECT-result.h5).

    Returns
    -------
    Selection
        The ranked scores and the outputs written (the plant file and result only when a candidate was fitted).

    Raises
    ------
    UserError
        For unusable inputs (unreadable files, an unknown candidate, an order outside 1..MAX_ORDER, a validation
        file of other signals or another plant) or an existing output without ``run.overwrite``; nothing is
        written then.  A candidate whose fit fails is ranked last, with its reason; the others go on.
    """
    from ..api_checks import check_arguments

    check_arguments(select_files, locals())  # a wrong type: UserError naming it
    options, run = options or SelectOptions(), run or RunOptions()
    paths = [x for x in (*data_files, validation_file, options.closed_loop) if isinstance(x, (str, Path))]
    outputs = {} if output is None else selection_outputs(output, plant_output, result_output)
    claim_outputs(outputs, output_mode(run.overwrite), inputs=paths)
    candidates = _check_options(options)
    if any(isinstance(d, (str, Path)) and isinstance(validation_file, (str, Path)) and Path(d).is_file()
           and Path(validation_file).is_file() and file_sha256(d) == file_sha256(validation_file) for d in data_files):
        raise UserError(f"{validation_file}: is one of the fitted data files (the same contents): validate on data "
                        "no candidate is fitted to")
    controller = options.closed_loop
    if isinstance(controller, (str, Path)):
        from ..model.controller import load_controller

        controller = load_controller(controller)
    data, files = load_selection_data(data_files, options.skip, controller)
    validation, (vfile,) = load_selection_data([validation_file], options.skip, controller)
    check_validation(data, files, validation, vfile)
    names = [data_name(d) for d in data_files]
    provenance = {"data_file": ", ".join(names),
                  "data_sha256": ", ".join(f.sha256 for f in files),  # of the bytes read and fitted
                  "validation_file": data_name(validation_file), "command": run.command, "date": utc_now(),
                  "structure_file": "selection candidate"}
    selection = _select(candidates, data, files, (validation, vfile), provenance, options, run)
    selection = replace(selection, data_files=tuple(names), validation_file=data_name(validation_file))
    if not outputs:
        return selection
    with all_or_none(outputs.values()):  # its three files, or none
        return write_selection(selection, outputs)


def _select(candidates: list[Candidate], data, files, validation_of: tuple, provenance: dict,
            options: SelectOptions, run: RunOptions) -> Selection:
    """The candidates fitted to ``data`` and ranked on the validation data of ``validation_of`` (data, DataFile)
    (select_files' work, nothing written)."""
    screen = options.screen
    validation, vfile = validation_of
    whole_job = CandidateJob(candidates[0], None, data, validation, options,
                             None if run.scheduler is None and run.workers == 0 else 1, provenance,
                             mode="screen" if screen else "full")
    # long records (a drive's log at 1 kHz and beyond): the candidates ranked on RANKED_SAMPLES of them (open-loop
    # records at a reduced rate, then their first share; broadband runs: every level's first realisation), the
    # chosen one polished on the whole of them at the end
    ranked, by_levels = ranked_data(data, files, RANKED_SAMPLES, options.skip)
    ranked_share = 1.0 if ranked is data else fitted_total(ranked) / fitted_total(data)
    job = whole_job if ranked is data else replace(
        whole_job, data=ranked, validation=ranked_data(validation, [vfile], RANKED_SAMPLES, options.skip)[0],
        provenance={**provenance, "ranked_share": ranked_share})
    data = job.data
    with Workers(scheduler=run.scheduler, workers=run.workers) as pool:
        scores, roughness, stopped = _rounds(pool, job, candidates, files, run, stop_if_rough=True)
        whole, share = roughness, 1.0
        # a response chaotic in the parameters over the records (a polish ends in whichever spike of the cost it
        # reaches, and so does every candidate's): the selection again on their first half, quarter, eighth, the
        # first over which the best fits are regular standing for it.  A share's rounds are not stopped early: a
        # start of the records is often regular for the final fits where the screened ones ranked first before
        # them are not (coulomb2_ripple seed 11: on its first quarter a rise above EARLY_ROUGH_RISE once its ripple
        # terms were fitted, 7.4 at the end)
        while roughness > ROUGH_RISE and share / 2 >= SHORTEST_SHARE:
            share /= 2
            short = replace(job, data=first_share(data, share), validation=first_share(job.validation, share),
                            provenance={**job.provenance, "horizon": share})
            again, roughness, _ = _rounds(pool, short, candidates, files, run)
            if not roughness > ROUGH_RISE:
                scores = again
                break
        else:
            roughness, share = whole, 1.0
            if stopped:  # no start is regular either: the whole records' selection, its rounds in full
                scores, roughness, _ = _rounds(pool, job, candidates, files, run)
                whole = roughness
        scores = rank(scores)
        final = _final_fit(pool, whole_job, scores, run) if ranked_share < 1 and share == 1 else None
    return Selection(scores=tuple(scores), data_files=(), validation_file="", kind=data_kind(data), options=options,
                          outputs={},
                          roughness=roughness, horizon=share, roughness_whole=whole,
                          horizon_seconds=share * fitted_seconds(data) if data_kind(data) != "sine" else math.nan,
                          ranked_share=ranked_share, final=final, ranked_levels=by_levels)


# The fitted samples (all records together) the candidates of a selection are ranked on at most (shortening.shortened:
# open-loop records at a reduced rate, then a first share).  The selection's time grows with them — on a drive's
# 1 kHz log of 12 400 samples, 400 s of CPU for the default candidates in its loop — and 4000 is the length of the
# benchmark's records, on which the 20-seed benchmark measures the choices (docs/bench-select.md)
RANKED_SAMPLES = 4000


def _final_fit(pool: Workers, job: CandidateJob, scores: list[CandidateScore], run: RunOptions
               ) -> CandidateScore | None:
    """The candidate ranked first polished on the whole records and validation from its fit on their share (the
    identifier's tolerances, the encoder's quantiser modelled), scored there; None when none was fitted or the
    polish failed (the share's fit then stands)."""
    first = scores[0] if scores else None
    if first is None or first.status != "fitted" or first.result is None:
        return None
    again = fit_all(pool, replace(job, mode="refit"), {first.candidate: first.result.plant}, run, [])
    return again[0] if again and again[0].status == "fitted" else None


# The shortest share of the records a selection on chaotic records is made again on (docs/selection.md)
SHORTEST_SHARE = 1 / 8


# The rise that stops a selection's rounds once its ripple terms are fitted (_rounds): five times ROUGH_RISE, for
# the fits there are screened and the one ranked first provisional — on coulomb1_ripple seed 1 a screened
# `lugre+ripple/1` rose by 358 where the final fits of the same records rise by 1.2; coulomb2_ripple's whole
# records by 280–3 500 at the end of their rounds.
EARLY_ROUGH_RISE = 5 * ROUGH_RISE


def _rounds(pool: Workers, job: CandidateJob, candidates: list[Candidate], files, run: RunOptions,
            stop_if_rough: bool = False) -> tuple[list[CandidateScore], float, bool]:
    """Every candidate fitted and scored on ``job``'s data and validation, in the selection's rounds: the first
    stage, the smaller candidates from larger ones' fits, the load terms, the nested structures, the screened
    candidates that could win polished in full, the first's fit handed to the candidates nested in it; and the
    best fits' roughness (_roughness), and whether the rounds were stopped before their end.  A ripple is what
    makes a response chaotic (a mass driven through its wells), so where one ranks first once the load terms and
    the laws nested in them are fitted the roughness is taken there too, and with ``stop_if_rough`` the rounds
    stop where it is above EARLY_ROUGH_RISE: every later round would fit a lottery (coulomb2_ripple seed 2: 24 of
    the whole records' 40 s came after that point)."""
    data, options = job.data, job.options
    screen = job.mode == "screen"
    checked = {}  # the roughness of the fits checked: the end's check repeats none the early one made
    scores = fit_all(pool, job, frequency_starts(pool, job, linear_starts(candidates, data, files), files), run, [])
    series = estimation_series(data, files)
    speeds = np.concatenate([s.v for s in series])  # a nested law's Coulomb levels are averaged over them
    second_stage, seeded = with_second_stage(options.candidates), replace(job, seeded=True)
    # one round: smaller candidates again from larger ones' fits without their roots beyond the data, and, on
    # the guess that the structure ranked first stays first, the second stage: the load terms on it (fitted
    # again below where it does not stay first)
    leader = rank(scores)[0]
    reduced, loads = fit_groups(pool, [
        (replace(job, polished=True), reduced_starts(scores, candidates, data_bandwidth(series), speeds)),
        (seeded, ranked_term_starts(leader, data) if second_stage else {})], run, len(scores))
    scores = keep_better(scores, reduced)
    springs = spring_starts(scores) if second_stage else {}
    if springs:  # a zero at the origin is a spring's: the structure with the spring instead, from the best fit
        scores = fit_all(pool, seeded, springs, run, scores)
    first = rank(scores)[0]  # the second stage's structure, ranked without its own load terms
    scores = with_new(keep_better(scores, loads), loads)
    if second_stage and first.status == "fitted" and term_candidates(first.candidate):
        if not _same_fit(first, leader):  # the guess was wrong: the load terms on the one ranked first now
            loads = fit_all(pool, seeded, ranked_term_starts(first, data), run, [])
            scores = with_new(keep_better(scores, loads), loads)
        scores = more_friction_terms(pool, seeded, scores, data, run)
        laws = nested_law_starts(term_leader(scores), scores, speeds)
        if laws:  # a load term leads: the structures its own contains, with the term (chosen without it)
            scores = fit_all(pool, seeded, laws, run, scores)
        if stop_if_rough and "ripple" in rank(scores)[0].candidate.terms:
            roughness = _roughness(pool, job, scores, checked)
            if roughness > EARLY_ROUGH_RISE:
                return scores, roughness, True
        # a nested structure (a law it contains, or one order lower: a far pole may stand in for the term)
        # worse than the one with load terms ranked first, or not fitted: from the first one's fit, again
        # from a nested one that then ranks first (each time a smaller structure: it ends)
        again = from_winner(rank(scores)[0], scores, speeds, options.orders)
        while again:
            refitted = fit_all(pool, replace(job, mode="refit", continued=True), again, run, [])
            scores = with_new(keep_better(scores, refitted), refitted)
            top = rank(scores)[0]
            again = from_winner(top, scores, speeds, options.orders) if top.candidate in again else {}
        scores = fewer_friction_terms(pool, seeded, scores, run)
    if screen:
        scores = _refit_contenders(pool, replace(job, mode="refit"), scores, run)
    if second_stage:
        scores = friction_terms_on_final(pool, replace(job, mode="refit"), scores, data, speeds, run)
    before = rank(scores)[0].candidate
    scores = _within_first(pool, replace(job, mode="refit"), scores, speeds, run)
    if screen and rank(scores)[0].candidate != before:
        scores = _refit_contenders(pool, replace(job, mode="refit"), scores, run)
    return scores, _roughness(pool, job, scores, checked), False


def _roughness(pool: Workers, job: CandidateJob, scores: list[CandidateScore], checked: dict | None = None
               ) -> float:
    """The larger select.response_roughness of the fits ranked first and of the lowest BIC among those with every
    parameter determined, over their parameters of finite intervals (a step of an unbounded one's standard error
    goes anywhere): a chaotic response shows in the structure that explains the data best, which a flag (a
    validation record that is a lottery too) may rank below one that cannot be chaotic — but a step of a standard
    error as large as the value itself (an undetermined parameter) is far from quadratic in any structure
    (coulomb1_spring seed 1: 1125 at such a fit); NaN where neither has a covariance.  ``checked`` holds the
    fits checked before (their results and values, by the results' ids), and takes the new ones."""
    ranked = rank(scores)
    fitted = [s for s in ranked if s.status == "fitted" and np.isfinite(s.bic) and s.result is not None
              and s.result.covariance is not None]
    if not fitted:
        return math.nan
    # where no fit has every parameter determined (a real axis's log often leaves some undetermined), the first's
    determined = [s for s in fitted if not s.undetermined]
    picks = {s.candidate: s for s in [fitted[0], min(determined, key=lambda s: s.bic, default=fitted[0])]}
    checked = {} if checked is None else checked
    new = [s for s in picks.values() if id(s.result) not in checked]
    threads = threads_per_job(pool, len(new))
    checks = [replace(job, candidate=s.candidate, start=s.result.plant, threads=threads,
                      covariance=finite_covariance(s.result.covariance, s.result.intervals),
                      information=s.information) for s in new]
    for i, value in pool.imap(response_roughness, checks):  # as they finish
        checked[id(new[i].result)] = (new[i].result, value)  # the result held: its id is not given to another
    values = [checked[id(s.result)][1] for s in picks.values()]
    return max((v for v in values if np.isfinite(v)), default=math.nan)


def _same_fit(now: CandidateScore, before: CandidateScore) -> bool:
    """Whether ``now`` is the candidate of ``before`` with a BIC within SAME_FIT of its own."""
    return now.candidate == before.candidate and abs(now.bic - before.bic) <= SAME_FIT


def _refit_contenders(pool: Workers, job: CandidateJob, scores: list[CandidateScore], run: RunOptions
                      ) -> list[CandidateScore]:
    """The screened candidates that could still be chosen (select.could_win) polished again at the identifier's
    tolerances from their screened fits, until the candidate ranked first is one so polished and no screened one
    could beat it.  A candidate whose polish fails keeps its screened fit (marked no longer screened, its
    message saying why)."""
    scores = list(scores)
    while True:
        ranked = rank(scores)  # with the screened fits' own flags
        first = ranked[0]
        todo = {s.candidate: s for s in ranked if could_win(s, first)}
        if not todo:
            return scores
        again = {s.candidate: s for s in fit_all(pool, job, {c: s.result.plant for c, s in todo.items()}, run, [])}
        scores = [_refitted(s, again[s.candidate]) if s.candidate in again else s for s in scores]


def _within_first(pool: Workers, job: CandidateJob, scores: list[CandidateScore], speeds: np.ndarray,
                  run: RunOptions) -> list[CandidateScore]:
    """The fitted candidates nested in the one ranked first (starts.within_first) polished again from its fit
    reduced to them, where that start fits the data better than their own fit did (a smaller model that fits
    worse than a larger one containing it has missed its optimum: stribeck2 seed 10, whose own structure's fit
    ended 21 above the one from the truth's values, ranked lugre/2 first) and could rank above the first (its BIC
    at the start within SCREEN_MARGIN of the first's); again from a nested one that then ranks first (each time
    a smaller structure: it ends)."""
    while True:
        first = rank(scores)[0]
        starts = within_first(first, scores, speeds)
        jobs = [replace(job, candidate=c, start=s) for c, s in starts.items()]
        costs = dict(pool.imap(start_neg2loglik, jobs))
        own = {s.candidate: s for s in scores}
        todo = {}
        for i, j in enumerate(jobs):
            fit = own[j.candidate]
            if costs[i] < fit.neg2loglik and costs[i] + fit.bic - fit.neg2loglik < first.bic + SCREEN_MARGIN:
                todo[j.candidate] = j.start
        if not todo:
            return scores
        scores = keep_better(scores, fit_all(pool, job, todo, run, []))
        if rank(scores)[0].candidate == first.candidate:
            return scores


def _refitted(screened: CandidateScore, again: CandidateScore) -> CandidateScore:
    """A candidate's score after its full polish: the new scores, with the screening's stages, time and start
    structure before the polish's; its screened score (no longer marked screened) when the polish failed."""
    if again.status != "fitted":
        return replace(screened, screened=False, message=f"full polish failed ({again.message}): screened fit kept")
    old, new = screened.result, again.result
    stages = (*(replace(st, name="screening polish") if st.name == "polish" else st for st in old.stages),
              *(st for st in new.stages if st.name != "start"))
    result = replace(new, structure=old.structure, stages=stages, seconds=old.seconds + new.seconds,
                     evaluations=old.evaluations + new.evaluations, history=old.history)
    message = "; ".join(m for m in (screened.message, again.message) if m)
    return replace(again, result=result, seconds=screened.seconds + again.seconds, message=message)
