"""Training the identifier's network (servofmu.identification.ann.Network) with torch: backpropagation on
normalised inputs and outputs with early stopping on a validation split.  torch is imported by this module's
functions only, so that identifying with a trained network never loads it."""
from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass

import numpy as np

from ..errors import UserError, check_int, is_real
from ..runtime import Progress, check_memory, temporary_folder
from .ann import ACTIVATIONS, NORMALISATIONS, Network

__all__ = ["TrainOptions", "train_network", "OPTIMIZERS"]

OPTIMIZERS = ("adam", "lbfgs", "sgd")
TORCH_CACHE_VARIABLE = "TORCHINDUCTOR_CACHE_DIR"  # where torch puts its compiler caches
# Used where a TrainOptions field is None.  sgd is the paper's plain backpropagation (rate 0.2–0.5).  An
# L-BFGS epoch is 100 iterations, so it needs far fewer epochs and less patience than the
# mini-batch methods, whose validation loss is noisy from epoch to epoch.
DEFAULT_LEARNING_RATE = {"adam": 3e-3, "lbfgs": 1.0, "sgd": 0.2}
DEFAULT_MAX_EPOCHS = {"adam": 3000, "lbfgs": 200, "sgd": 3000}
DEFAULT_PATIENCE = {"adam": 100, "lbfgs": 10, "sgd": 100}

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


# ---------------------------------------------------------------------------
# Training
# ---------------------------------------------------------------------------
def _import_torch():
    """torch, imported; a loader that cannot map its libraries for lack of memory (a limit on the address space)
    is a MemoryError, as an allocation that fails later is, not an ImportError."""
    try:
        import torch
    except ImportError as exc:
        if "failed to map segment" in str(exc) or "cannot allocate memory" in str(exc).lower():
            raise MemoryError(str(exc)) from exc
        raise
    return torch


def train_network(X, Y, hidden: int = 20, seed: int = 0, options: TrainOptions = TrainOptions(),
                  progress: Progress | None = None) -> Network:
    """Train a network mapping X (n, inputs) to Y (n, outputs); deterministic for a given seed.

    The seed fixes the train/validation split, the initial weights and the order of the
    mini-batches.
    """
    torch = _import_torch()
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
