"""One identification from files to a result file (`servofmu identify DATA -o RESULT.h5`): the choices between
open- and closed-loop data, the method's default and the combinations of methods and inputs, made once here for
the command line and for a fleet's workers (identification.fleet)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import UserError
from ..fileio import claim_output, output_mode
from ..runtime import WORK_LIMIT_HOURS, RunOptions, utc_now
from .identifier import PSOANNIdentifier, swarm_options
from .inputs import load_identification_inputs
from .results import Result, result_from_estimator, write_result

__all__ = ["IdentifyOptions", "default_method", "identify_to_file"]


def default_method(ann_file) -> str:
    """The method when none is given: the paper's hybrid pso-ann with a network, the swarm alone (pso) without."""
    return "pso-ann" if ann_file is not None else "pso"


@dataclass(frozen=True)
class IdentifyOptions:
    """What an identification from files computes.

    ``method``: one of identification.methods.METHODS (None: :func:`default_method`); ``seed``, ``polish`` as for
    :class:`servofmu.PSOANNIdentifier`; ``iterations``: swarm iterations (None: the paper's 50); ``skip``: seconds
    left out at the start of every record; ``closed_loop``: the controller file of closed-loop records (the
    candidates are then simulated in the loop from the recorded reference; the swarm alone searches);
    ``work_limit``: the hours the search may be estimated at (servofmu.runtime.check_work)."""

    method: str | None = None
    seed: int = 0
    polish: bool = True
    iterations: int | None = None
    skip: float = 0.0
    closed_loop: object = None  # a controller file, or a ControllerSpec
    work_limit: float = WORK_LIMIT_HOURS

    def method_for(self, ann_file) -> str:
        """The method of a run with (or without) the network ``ann_file``."""
        return self.method or default_method(ann_file)


def _is_broadband(path) -> bool:
    """Whether ``path`` is a data file (or a DataFile) of kind broadband (other files, and unreadable ones, are left
    to the readers that name what is wrong with them)."""
    from ..measurement.datafile import as_data_file

    try:
        return as_data_file(path).kind == "broadband"
    except UserError:
        return False


def identify_to_file(data_file, structure_file, output, ann_file=None, options: IdentifyOptions | None = None,
                     run: RunOptions | None = None, threads: int | None = None) -> Result:
    """Identify the plant of one data file and write its result file.

    Parameters
    ----------
    data_file : str, Path or DataFile
        Stepped-sine data (`servofmu measure`), records (`servofmu import`, `servofmu cosim`) or broadband data
        (`servofmu measure --excitation`: identification.broadband_identify); or such data held in memory.
    structure_file : str, Path or Plant
        The structure: a plant file, the name of an example plant or a Plant.
    output : str, Path or None
        The result file (RESULT.h5) to write; None writes nothing.
    ann_file : str, Path or AnnModel, optional
        The trained network (`servofmu train`), for the methods that need one.
    options : IdentifyOptions, optional
        Method, seed, polish, swarm iterations, skip, closed loop.
    run : RunOptions, optional
        ``overwrite`` an existing ``output``; ``command`` recorded as provenance; ``progress`` called with (swarm
        iterations done, iterations).
    threads : int, optional
        Threads of the batch simulator (default: all cores); the result does not depend on it.

    Returns
    -------
    Result
        The result written, its provenance stamped (inputs, their SHA-256, command, date, settings).

    Raises
    ------
    UserError
        For an existing ``output`` (without ``run.overwrite``) or ``output`` one of the inputs, unusable inputs, a
        method that needs a network without one, or a closed-loop identification with another method than pso.
    """
    options, run = options or IdentifyOptions(), run or RunOptions()
    method = options.method_for(ann_file)
    if output is not None:
        claim_output(output, output_mode(run.overwrite), inputs=[x for x in (data_file, structure_file, ann_file,
                                                                            options.closed_loop) if _is_path(x)])
    if _is_broadband(data_file):
        from .broadband_identify import identify_broadband

        return identify_broadband(data_file, structure_file, output, options, run, method, threads, ann_file)
    if options.closed_loop is not None:
        from .closed_loop import load_closed_loop_inputs

        if method != "pso" or ann_file is not None:
            raise UserError("a closed-loop identification searches with the swarm alone (--method pso, no --ann)")
        structure, data, provenance = load_closed_loop_inputs(data_file, structure_file, options.closed_loop,
                                                              command=run.command, skip=options.skip)
        ann = None
    else:
        structure, data, ann, provenance = load_identification_inputs(data_file, structure_file, ann_file, method,
                                                                      command=run.command, skip=options.skip)
    est = PSOANNIdentifier(structure, ann=ann, method=method, seed=options.seed, polish=options.polish,
                           pso=swarm_options(options.iterations), progress=run.progress, threads=threads)
    est.work_limit = options.work_limit
    est.fit(data)
    provenance["date"] = utc_now()
    result = result_from_estimator(est, method, provenance)
    if output is not None:
        write_result(output, result, overwrite=True)  # claimed above
    return result


def _is_path(x) -> bool:
    """Whether an input is named by a path (a file that an output must not be), not an object in memory."""
    return isinstance(x, (str, Path))
