"""Many data files identified in one call — a fleet of axes (`servofmu identify A.h5 B.h5 ... --output-dir DIR`).

Every data file is identified on its own, exactly as `servofmu identify DATA -o RESULT.h5` identifies it (nothing
is shared between files, and a fit's result does not depend on the threads it runs on, so the results are those of
one-file runs), in local worker processes or on a Dask cluster (servofmu.simulation.parallel).  Its result goes to
DIR/<data file's name>-result.h5 as soon as it is done, written atomically.  With ``resume``, a result already in
DIR that was identified from the same data (SHA-256) with the same structure, network, method, seed, polish and
swarm iterations is kept, so that a run interrupted and started again only identifies the files it had not finished.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import UserError
from ..fileio import OutputExists, claim_output, claim_outputs, file_sha256, holds_outputs
from ..model.plant import load_plant
from ..runtime import RunOptions
from ..simulation.parallel import Workers
from .identifier import swarm_options
from .pso import PsoOptions
from .results import read_result
from .run import IdentifyOptions, identify_to_file

__all__ = ["FileJob", "FileOutcome", "identify_files", "result_path", "outcomes_table", "outcomes_json"]


@dataclass(frozen=True)
class FileJob:
    """One data file to identify and where its result goes (what a worker is sent)."""

    data_file: str
    result_file: str
    structure_file: str
    ann_file: str | None
    options: IdentifyOptions  # its method and iterations resolved
    threads: int | None
    command: str


@dataclass(frozen=True)
class FileOutcome:
    """How one data file fared: ``status`` is "identified", "kept" (a finished result that ``resume`` kept) or
    "failed" (``message`` says why, in one line); ``names``/``theta``, ``fitness``, ``seconds`` and ``evaluations``
    as in its result (empty and NaN when it failed)."""

    data_file: str
    result_file: str
    status: str
    message: str = ""
    names: tuple[str, ...] = ()
    theta: tuple[float, ...] = ()
    fitness: float = float("nan")
    seconds: float = float("nan")
    evaluations: int = 0


def result_path(output_dir: Path, data_file: str | Path) -> Path:
    """Where the result of ``data_file`` goes: DIR/<its name without .h5>-result.h5."""
    return Path(output_dir) / f"{Path(data_file).stem}-result.h5"


@holds_outputs  # a long run: its outputs are its own until it ends (fileio.output_claims)
def identify_files(data_files, structure_file, output_dir, ann_file=None, options: IdentifyOptions | None = None,
                   run: RunOptions | None = None) -> list[FileOutcome]:
    """Identify every data file and write one result per file into ``output_dir``.

    Parameters
    ----------
    data_files : list of str or Path
        Stepped-sine data files (`servofmu measure`) or records (`servofmu import`), all of the structure's plant.
    structure_file, ann_file : str or Path
        As for `servofmu identify`: the structure, and the network (for the methods that need one).
    output_dir : str or Path
        An existing folder; the result of A.h5 is written to output_dir/A-result.h5.
    options : IdentifyOptions, optional
        Method, seed, polish, swarm iterations, skip: as for one file (:func:`identify_to_file`); closed-loop
        records are identified one file at a time, not here.
    run : RunOptions, optional
        ``resume``: keep the results already in ``output_dir`` that were identified from the same data with the
        same settings, identify the others; ``overwrite``: replace them; without either, a result already there is
        refused.  ``scheduler`` (a Dask scheduler address, tcp://HOST:PORT; default local worker processes),
        ``workers`` (default one per core; 0: this process, one file after the other), ``command`` (for the
        results' provenance), ``progress`` (called with (files done, files)).

    Returns
    -------
    list of FileOutcome
        One per data file, in the order given.  A file that cannot be identified (unreadable, another plan than
        the network's, ...) fails on its own; the others go on.

    Raises
    ------
    UserError
        For a missing folder, two data files with the same name, an unusable structure or network, closed-loop
        options, or (without ``run.resume`` or ``run.overwrite``) a result already in the folder, and with
        ``run.resume`` for a result there of other data or settings; nothing has been identified then.
    """
    options, run = options or IdentifyOptions(), run or RunOptions()
    if options.closed_loop is not None:
        raise UserError("closed-loop records are identified one file at a time")
    output_dir = Path(output_dir)
    if not output_dir.is_dir():
        raise UserError(f"{output_dir}: no such folder (the output folder must exist)")
    claim_output(result_path(output_dir, "probe"), "replace")  # writable, before any work
    data_files = [str(d) for d in data_files]
    if not data_files:
        raise UserError("no data files to identify")
    results = [str(result_path(output_dir, d)) for d in data_files]
    seen: dict[str, str] = {}
    for d, r in zip(data_files, results):
        if r in seen:
            raise UserError(f"{d} and {seen[r]} would both be identified into {r}: give data files distinct names")
        seen[r] = d
    # no result over an input (a data file named like another's result): replaced or continued later, one by one
    claim_outputs({f"the result of {d}": r for d, r in zip(data_files, results)}, "replace",
                  inputs=(*data_files, structure_file, ann_file))
    structure = load_plant(structure_file)  # a bad structure or network fails once, here, not in every worker
    if ann_file is not None:
        from .ann import load_ann

        load_ann(ann_file)
    # a bad number of iterations is refused before any work
    options = replace(options, method=options.method_for(ann_file),
                      iterations=swarm_options(options.iterations).iterations)
    in_process = run.scheduler is None and run.workers == 0
    jobs = [FileJob(data_file=d, result_file=r, structure_file=str(structure_file),
                    ann_file=None if ann_file is None else str(ann_file), options=options,
                    threads=None if in_process else 1, command=run.command)
            for d, r in zip(data_files, results)]
    outcomes: list[FileOutcome | None] = [None] * len(jobs)
    for i, job in enumerate(jobs):
        if not Path(job.result_file).exists():
            continue
        if run.resume:
            outcomes[i] = _kept(job, structure.to_toml())
        elif not run.overwrite:
            raise OutputExists(Path(job.result_file), "resume")
    todo = [i for i, o in enumerate(outcomes) if o is None]
    done = len(jobs) - len(todo)
    run.report(done, len(jobs))
    with Workers(scheduler=run.scheduler, workers=run.workers) as pool:
        for k, outcome in pool.imap(identify_file, [jobs[i] for i in todo]):
            outcomes[todo[k]] = outcome
            done += 1
            run.report(done, len(jobs))
    return outcomes


def identify_file(_, job: FileJob) -> FileOutcome:
    """Worker task: identify one data file and write its result; a user error becomes a failed outcome."""
    try:  # the rule was applied to every result before any work
        result = identify_to_file(job.data_file, job.structure_file, job.result_file, job.ann_file, job.options,
                                  RunOptions(overwrite=True, command=job.command), threads=job.threads)
    except (UserError, OSError) as exc:
        return FileOutcome(job.data_file, job.result_file, "failed", message=_one_line(exc))
    return _outcome(job, result, "identified")


def _kept(job: FileJob, structure_toml: str) -> FileOutcome:
    """The outcome of a result that ``resume`` keeps, after checking that it is this job's."""
    result = read_result(job.result_file)
    prov = result.provenance
    try:
        sha = file_sha256(job.data_file)
    except OSError as exc:
        raise UserError(f"{job.data_file}: cannot read ({exc.strerror or exc})") from exc
    ann, o = job.ann_file or "", job.options
    same = (prov.get("data_sha256") == sha and result.method == o.method and prov.get("seed") == o.seed
            and prov.get("polish") == o.polish and prov.get("ann_file", "") == ann
            and prov.get("iterations", PsoOptions().iterations) == o.iterations  # results from before the option
            and prov.get("skip", 0.0) == o.skip
            and result.structure.to_toml() == structure_toml)
    if not same:
        raise UserError(f"{job.result_file}: was identified from other data or with other settings than this run's "
                        "(remove it to identify it again)")
    return _outcome(job, result, "kept")


def _outcome(job: FileJob, result, status: str) -> FileOutcome:
    return FileOutcome(job.data_file, job.result_file, status, names=tuple(result.names),
                       theta=tuple(float(v) for v in result.theta), fitness=result.fitness, seconds=result.seconds,
                       evaluations=result.evaluations)


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and not isinstance(exc, UserError):
        return f"{exc.filename + ': ' if exc.filename else ''}{exc.strerror or exc}"
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def outcomes_table(outcomes: list[FileOutcome]) -> str:
    """The summary: one row per data file (status, fitness, seconds, the identified parameters), aligned; a failed
    file's row ends with why."""
    names = next((o.names for o in outcomes if o.names), ())
    head = ["data file", "status", "fitness", "seconds", *names]
    rows = [[o.data_file, o.status, f"{o.fitness:.3g}", f"{o.seconds:.2f}", *(f"{v:.10g}" for v in o.theta)]
            if o.status != "failed" else [o.data_file, o.status, "-", "-", o.message] for o in outcomes]
    aligned = [head] + [r for r in rows if len(r) == len(head)]
    widths = [max(len(r[i]) for r in aligned) for i in range(len(head))]
    widths[:4] = [max(w, *(len(r[i]) for r in rows)) for i, w in enumerate(widths[:4])]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths + [0])).rstrip() for r in [head, *rows])


def outcomes_json(outcomes: list[FileOutcome]) -> str:
    """The summary as one JSON array (one object per data file)."""
    return json.dumps([{"data_file": o.data_file, "result_file": o.result_file, "status": o.status,
                        **({"message": o.message} if o.message else {}),
                        "parameters": dict(zip(o.names, o.theta)), "fitness": o.fitness, "seconds": o.seconds,
                        "evaluations": o.evaluations} for o in outcomes], allow_nan=True)
