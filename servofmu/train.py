"""`servofmu train`: the ANN of the PSO-ANN hybrid, trained on a training set (DS.h5) and saved as ANN.h5."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from .ann import FeatureLayout, Network, save_network, train_network
from .dataset import ann_features, feature_names, load_training_set, to_targets
from .errors import UserError
from .fileio import check_output_path
from .prior import identified_names


def train_from_file(dataset: str | Path, output: str | Path, hidden: int = 20, seed: int = 0,
                    progress: Callable[[int, int, float], None] | None = None) -> tuple[Network, int]:
    """Train on the usable rows of ``dataset`` and write ``output``; returns the network and the rows used."""
    output = check_output_path(output)
    ts = load_training_set(dataset)
    rows = ts.usable()
    if rows.sum() < 10:
        raise UserError(f"{dataset}: only {int(rows.sum())} plants with every experiment at steady state; "
                        "need at least 10 to train (more samples, or a plan whose experiments settle)")
    X = ann_features(ts.H[rows], ts.dc[rows], ts.amplitudes)
    Y = to_targets(ts.structure, ts.parameters[rows])
    net = train_network(X, Y, hidden=hidden, seed=seed, progress=progress)
    layout = FeatureLayout(feature_names=feature_names(ts.amplitudes.size),
                           parameter_names=identified_names(ts.structure), plan=ts.plan)
    save_network(net, output, layout)
    return net, int(rows.sum())
