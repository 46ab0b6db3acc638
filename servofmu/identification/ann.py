"""The identifier's feed-forward network: measured features → plant parameters.

One hidden layer (the paper's 20 neurons by default, tanh or sigmoid), linear output, trained
by backpropagation on normalised inputs and outputs with early stopping on a validation
split (servofmu.identification.ann_training, with torch); the trained network is a frozen
dataclass of numpy arrays whose ``predict`` needs no torch, and it is stored as arrays in HDF5
(no pickle) together with the *feature layout* it was trained on, so that data measured with
another plan is refused.

ANN.h5 layout (root attributes format = "servofmu-ann", schema_version = 1):
    attrs   format, schema_version, activation, normalisation, optimizer, seed, best_epoch
    w1 (hidden, inputs)  b1 (hidden,)  w2 (outputs, hidden)  b2 (outputs,)
    x_shift, x_scale (inputs,)   y_shift, y_scale (outputs,)     x_norm = (x − x_shift) / x_scale
    train_loss, validation_loss (epochs,)                        mean squared error, normalised units
    layout/feature_names (inputs,)  layout/parameter_names (outputs,)  layout/plan (any shape)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError
from ..fileio import check_output_path, check_values, hdf5_attr, read_hdf5, store_array, write_hdf5

__all__ = ["Network", "FeatureLayout", "AnnModel", "load_ann", "save_network", "load_network", "ACTIVATIONS",
           "NORMALISATIONS"]

FORMAT = "servofmu-ann"
SCHEMA_VERSION = 1
ACTIVATIONS = ("tanh", "sigmoid")
NORMALISATIONS = ("zscore", "minmax")
_ARRAYS = ("w1", "b1", "w2", "b2", "x_shift", "x_scale", "y_shift", "y_scale", "train_loss", "validation_loss")


@dataclass(frozen=True, eq=False)
class Network:
    """A trained network; all arrays are read-only float64.

    w1 (hidden, inputs), b1 (hidden,), w2 (outputs, hidden), b2 (outputs,): weights on
    normalised data; x_shift, x_scale (inputs,) and y_shift, y_scale (outputs,): the
    normalisation, x_norm = (x − x_shift)/x_scale, y = y_shift + y_scale·y_norm.
    train_loss, validation_loss (epochs,): mean squared error per epoch in normalised units;
    best_epoch indexes the epoch whose weights these are.
    """

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    x_shift: np.ndarray
    x_scale: np.ndarray
    y_shift: np.ndarray
    y_scale: np.ndarray
    activation: str
    normalisation: str
    train_loss: np.ndarray
    validation_loss: np.ndarray
    best_epoch: int

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        loss = self.validation_loss[self.best_epoch] if self.validation_loss.size > self.best_epoch else float("nan")
        return Shown(type(self).__name__, f"{self.w1.shape[1]} inputs → {self.w1.shape[0]} hidden ({self.activation})"
                     f" → {self.w2.shape[0]} outputs", (figure("best epoch", int(self.best_epoch)),
                                                        figure("epochs", int(self.train_loss.size)),
                                                        figure("validation loss", float(loss), "", ".3g")))
    optimizer: str = ""
    seed: int = 0

    def __post_init__(self):
        for name in _ARRAYS:
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)  # frozen: set once here, read-only afterwards

    @property
    def inputs(self) -> int:
        """Number of input features."""
        return self.w1.shape[1]

    @property
    def hidden(self) -> int:
        """Number of hidden neurons."""
        return self.w1.shape[0]

    @property
    def outputs(self) -> int:
        """Number of outputs (identified parameters)."""
        return self.w2.shape[0]

    @property
    def validation_rmse(self) -> float:
        """Root mean squared validation error of the kept weights, in normalised (≈ standard-deviation) units."""
        return float(np.sqrt(self.validation_loss[self.best_epoch]))

    def predict(self, X) -> np.ndarray:
        """Parameters (n, outputs) for features X (n, inputs); a single row (inputs,) gives (outputs,)."""
        X = np.asarray(X, dtype=float)
        single = X.ndim == 1
        X = np.atleast_2d(X)
        if X.ndim != 2 or X.shape[1] != self.inputs:
            raise UserError(f"the network expects {self.inputs} features per sample, the data has shape {X.shape}")
        h = _activate((X - self.x_shift) / self.x_scale @ self.w1.T + self.b1, self.activation)
        Y = self.y_shift + self.y_scale * (h @ self.w2.T + self.b2)
        return Y[0] if single else Y


@dataclass(frozen=True, eq=False)
class FeatureLayout:
    """What a network's inputs and outputs mean.

    feature_names (inputs,): one name per input column; parameter_names (outputs,): one per
    output column (a plant's parameter_names()); plan: any float array describing the
    experiment the features come from (e.g. rows of amplitude and frequency).
    """

    feature_names: tuple[str, ...]
    parameter_names: tuple[str, ...]
    plan: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "feature_names", tuple(str(n) for n in self.feature_names))
        object.__setattr__(self, "parameter_names", tuple(str(n) for n in self.parameter_names))
        plan = np.array(self.plan, dtype=float)
        plan.setflags(write=False)
        object.__setattr__(self, "plan", plan)

    def check_compatible(self, data: "FeatureLayout", source: str | Path) -> None:
        """Refuse data whose layout differs from the one the network ``source`` was trained on."""
        if self.plan.shape != data.plan.shape or not np.allclose(self.plan, data.plan, rtol=1e-9, atol=0.0):
            raise UserError(f"{source} was trained on plan {describe_plan(self.plan)}, "
                            f"data has plan {describe_plan(data.plan)}")
        if self.feature_names != data.feature_names:
            raise UserError(f"{source} was trained on features {_names(self.feature_names)}, "
                            f"data has features {_names(data.feature_names)}")
        if self.parameter_names != data.parameter_names:
            raise UserError(f"{source} estimates parameters {_names(self.parameter_names)}, "
                            f"the structure has {_names(data.parameter_names)}")


@dataclass(frozen=True)
class AnnModel:
    """A trained network with the feature layout it was trained on and the file it came from."""

    network: Network
    layout: FeatureLayout
    source: str

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        net = self.network._shown()
        return Shown(type(self).__name__, f"{self.source!r}: {len(self.layout.feature_names)} features → "
                     f"{', '.join(self.layout.parameter_names)}", net.figures + (
                         figure("network", net.head), figure("plan", f"{self.layout.plan.shape[-1]} experiments")))


def describe_plan(plan: np.ndarray) -> str:
    """A one-line summary of a plan array."""
    text = np.array2string(np.asarray(plan), separator=", ", threshold=12, edgeitems=2, max_line_width=10**6,
                           formatter={"float_kind": lambda x: f"{x:.6g}"}).replace("\n", "")
    return f"{'×'.join(map(str, np.shape(plan)))} {text}"


def _names(names) -> str:
    return ", ".join(names[:6]) + (f", ... ({len(names)} in all)" if len(names) > 6 else "")


def _activate(z: np.ndarray, activation: str) -> np.ndarray:
    if activation == "tanh":
        return np.tanh(z)
    return 0.5 + 0.5 * np.tanh(0.5 * z)  # the logistic function, overflow-free


# ---------------------------------------------------------------------------
# HDF5
# ---------------------------------------------------------------------------
def save_network(net: Network, path: str | Path, layout: FeatureLayout) -> Path:
    """Write ``net`` and the ``layout`` it was trained on to ``path`` (ANN.h5), atomically."""
    if len(layout.feature_names) != net.inputs or len(layout.parameter_names) != net.outputs:
        raise UserError(f"{path}: the layout names {len(layout.feature_names)} features and "
                        f"{len(layout.parameter_names)} parameters, the network has {net.inputs} inputs and "
                        f"{net.outputs} outputs")
    path = check_output_path(path)

    def write(f):
        f.attrs.update({"format": FORMAT, "schema_version": SCHEMA_VERSION, "activation": net.activation,
                        "normalisation": net.normalisation, "optimizer": net.optimizer, "seed": net.seed,
                        "best_epoch": net.best_epoch})
        for name in _ARRAYS:
            store_array(f, name, getattr(net, name))
        g = f.create_group("layout")
        store_array(g, "feature_names", list(layout.feature_names))
        store_array(g, "parameter_names", list(layout.parameter_names))
        store_array(g, "plan", layout.plan)

    write_hdf5(path, write)
    return path


def load_network(path: str | Path) -> tuple[Network, FeatureLayout]:
    """Read a network file written by ``save_network``; anything else is refused naming the file."""
    import h5py

    path = Path(path)

    def read(f, version):
        def dataset(name):
            if not isinstance(f.get(name), h5py.Dataset):
                raise KeyError(f"missing dataset {name}")
            return f[name]

        arrays = {name: check_values(path, name, dataset(name)[()]).astype(float) for name in _ARRAYS}
        net = Network(**arrays, activation=str(hdf5_attr(f, "activation")),
                      normalisation=str(hdf5_attr(f, "normalisation")), optimizer=str(hdf5_attr(f, "optimizer")),
                      seed=int(hdf5_attr(f, "seed")), best_epoch=int(hdf5_attr(f, "best_epoch")))
        layout = FeatureLayout(feature_names=tuple(dataset("layout/feature_names").asstr()[()]),
                               parameter_names=tuple(dataset("layout/parameter_names").asstr()[()]),
                               plan=check_values(path, "layout/plan", dataset("layout/plan")[()]).astype(float))
        return net, layout

    net, layout = read_hdf5(path, "network file", FORMAT, SCHEMA_VERSION, read)
    _check_loaded(net, layout, path)
    return net, layout


def load_ann(path: str | Path) -> AnnModel:
    """Read a trained network for the identifier.

    Parameters
    ----------
    path : str or Path
        A network file (ANN.h5) written by :func:`servofmu.train_from_file` (``servofmu train``).

    Returns
    -------
    AnnModel
        The network, the feature layout (plan, features, parameters) it was trained on, and its source.

    Raises
    ------
    UserError
        For a missing, foreign, newer or damaged file.
    """
    from ..api_checks import check_arguments

    check_arguments(load_ann, locals())  # a wrong type: UserError naming it
    net, layout = load_network(path)
    return AnnModel(net, layout, str(path))


def _check_loaded(net: Network, layout: FeatureLayout, path: Path) -> None:
    """The arrays of a read file fit together: a damaged file must not predict nonsense."""
    h, i = net.w1.shape if net.w1.ndim == 2 else (-1, -1)
    o = net.w2.shape[0] if net.w2.ndim == 2 else -1
    if min(h, i, o) < 1:
        raise UserError(f"{path}: damaged network file (weights of shapes {net.w1.shape} and {net.w2.shape})")
    for name, shape in {"w1": (h, i), "b1": (h,), "w2": (o, h), "b2": (o,), "x_shift": (i,), "x_scale": (i,),
                        "y_shift": (o,), "y_scale": (o,)}.items():
        check_values(path, name, getattr(net, name), shape)
    if np.any(net.x_scale <= 0) or np.any(net.y_scale <= 0):
        raise UserError(f"{path}: damaged network file (a normalisation scale is not positive)")
    if net.activation not in ACTIVATIONS or net.normalisation not in NORMALISATIONS:
        raise UserError(f"{path}: damaged network file (activation {net.activation!r}, "
                        f"normalisation {net.normalisation!r})")
    if len(layout.feature_names) != i or len(layout.parameter_names) != o:
        raise UserError(f"{path}: damaged network file (layout names {len(layout.feature_names)} features and "
                        f"{len(layout.parameter_names)} parameters for a {i}→{o} network)")
    if not (0 <= net.best_epoch < max(1, net.validation_loss.size)):
        raise UserError(f"{path}: damaged network file (best_epoch {net.best_epoch})")
