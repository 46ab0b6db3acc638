"""The plant's response from a drive's log in closed loop: from the reference (S_ry/S_ru) within its ±2σ band of the
true plant where the coherence is high, the direct estimate (S_uy/S_uu) biased by the noise the loop feeds back;
`frf --closed-loop` on an imported log, and its one-line refusal of a log without a reference."""
from __future__ import annotations

import json

import numpy as np
import pytest
from clitools import assert_one_line_error, run
from scipy import signal

from servofmu.broadband.bla import closed_loop_estimate, h1_estimate

RATE = 1000.0
POLE = np.exp(-10 / RATE)  # G(s) = 1/(s + 10), sampled behind a zero-order hold
GAIN = (1 - POLE) / 10


def loop_log(n=40000, seed=1):
    """A velocity loop u = kp·(r − y) around G, y = the plant's output plus coloured noise: (r, u, y)."""
    rng = np.random.default_rng(seed)
    r = 0.2 * rng.standard_normal(n)
    noise = signal.lfilter([1.0], [1.0, -0.9], 0.02 * rng.standard_normal(n))
    x, u, y = 0.0, np.zeros(n), np.zeros(n)
    for k in range(n):
        y[k] = x + noise[k]
        u[k] = 30.0 * (r[k] - y[k])
        x = POLE * x + GAIN * u[k]
    return r, u, y


def true_g(f):
    return GAIN / (np.exp(2j * np.pi * f / RATE) - POLE)


def test_from_the_reference_the_plant_is_within_its_band_and_the_direct_estimate_is_biased():
    r, u, y = loop_log()
    band = (1.0, 200.0)
    cl = closed_loop_estimate(r, u, y, RATE, 1250, band)
    direct = h1_estimate(u, y, RATE, 1250, band)
    good = cl.coherence_ru >= 0.9
    assert good.sum() > 100
    inside = np.abs(cl.G - true_g(cl.frequencies)) <= 2 * np.sqrt(cl.var)
    assert inside[good].mean() >= 0.9
    low = direct.frequencies < 5  # where the fed-back noise dominates: the direct estimate is off by far
    assert np.median(np.abs(direct.G[low] / true_g(direct.frequencies[low]) - 1)) > 0.3
    off = np.abs(direct.G - true_g(direct.frequencies)) > 2 * np.sqrt(direct.var)
    assert off[low].mean() > 0.5  # a bias, not scatter: outside its own band


def test_frf_closed_loop_of_an_imported_log_and_its_refusal_without_a_reference(tmp_path):
    r, u, y = loop_log(n=20000)
    log = tmp_path / "log.csv"
    np.savetxt(log, np.column_stack([np.arange(r.size) / RATE, u, y, r]), delimiter=",", header="t,u,v,r",
               comments="")
    data = tmp_path / "log.h5"
    assert run("import", log, "--time", "t", "--input", "u", "--output-variable", "v", "--reference", "r",
               "-o", data).returncode == 0
    proc = run("frf", data, "--closed-loop", "--json")
    assert proc.returncode == 0, proc.stderr
    (rec,) = json.loads(proc.stdout)["records"]
    assert rec["closed_loop"]["direct_deviation"] > 0.1
    assert len(rec["closed_loop"]["re"]) == len(rec["closed_loop"]["coherence_ru"]) > 100
    # the local polynomial method from the reference beside it: every DFT line but DC and Nyquist, one line and no
    # averaging (σ/|G| ≈ 1–2 in this loop), but its 95 % band holds the plant
    lpm = rec["lpm"]
    assert lpm["closed_loop"] and lpm["dof"] == 3 and lpm["band_factor"] > 2
    f, G = np.array(lpm["frequency"]), np.array(lpm["re"]) + 1j * np.array(lpm["im"])
    assert f.size == r.size // 2 - 1 and f[0] == pytest.approx(RATE / r.size)
    assert np.mean(np.abs(G - true_g(f)) <= lpm["band_factor"] * np.array(lpm["std"])) >= 0.9
    # and Fieller's band as a disc per line, null where unbounded: it holds the plant at least as often
    radius = np.array([np.inf if x is None else x for x in lpm["band_radius"]])
    centre = np.array(lpm["band_centre_re"]) + 1j * np.array(lpm["band_centre_im"])
    assert radius.size == f.size and np.isfinite(radius).mean() > 0.5
    assert np.mean(np.abs(centre - true_g(f)) <= radius) >= np.mean(np.abs(G - true_g(f)) <= lpm["band_factor"]
                                                                     * np.array(lpm["std"]))
    plain = tmp_path / "plain.h5"
    assert run("import", log, "--time", "t", "--input", "u", "--output-variable", "v", "-o", plain).returncode == 0
    proc = run("frf", plain, "--closed-loop", "-o", tmp_path / "f.png")
    assert_one_line_error(proc, "no reference", "--reference")
    assert not (tmp_path / "f.png").exists()


def test_frf_from_an_injected_test_signal_where_the_reference_drives_nothing(tmp_path):
    # a slow reference and a white test force injected at the drive's output: from the reference no frequency is
    # trusted, from the test signal the plant lies within the band where its coherence is high
    n, rng = 20000, np.random.default_rng(4)
    t = np.arange(n) / RATE
    r = 0.05 * np.sin(2 * np.pi * 0.2 * t)
    d = 2.0 * rng.standard_normal(n)
    noise = signal.lfilter([1.0], [1.0, -0.9], 0.02 * rng.standard_normal(n))
    x, u, y = 0.0, np.zeros(n), np.zeros(n)
    for k in range(n):
        y[k] = x + noise[k]
        u[k] = 30.0 * (r[k] - y[k]) + d[k]
        x = POLE * x + GAIN * u[k]
    log = tmp_path / "log.csv"
    np.savetxt(log, np.column_stack([t, u, y, r, d]), delimiter=",", header="t,u,v,r,d", comments="")
    data = tmp_path / "log.h5"
    assert run("import", log, "--time", "t", "--input", "u", "--output-variable", "v", "--reference", "r",
               "--disturbance", "d", "-o", data).returncode == 0
    found = {}
    for external in ("reference", "disturbance"):
        proc = run("frf", data, "--closed-loop", "--external", external, "--json")
        assert proc.returncode == 0, proc.stderr
        found[external] = json.loads(proc.stdout)["records"][0]["closed_loop"]
        assert found[external]["external"] == external
    assert max(found["reference"]["coherence_ru"]) < 0.9
    cl = found["disturbance"]
    f, G = np.array(cl["frequency"]), np.array(cl["re"]) + 1j * np.array(cl["im"])
    good = np.array(cl["coherence_ru"]) >= 0.9
    assert good.mean() > 0.5
    assert np.mean(np.abs(G - true_g(f))[good] <= 2 * np.array(cl["std"])[good]) >= 0.9
    assert_one_line_error(run("frf", data, "--external", "disturbance"), "--external", "--closed-loop")
    plain = tmp_path / "plain.h5"
    assert run("import", log, "--time", "t", "--input", "u", "--output-variable", "v", "--reference", "r",
               "-o", plain).returncode == 0
    assert_one_line_error(run("frf", plain, "--closed-loop", "--external", "disturbance"), "no disturbance",
                          "--disturbance")
