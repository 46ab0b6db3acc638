"""The identifier's network: it learns a known smooth map, is deterministic, and its HDF5 file
round-trips exactly and refuses foreign, damaged or mismatched input."""
import h5py
import numpy as np
import pytest

from servofmu.errors import UserError
from servofmu.identification.ann import FeatureLayout, Network, load_network, save_network
from servofmu.identification.ann_training import TrainOptions, train_network
from hdf5edit import edit_hdf5


def known_map(X):
    """A smooth nonlinear map R^3 -> R^2 on very different scales, like features -> parameters."""
    return np.column_stack([10.0 * np.sin(1.5 * X[:, 0]) + 5.0 * X[:, 1] ** 2,
                            0.4 + 0.1 * np.tanh(X[:, 0] * X[:, 2]) + 0.05 * X[:, 1]])


def data(n, seed):
    X = np.random.default_rng(seed).uniform(-1, 1, size=(n, 3)) * [1.0, 2.0, 0.5] + [0.0, 0.0, 100.0]
    return X, known_map(X - [0.0, 0.0, 100.0])


FAST = TrainOptions(max_epochs=12, lbfgs_iterations=50)


def layout(plan=((2.0, 1.0), (2.0, 5.0), (1.0, 1.0))):
    return FeatureLayout(feature_names=("gain_1", "gain_2", "phase_1"), parameter_names=("pole1", "fc_pos"),
                         plan=np.array(plan))


@pytest.fixture(scope="module")
def trained():
    X, Y = data(600, 0)
    return train_network(X, Y, hidden=20, seed=0, options=FAST)


def test_learns_a_smooth_map(trained):
    Xt, Yt = data(500, 1)                       # fresh samples, never seen in training
    err = trained.predict(Xt) - Yt
    rms = np.sqrt(np.mean(err**2, axis=0))
    assert np.all(rms < 0.02 * Yt.std(axis=0)), rms / Yt.std(axis=0)
    assert trained.validation_rmse < 0.02
    assert trained.w1.shape == (20, 3) and trained.w2.shape == (2, 20) and trained.hidden == 20


@pytest.mark.parametrize("optimizer, activation, normalisation, extra", [
    ("lbfgs", "sigmoid", "minmax", dict(max_epochs=10, lbfgs_iterations=50)),
    ("adam", "tanh", "minmax", dict(learning_rate=1e-2, max_epochs=150, patience=20)),
    ("sgd", "tanh", "zscore", dict(max_epochs=300, patience=20)),     # the paper's backpropagation, rate 0.2
])
def test_other_optimizers_activations_and_normalisations_learn_too(optimizer, activation, normalisation, extra):
    X, Y = data(400, 2)
    net = train_network(X, Y, seed=1, options=TrainOptions(optimizer=optimizer, activation=activation,
                                                           normalisation=normalisation, **extra))
    Xt, Yt = data(300, 3)
    rms = np.sqrt(np.mean((net.predict(Xt) - Yt) ** 2, axis=0))
    # Reference: the least-squares affine fit; the network must halve its error on both outputs.
    A = np.column_stack([X, np.ones(len(X))])
    coef = np.linalg.lstsq(A, Y, rcond=None)[0]
    rms_affine = np.sqrt(np.mean((np.column_stack([Xt, np.ones(len(Xt))]) @ coef - Yt) ** 2, axis=0))
    assert np.all(rms < 0.5 * rms_affine), rms / rms_affine
    assert net.activation == activation and net.normalisation == normalisation and net.optimizer == optimizer


def test_predict_single_sample_and_constant_feature():
    X, Y = data(300, 4)
    X = np.column_stack([X, np.full(len(X), 7.0)])       # a feature that never changes
    net = train_network(X, Y, seed=0, options=TrainOptions(max_epochs=20))
    assert np.all(np.isfinite(net.predict(X)))
    np.testing.assert_array_equal(net.predict(X[5]), net.predict(X[5:6])[0])


def test_deterministic_with_a_seed(trained):
    X, Y = data(600, 0)
    again = train_network(X, Y, hidden=20, seed=0, options=FAST)
    other = train_network(X, Y, hidden=20, seed=1, options=FAST)
    for name in ("w1", "b1", "w2", "b2", "validation_loss"):
        np.testing.assert_array_equal(getattr(again, name), getattr(trained, name))
    assert not np.array_equal(other.w1, trained.w1)


def test_early_stopping_keeps_the_best_epoch():
    X, Y = data(300, 5)
    net = train_network(X, Y, seed=0, options=TrainOptions(optimizer="adam", learning_rate=0.05, max_epochs=2000,
                                                           patience=5, min_improvement=0.0))
    assert net.validation_loss.size == net.best_epoch + 1 + 5 < 2000
    assert net.best_epoch == int(np.argmin(net.validation_loss))
    assert net.validation_rmse == pytest.approx(np.sqrt(net.validation_loss.min()))


def test_threads_setting_is_restored():
    import torch

    before = torch.get_num_threads()
    X, Y = data(100, 6)
    train_network(X, Y, options=TrainOptions(max_epochs=2, threads=2 if before == 1 else 1))
    assert torch.get_num_threads() == before


def test_network_is_immutable(trained):
    with pytest.raises(ValueError):
        trained.w1[0, 0] = 1.0
    with pytest.raises(AttributeError):
        trained.activation = "sigmoid"


def test_save_load_round_trip(trained, tmp_path):
    path = tmp_path / "ANN.h5"
    save_network(trained, path, layout())
    net, lay = load_network(path)
    X, _ = data(50, 7)
    np.testing.assert_array_equal(net.predict(X), trained.predict(X))
    for name in ("w1", "b1", "w2", "b2", "x_shift", "x_scale", "y_shift", "y_scale", "train_loss",
                 "validation_loss"):
        np.testing.assert_array_equal(getattr(net, name), getattr(trained, name))
    assert (net.activation, net.normalisation, net.best_epoch, net.seed, net.optimizer) == \
        (trained.activation, trained.normalisation, trained.best_epoch, trained.seed, trained.optimizer)
    assert lay.feature_names == layout().feature_names and lay.parameter_names == layout().parameter_names
    np.testing.assert_array_equal(lay.plan, layout().plan)
    assert [p.name for p in tmp_path.iterdir()] == ["ANN.h5"]     # no temporary file left behind
    lay.check_compatible(layout(), path)                            # same plan: accepted


def test_plan_or_names_mismatch_is_refused(trained, tmp_path):
    path = save_network(trained, tmp_path / "ANN.h5", layout())
    _, lay = load_network(path)
    with pytest.raises(UserError, match=r"ANN\.h5 was trained on plan 3×2 .*data has plan 2×2") as info:
        lay.check_compatible(layout(plan=((2.0, 1.0), (1.0, 1.0))), path)
    assert "\n" not in str(info.value)
    with pytest.raises(UserError, match="was trained on plan"):
        lay.check_compatible(layout(plan=((2.0, 1.0), (2.0, 5.5), (1.0, 1.0))), path)
    with pytest.raises(UserError, match="features"):
        lay.check_compatible(FeatureLayout(("a", "b", "c"), lay.parameter_names, lay.plan), path)
    with pytest.raises(UserError, match="estimates parameters pole1, fc_pos"):
        lay.check_compatible(FeatureLayout(lay.feature_names, ("pole1", "fc_neg"), lay.plan), path)
    with pytest.raises(UserError, match="expects 3 features"):
        trained.predict(np.zeros((2, 4)))


def test_layout_that_does_not_fit_the_network_is_refused_and_the_old_file_survives(trained, tmp_path):
    path = save_network(trained, tmp_path / "ANN.h5", layout())
    bad = FeatureLayout(("a", "b"), ("pole1", "fc_pos"), np.zeros(2))
    with pytest.raises(UserError, match="2 features"):
        save_network(trained, path, bad)
    net, _ = load_network(path)
    np.testing.assert_array_equal(net.w1, trained.w1)


def _write_then(path, trained, edit):
    save_network(trained, path, layout())
    edit_hdf5(path, edit)  # given the digest of what it now holds: the reader's own checks meet the edit


@pytest.mark.parametrize("damage, words", [
    (lambda f: f.__delitem__("w2"), "damaged network file"),
    (lambda f: f["b1"].__setitem__(0, np.nan), "b1 holds NaN"),
    (lambda f: f.attrs.__setitem__("format", "something-else"), "not a servofmu network file"),
    (lambda f: f.attrs.__setitem__("schema_version", 99), "schema version 99"),
    (lambda f: f.attrs.__setitem__("seed", "x"), "damaged network file"),
    (lambda f: f.attrs.__setitem__("activation", "relu"), "activation 'relu'"),
    (lambda f: f["layout"].__delitem__("plan"), "damaged network file"),
])
def test_damaged_file_is_refused_naming_it(trained, tmp_path, damage, words):
    path = tmp_path / "ANN.h5"
    _write_then(path, trained, damage)
    with pytest.raises(UserError, match=words) as info:
        load_network(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_truncated_random_and_foreign_files_are_refused(trained, tmp_path):
    good = save_network(trained, tmp_path / "good.h5", layout())
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(good.read_bytes()[:1500])
    noise = tmp_path / "noise.h5"
    noise.write_bytes(np.random.default_rng(0).bytes(4096))
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["data"] = np.arange(3)
    for path in (truncated, noise, foreign, tmp_path / "missing.h5"):
        with pytest.raises(UserError, match=path.name):
            load_network(path)


@pytest.mark.parametrize("X, Y, words", [
    (np.zeros((10, 3)), np.zeros((9, 2)), "same n"),
    (np.zeros(10), np.zeros((10, 2)), "shapes"),
    (np.where(np.arange(30).reshape(10, 3) == 13, np.nan, 1.0), np.zeros((10, 2)), "features of sample 4"),
    (np.zeros((10, 3)), np.full((10, 2), np.inf), "parameters of sample 0"),
    (np.zeros((1, 3)), np.zeros((1, 2)), "too few"),
])
def test_bad_training_data_raises_user_error(X, Y, words):
    with pytest.raises(UserError, match=words):
        train_network(X, Y)


@pytest.mark.parametrize("kwargs, words", [
    (dict(activation="relu"), "activation"), (dict(normalisation="none"), "normalisation"),
    (dict(optimizer="rmsprop"), "optimizer"), (dict(batch_size=0), "batch_size"),
    (dict(learning_rate=-1.0), "learning_rate"), (dict(validation_fraction=1.0), "validation_fraction"),
    (dict(threads=0), "threads"), (dict(time_limit=0), "time_limit"), (dict(patience=1.5), "patience"),
])
def test_bad_training_options_raise_user_error(kwargs, words):
    with pytest.raises(UserError, match=words):
        TrainOptions(**kwargs)


def test_bad_hidden_or_seed_raise_user_error():
    X, Y = data(20, 0)
    with pytest.raises(UserError, match="hidden"):
        train_network(X, Y, hidden=0)
    with pytest.raises(UserError, match="seed"):
        train_network(X, Y, seed=-1)


def test_divergence_is_reported():
    X, Y = data(100, 0)
    with pytest.raises(UserError, match="diverged"):
        train_network(X, Y, options=TrainOptions(optimizer="sgd", learning_rate=1e6, max_epochs=50))


def test_network_class_is_plain_arrays():
    net = Network(w1=np.eye(2), b1=np.zeros(2), w2=np.ones((1, 2)), b2=np.zeros(1), x_shift=np.zeros(2),
                  x_scale=np.ones(2), y_shift=np.array([1.0]), y_scale=np.array([2.0]), activation="tanh",
                  normalisation="zscore", train_loss=np.zeros(1), validation_loss=np.zeros(1), best_epoch=0)
    # y = 1 + 2·(tanh(x1) + tanh(x2)), written out by hand
    np.testing.assert_allclose(net.predict([[0.3, -0.1]]), [[1 + 2 * (np.tanh(0.3) + np.tanh(-0.1))]])


def test_training_leaves_torchs_global_generator_alone():
    import torch

    X, Y = data(50, 0)
    state = torch.random.get_rng_state()
    train_network(X, Y, options=TrainOptions(max_epochs=2))
    assert torch.equal(torch.random.get_rng_state(), state)


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(trained, tmp_path, monkeypatch):
    path = save_network(trained, tmp_path / "ANN.h5", layout())
    before = path.read_bytes()

    def disk_full(self, name, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(h5py.Group, "create_dataset", disk_full)
    with pytest.raises(UserError, match="cannot write .*ANN.h5"):
        save_network(trained, path, layout())
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["ANN.h5"]
    with pytest.raises(UserError, match="does not exist"):
        save_network(trained, tmp_path / "missing" / "ANN.h5", layout())


@pytest.mark.parametrize("optimizer", ["lbfgs", "adam"])
def test_training_leaves_nothing_in_the_temporary_directory(tmp_path, monkeypatch, optimizer):
    """torch makes a compiler-cache folder at an optimizer's first step; it goes with servofmu's own folder."""
    import tempfile

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", None)
    X = np.random.default_rng(0).normal(size=(60, 2))
    train_network(X, X ** 2, hidden=3, options=TrainOptions(optimizer=optimizer, max_epochs=2))
    assert list(tmp_path.iterdir()) == []
