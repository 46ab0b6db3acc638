"""Every reading subcommand fed a damaged file — truncated, a flipped bit in an array, NaN, Inf, an array of the
wrong shape, a value of ±1e308 — ends with one line naming the file, exit status 2, no traceback, nothing
written and nothing left in the temporary directory."""
from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from harness import assert_one_line, flip_bit, run_here

# file kind -> the array the value faults go into
TARGETS = {"data": "experiments/exp_0000/window/v", "ds": "parameters", "ann": "w1", "result": "theta"}
# reader -> (the damaged input, the command with {bad} for it)
READERS = {
    "plot": ("data", ["plot", "{bad}", "-o", "out.png"]),
    "identify": ("data", ["identify", "{bad}", "--structure", "g1", "--ann", "{ann}", "-o", "out.h5"]),
    "dataset": ("data", ["dataset", "g1", "--like", "{bad}", "--samples", "10", "-o", "out.h5"]),
    "validate": ("data", ["validate", "{result}", "{bad}", "-o", "out.html"]),
    "train": ("ds", ["train", "{bad}", "-o", "out.h5"]),
    "identify --ann": ("ann", ["identify", "{data}", "--structure", "g1", "--ann", "{bad}", "-o", "out.h5"]),
    "report": ("result", ["report", "{bad}", "-o", "out.html"]),
    "export": ("result", ["export", "{bad}", "-o", "out.fmu"]),
    "select": ("data", ["select", "{bad}", "--validate", "{data2}", "--candidates", "coulomb/1", "--workers", "0",
                        "-o", "out.h5"]),
    "select --validate": ("data", ["select", "{data}", "--validate", "{bad}", "--candidates", "coulomb/1",
                                   "--workers", "0", "-o", "out.h5"]),
    "tune": ("result", ["tune", "{bad}", "{controller_toml}", "-o", "out.toml"]),
}
FAULTS = ("truncated", "bit-flip", "nan", "inf", "wrong-shape", "1e308", "-1e308")


def damage(path, fault: str, target: str, seed: int) -> None:
    if fault == "truncated":
        with open(path, "r+b") as fh:
            fh.truncate(path.stat().st_size // 2)
        return
    if fault == "bit-flip":
        flip_bit(path, np.random.default_rng(seed), [target])
        return
    with h5py.File(path, "r+") as f:
        values = np.array(f[target][()], dtype=float)
        del f[target]
        if fault == "wrong-shape":
            values = values.ravel()[:-1]
        else:
            values.flat[seed % values.size] = {"nan": np.nan, "inf": np.inf, "1e308": 1e308, "-1e308": -1e308}[fault]
        f.create_dataset(target, data=values)


CASES = [(reader, fault) for reader in READERS for fault in FAULTS]


@pytest.mark.parametrize("reader, fault", CASES)
def test_a_damaged_input_is_one_line_naming_it(inputs, tmp_path, reader, fault):
    kind, argv = READERS[reader]
    bad = tmp_path / f"bad-{kind}.h5"
    shutil.copyfile(inputs[kind], bad)
    damage(bad, fault, TARGETS[kind], seed=len(reader) + FAULTS.index(fault))
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, err = run_here([a.format(bad=bad, **{k: str(v) for k, v in inputs.items()}) for a in argv], tmp_path)
    assert_one_line(err, rc, 2, str(bad))
    assert sorted(p.name for p in tmp_path.iterdir()) == before
