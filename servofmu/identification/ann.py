"""The identifier's feed-forward network: measured features → plant parameters.

One hidden layer (the paper's 20 neurons by default, tanh or sigmoid), linear output, trained
by backpropagation on normalised inputs and outputs with early stopping on a validation
split.  Training uses torch; the trained network is a frozen dataclass of numpy arrays whose
``predict`` needs no torch, and it is stored as arrays in HDF5 (no pickle) together with the
*feature layout* it was trained on, so that data measured with another plan is refused.

ANN.h5 layout (root attributes format = "servofmu-ann", schema_version = 1):
    attrs   format, schema_version, activation, normalisation, optimizer, seed, best_epoch
    w1 (hidden, inputs)  b1 (hidden,)  w2 (outputs, hidden)  b2 (outputs,)
    x_shift, x_scale (inputs,)   y_shift, y_scale (outputs,)     x_norm = (x − x_shift) / x_scale
    train_loss, validation_loss (epochs,)                        mean squared error, normalised units
    layout/feature_names (inputs,)  layout/parameter_names (outputs,)  layout/plan (any shape)
"""
from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError, check_int, is_real
from ..fileio import check_output_path, check_values, hdf5_attr, read_hdf5, store_array, write_hdf5
from ..runtime import Progress, check_memory, temporary_folder

__all__ = ["Network", "FeatureLayout", "AnnModel", "load_ann", "TrainOptions", "train_network", "save_network",
           "load_network"]

FORMAT = "servofmu-ann"
SCHEMA_VERSION = 1
ACTIVATIONS = ("tanh", "sigmoid")
NORMALISATIONS = ("zscore", "minmax")
OPTIMIZERS = ("adam", "lbfgs", "sgd")
TORCH_CACHE_VARIABLE = "TORCHINDUCTOR_CACHE_DIR"  # where torch puts its compiler caches
# Used where a TrainOptions field is None.  sgd is the paper's plain backpropagation (rate 0.2–0.5).  An
# L-BFGS epoch is 100 iterations, so it needs far fewer epochs and less patience than the
# mini-batch methods, whose validation loss is noisy from epoch to epoch.
DEFAULT_LEARNING_RATE = {"adam": 3e-3, "lbfgs": 1.0, "sgd": 0.2}
DEFAULT_MAX_EPOCHS = {"adam": 3000, "lbfgs": 200, "sgd": 3000}
DEFAULT_PATIENCE = {"adam": 100, "lbfgs": 10, "sgd": 100}
_ARRAYS = ("w1", "b1", "w2", "b2", "x_shift", "x_scale", "y_shift", "y_scale", "train_loss", "validation_loss")


@dataclass(frozen=True)
class TrainOptions:
    """How to train.  An "epoch" is one pass over the training samples (adam, sgd) or one
    L-BFGS step of up to ``lbfgs_iterations`` iterations on the full batch (lbfgs).

    Full-batch L-BFGS is the default: on ~10 000 samples × 24 features → 6 parameters it
    reached a lower validation error than Adam or plain SGD at every time from 5 s to 60 s
    on one core.  "sgd" with learning rate 0.2 is the paper's plain backpropagation.  One
    thread by default: for a network this small a second thread was slower in every
    measurement, and many times slower when the other core was busy.

    ``patience``: stop after this many epochs without a relative improvement of the validation
    loss by ``min_improvement``; the weights of the best epoch are kept.  ``learning_rate``,
    ``max_epochs`` and ``patience`` left at None take the optimizer's default (DEFAULT_*).
    ``threads``: torch intra-op threads during training (restored afterwards); None keeps the
    current setting.  ``time_limit``: stop after the epoch that exceeds this many seconds (the
    result then depends on the machine's speed, so it is off by default).
    """

    activation: str = "tanh"
    normalisation: str = "zscore"
    optimizer: str = "lbfgs"
    learning_rate: float | None = None
    batch_size: int = 64
    max_epochs: int | None = None
    patience: int | None = None
    min_improvement: float = 1e-4
    validation_fraction: float = 0.2
    lbfgs_iterations: int = 100
    threads: int | None = 1
    time_limit: float | None = None

    def __post_init__(self):
        for name, allowed in (("activation", ACTIVATIONS), ("normalisation", NORMALISATIONS),
                              ("optimizer", OPTIMIZERS)):
            if getattr(self, name) not in allowed:
                raise UserError(f"training option {name} must be one of {', '.join(allowed)}, "
                                f"not {getattr(self, name)!r}")
        for name in ("batch_size", "max_epochs", "patience", "lbfgs_iterations"):
            if getattr(self, name) is not None:
                check_int(f"training option {name}", getattr(self, name), 1)
        if self.threads is not None:
            check_int("training option threads", self.threads, 1)
        if self.learning_rate is not None and not (is_real(self.learning_rate) and self.learning_rate > 0):
            raise UserError(f"training option learning_rate must be positive, not {self.learning_rate!r}")
        if not (is_real(self.min_improvement) and 0 <= self.min_improvement < 1):
            raise UserError(f"training option min_improvement must be in [0, 1), not {self.min_improvement!r}")
        if self.time_limit is not None and not (is_real(self.time_limit) and self.time_limit > 0):
            raise UserError(f"training option time_limit must be positive or None, not {self.time_limit!r}")
        if not (is_real(self.validation_fraction) and 0 < self.validation_fraction < 1):
            raise UserError(f"training option validation_fraction must be in (0, 1), "
                            f"not {self.validation_fraction!r}")


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


def describe_plan(plan: np.ndarray) -> str:
    """A one-line summary of a plan array."""
    text = np.array2string(np.asarray(plan), separator=", ", threshold=12, edgeitems=2, max_line_width=10**6,
                           formatter={"float_kind": lambda x: f"{x:.6g}"}).replace("\n", "")
    return f"{'×'.join(map(str, np.shape(plan)))} {text}"


def _names(names) -> str:
    return ", ".join(names[:6]) + (f", ... ({len(names)} in all)" if len(names) > 6 else "")


# ---------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------
def train_network(X, Y, hidden: int = 20, seed: int = 0, options: TrainOptions = TrainOptions(),
                  progress: Progress | None = None) -> Network:
    """Train a network mapping X (n, inputs) to Y (n, outputs); deterministic for a given seed.

    The seed fixes the train/validation split, the initial weights and the order of the
    mini-batches.
    """
    import torch

    check_int("hidden", hidden, 1)
    check_int("seed", seed, 0)
    X, Y = _check_training_data(X, Y)
    n = X.shape[0]
    weights = hidden * (X.shape[1] + 1) + Y.shape[1] * (hidden + 1)
    # weights, gradients and the optimizer's history (L-BFGS keeps 2 x 50 vectors), and the hidden layer's
    # activations and their gradients for every sample
    check_memory(f"a network of {hidden} hidden neurons", 8 * (weights * 108 + 4 * n * hidden),
                 "use fewer hidden neurons")
    n_val = max(1, int(round(options.validation_fraction * n)))
    if n - n_val < 1:
        raise UserError(f"training data: {n} samples are too few for a training and a validation set")
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    train, val = order[n_val:], order[:n_val]

    x_shift, x_scale = _normalisation(X[train], options.normalisation)
    y_shift, y_scale = _normalisation(Y[train], options.normalisation)
    xt = torch.from_numpy((X - x_shift) / x_scale)
    yt = torch.from_numpy((Y - y_shift) / y_scale)
    x_train, y_train, x_val, y_val = xt[train], yt[train], xt[val], yt[val]

    threads_before = torch.get_num_threads()
    if options.threads is not None:
        torch.set_num_threads(options.threads)
    try:
        with _torch_caches():
            result = _fit(x_train, y_train, x_val, y_val, hidden, seed, rng, options, progress)
    finally:
        torch.set_num_threads(threads_before)
    (w1, b1, w2, b2), train_loss, val_loss, best_epoch = result
    return Network(w1=w1, b1=b1, w2=w2, b2=b2, x_shift=x_shift, x_scale=x_scale, y_shift=y_shift,
                   y_scale=y_scale, activation=options.activation, normalisation=options.normalisation,
                   train_loss=train_loss, validation_loss=val_loss, best_epoch=best_epoch,
                   optimizer=options.optimizer, seed=int(seed))


@contextlib.contextmanager
def _torch_caches():
    """torch's compiler cache folder (made by the optimizers' first step, empty for this training) inside a
    temporary folder of servofmu's, removed with it, unless the user chose where it goes."""
    if os.environ.get(TORCH_CACHE_VARIABLE):
        yield
        return
    with temporary_folder("torch") as folder:
        os.environ[TORCH_CACHE_VARIABLE] = str(folder)
        try:
            yield
        finally:
            os.environ.pop(TORCH_CACHE_VARIABLE, None)


def _initial_weights(inputs: int, hidden: int, outputs: int, seed: int, activation: str) -> list:
    """Xavier-initialised weights and zero biases (w1, b1, w2, b2), float64, requiring gradients.

    float64: no slower than float32 for networks this small (measured), and it is predict's arithmetic.
    Plain tensors drawn from a local generator: torch.nn.Linear would draw from (and advance) torch's global
    generator."""
    import torch

    generator = torch.Generator().manual_seed(int(seed))
    w1 = torch.empty(hidden, inputs, dtype=torch.float64)
    w2 = torch.empty(outputs, hidden, dtype=torch.float64)
    torch.nn.init.xavier_uniform_(w1, gain=torch.nn.init.calculate_gain(activation), generator=generator)
    torch.nn.init.xavier_uniform_(w2, gain=1.0, generator=generator)
    b1 = torch.zeros(hidden, dtype=torch.float64)
    b2 = torch.zeros(outputs, dtype=torch.float64)
    return [t.requires_grad_() for t in (w1, b1, w2, b2)]


def _optimizer(params: list, options: TrainOptions):
    import torch

    lr = options.learning_rate if options.learning_rate is not None else DEFAULT_LEARNING_RATE[options.optimizer]
    if options.optimizer == "lbfgs":
        return torch.optim.LBFGS(params, lr=lr, max_iter=options.lbfgs_iterations, history_size=50,
                                 line_search_fn="strong_wolfe")
    if options.optimizer == "adam":
        return torch.optim.Adam(params, lr=lr)
    return torch.optim.SGD(params, lr=lr)


def _train_epoch(opt, mse, x_train, y_train, rng, options: TrainOptions) -> float:
    """One epoch (one L-BFGS step on the full batch, or one pass of mini-batches); returns its training loss."""
    import torch

    if options.optimizer == "lbfgs":
        def closure():
            opt.zero_grad()
            loss = mse(x_train, y_train)
            loss.backward()
            return loss

        opt.step(closure)
        with torch.no_grad():
            return float(mse(x_train, y_train))
    n_train = x_train.shape[0]
    perm = torch.from_numpy(rng.permutation(n_train))
    total = 0.0
    for start in range(0, n_train, options.batch_size):
        idx = perm[start:start + options.batch_size]
        opt.zero_grad()
        loss = mse(x_train[idx], y_train[idx])
        loss.backward()
        opt.step()
        total += loss.item() * idx.numel()
    return total / n_train  # mean over the epoch's batches: no extra pass over the data


def _fit(x_train, y_train, x_val, y_val, hidden, seed, rng, options: TrainOptions, progress):
    """Epochs until the validation loss stops improving (early stopping); the best epoch's weights."""
    import torch

    params = _initial_weights(x_train.shape[1], hidden, y_train.shape[1], seed, options.activation)
    w1, b1, w2, b2 = params
    act = torch.tanh if options.activation == "tanh" else torch.sigmoid

    def mse(x, y):
        return torch.mean((act(x @ w1.T + b1) @ w2.T + b2 - y) ** 2)

    opt = _optimizer(params, options)
    max_epochs = options.max_epochs or DEFAULT_MAX_EPOCHS[options.optimizer]
    patience = options.patience or DEFAULT_PATIENCE[options.optimizer]
    train_loss, val_loss = [], []
    best, best_state, best_epoch, waited = np.inf, None, 0, 0
    deadline = None if options.time_limit is None else time.monotonic() + options.time_limit
    for epoch in range(max_epochs):
        train_loss.append(_train_epoch(opt, mse, x_train, y_train, rng, options))
        with torch.no_grad():
            v = float(mse(x_val, y_val))
        if not np.isfinite(v):
            raise UserError(f"training diverged at epoch {epoch + 1} (validation loss {v}); "
                            f"lower the learning rate")
        val_loss.append(v)
        if progress is not None:
            progress(epoch + 1, max_epochs)
        if v < best * (1 - options.min_improvement):
            best, best_epoch, waited = v, epoch, 0
            best_state = [p.detach().clone() for p in params]
        else:
            waited += 1
            if waited >= patience:
                break
        if deadline is not None and time.monotonic() > deadline:
            break
    weights = tuple(p.numpy() for p in best_state)
    return weights, np.array(train_loss), np.array(val_loss), best_epoch


def _check_training_data(X, Y) -> tuple[np.ndarray, np.ndarray]:
    try:
        X = np.asarray(X, dtype=float)
        Y = np.asarray(Y, dtype=float)
    except (TypeError, ValueError) as exc:
        raise UserError("training data: features and parameters must be numeric arrays") from exc
    if X.ndim != 2 or Y.ndim != 2 or X.shape[0] != Y.shape[0] or X.shape[0] == 0:
        raise UserError(f"training data: expected features (n, inputs) and parameters (n, outputs) with the "
                        f"same n > 0, got shapes {X.shape} and {Y.shape}")
    for name, A in (("features", X), ("parameters", Y)):
        bad = np.flatnonzero(~np.all(np.isfinite(A), axis=1))
        if bad.size:
            raise UserError(f"training data: {name} of sample {bad[0]} contain NaN or infinite values "
                            f"({bad.size} samples in all)")
    return X, Y


def _normalisation(A: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(shift, scale) per column; z-score or min-max onto [−1, 1]."""
    if method == "zscore":
        shift, scale = A.mean(axis=0), A.std(axis=0)
    else:
        lo, hi = A.min(axis=0), A.max(axis=0)
        shift, scale = (hi + lo) / 2, (hi - lo) / 2
    # A constant column carries no information; scale 1 keeps it finite instead of dividing by zero.
    scale = np.where(scale > 1e-12 * np.maximum(1.0, np.abs(shift)), scale, 1.0)
    return shift, scale


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
