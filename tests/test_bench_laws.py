"""scripts/bench_laws.py's helpers compute what the benchmark's table claims (fast: no fit is run)."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "scripts" / "bench_laws.py"
spec = importlib.util.spec_from_file_location("bench_laws", SCRIPT)
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def test_binomial_states_the_share_and_its_standard_error():
    assert bench.binomial(19, 20) == "95.0 ± 4.9 %"
    assert bench.binomial(20, 20) == "100.0 ± 0.0 %"
    assert bench.binomial(385, 400) == "96.2 ± 0.9 %"


def test_covers_counts_the_ends_and_nothing_outside():
    intervals = np.array([[0.9, 1.1], [1.0, 2.0], [2.0, 3.0], [-1.0, -0.5]])
    assert bench.covers(intervals, np.array([1.0, 1.0, 3.0000001, -0.75])).tolist() == [True, True, False, True]


def test_worst_relative_is_the_largest_relative_error_of_any_sign():
    assert bench.worst_relative([1.0, -2.002, 0.5], [1.0, -2.0, 0.5]) == pytest.approx(1e-3)
    assert bench.worst_relative([0.99, 2.0], [1.0, 2.0]) == pytest.approx(1e-2)


def test_the_record_moves_both_ways_about_zero():
    t, u = bench.multisine()
    assert t.size == 4000 and t[1] - t[0] == pytest.approx(0.005)
    assert abs(np.mean(u)) < 0.05 * np.std(u) and u.max() > 1.0 and u.min() < -1.0
