"""`servofmu train`: the ANN of the PSO-ANN hybrid, trained on a training set (DS.h5) and saved as ANN.h5."""
from __future__ import annotations

from pathlib import Path

from ..errors import UserError
from ..fileio import claim_output, output_mode
from ..runtime import RunOptions
from .ann import FeatureLayout, Network, save_network
from .ann_training import train_network
from .features import ann_features, feature_names, to_targets
from .prior import identified_names
from .training_set import load_training_set

__all__ = ["train_from_file"]


def train_from_file(training_set: str | Path, output: str | Path, hidden: int = 20, seed: int = 0,
                    run: RunOptions | None = None) -> tuple[Network, int]:
    """Train the ANN on a training set and write it.

    Parameters
    ----------
    training_set : str or Path
        A training set (DS.h5) made by :func:`servofmu.make_training_set` (``servofmu dataset``).
    output : str or Path
        The network file (ANN.h5) to write.
    hidden : int
        Hidden neurons (the paper's 20 by default).
    seed : int
        Seed of the validation split and the initial weights.
    run : RunOptions, optional
        ``overwrite`` an existing ``output``; ``progress`` called with (epoch, max_epochs).

    Returns
    -------
    tuple of (Network, int)
        The trained network and the number of plants it was trained on (those with every experiment settled).

    Raises
    ------
    UserError
        For a file that is not a training set, or one with fewer than 10 usable plants; an existing ``output``
        (without ``run.overwrite``), or ``output`` the training set itself.
    """
    from ..api_checks import check_arguments

    check_arguments(train_from_file, locals())  # a wrong type: UserError naming it
    run = run or RunOptions()
    output = claim_output(output, output_mode(run.overwrite), inputs=(training_set,))
    ts = load_training_set(training_set)
    rows = ts.usable()
    if rows.sum() < 10:
        raise UserError(f"{training_set}: only {int(rows.sum())} plants with every experiment at steady state; "
                        "need at least 10 to train (more samples, or a plan whose experiments settle)")
    X = ann_features(ts.H[rows], ts.dc[rows], ts.amplitudes)
    Y = to_targets(ts.structure, ts.parameters[rows])
    net = train_network(X, Y, hidden=hidden, seed=seed, progress=run.progress)
    layout = FeatureLayout(feature_names=feature_names(ts.amplitudes.size),
                           parameter_names=identified_names(ts.structure), plan=ts.plan)
    save_network(net, output, layout)
    return net, int(rows.sum())
