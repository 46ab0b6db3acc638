"""The local polynomial method (servofmu.broadband.lpm) against H1 over seeds, in numbers pasted into
docs/broadband.md ("The local polynomial method").

1. Open loop: G(s) = ω²/(s² + 2ζωs + ω²), f_n = 20 Hz, ζ = 0.3, behind a zero-order hold at 1 kHz; a white input,
   4096 samples cut out of a longer run (a non-zero initial and final state: a transient and leakage), white output
   noise σ; 20 seeds.  The share of the lines whose 95 % band (k = √F⁻¹(0.95; 2, 2·dof)) holds the true G, the
   median relative error below 2·f_n of the LPM and of H1 (256-sample Welch segments), the mean σ²_V over N·σ².
2. Noise-free: the LPM's relative error (median, 95th percentile, worst) for R = 2 and 3, and H1's.
3. Closed loop: G = 1/(s + 10), u = 30·(r − y), white reference, coloured output noise the loop feeds back, 20 000
   samples, 20 seeds: the share within the first-order band from the reference and within Fieller's (1–200 Hz,
   and below 5 Hz; LpmEstimate.band), the share of lines Fieller's leaves unbounded, the mean relative
   error below 5 Hz of the LPM from the reference and of the direct (open-loop) LPM.
4. Time of one LPM (R = 2) on 10⁶ samples.

Usage: python scripts/bench_lpm.py [SEEDS]
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy import signal

from servofmu.broadband.bla import h1_estimate
from servofmu.broadband.lpm import lpm_estimate

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_closed_loop_frf import loop_log  # noqa: E402  (the test's velocity loop)

RATE, N, FN, ZETA = 1000.0, 4096, 20.0, 0.3
W = 2 * np.pi * FN
B, A, _ = signal.cont2discrete(([W * W], [1, 2 * ZETA * W, W * W]), 1 / RATE, method="zoh")
B = np.squeeze(B)
POLE = np.exp(-10 / RATE)


def g_plant(f):
    z = np.exp(2j * np.pi * f / RATE)
    return np.polyval(B, z) / np.polyval(A, z)


def g_loop(f):
    return (1 - POLE) / 10 / (np.exp(2j * np.pi * f / RATE) - POLE)


def record(seed, sigma):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(N + 1000)
    return u[1000:], signal.lfilter(B, A, u)[1000:] + sigma * rng.standard_normal(N)


def main(seeds: int) -> None:
    for sigma in (0.05, 0.005):
        inside, le, he, ratio = [], [], [], []
        for s in range(seeds):
            u, y = record(s, sigma)
            e, h = lpm_estimate(u, y, RATE), h1_estimate(u, y, RATE, 256)
            inside.append(np.abs(e.G - g_plant(e.frequencies)) <= e.band_factor() * e.std)
            le.append(np.abs(e.G / g_plant(e.frequencies) - 1)[e.frequencies < 2 * FN])
            he.append(np.abs(h.G / g_plant(h.frequencies) - 1)[h.frequencies < 2 * FN])
            ratio.append(np.mean(e.noise_var) / (N * sigma ** 2))
        print(f"open loop, σ = {sigma}: within the 95 % band {100 * np.concatenate(inside).mean():.1f} % of the lines; "
              f"median relative error below {2 * FN:g} Hz: LPM {np.median(np.concatenate(le)):.2g}, H1 "
              f"{np.median(np.concatenate(he)):.2g}; σ²_V/(N·σ²) {np.mean(ratio):.3f} (seeds {min(ratio):.3f}–"
              f"{max(ratio):.3f})")
    for order in (2, 3):
        errs = np.concatenate([np.abs((e := lpm_estimate(*record(s, 0.0), RATE, order)).G / g_plant(e.frequencies) - 1)
                               for s in range(seeds)])
        print(f"noise-free, R = {order}: relative error median {np.median(errs):.2g}, 95th percentile "
              f"{np.quantile(errs, 0.95):.2g}, worst {errs.max():.2g}")
    h1 = np.concatenate([np.abs((h := h1_estimate(*record(s, 0.0), RATE, 256)).G / g_plant(h.frequencies) - 1)
                         for s in range(seeds)])
    print(f"noise-free, H1: relative error median {np.median(h1):.2g}")
    inside, low_in, cl_bias, d_bias, fieller, low_fieller, unbounded, low_unbounded = [], [], [], [], [], [], [], []
    bounded_low = []  # (held, lines) of the bounded lines below 5 Hz
    for s in range(seeds):
        r, u, y = loop_log(20000, s)  # the test's loop (tests/test_closed_loop_frf.py)
        cl, d = (lpm_estimate(u, y, RATE, band=(1.0, 200.0), reference=ref) for ref in (r, None))
        g = g_loop(cl.frequencies)
        ok = np.abs(cl.G - g) <= cl.band_factor() * cl.std  # the first-order band
        centre, radius = cl.band()  # Fieller's (LpmEstimate.band)
        held = np.abs(centre - g) <= radius
        low = cl.frequencies < 5
        inside.append(ok.mean()), low_in.append(ok[low].mean())
        fieller.append(held.mean()), low_fieller.append(held[low].mean()), unbounded.append(np.isinf(radius).mean())
        low_unbounded.append(np.isinf(radius[low]).mean())
        finite = low & np.isfinite(radius)
        bounded_low.append((held[finite].sum(), finite.sum()))
        cl_bias.append(abs(np.mean(cl.G[low] / g[low] - 1))), d_bias.append(abs(np.mean(d.G[low] / g[low] - 1)))
    print(f"closed loop: within the first-order band from the reference {100 * np.mean(inside):.1f} % of the lines "
          f"1–200 Hz (seeds {100 * min(inside):.0f}–{100 * max(inside):.0f} %), {100 * np.mean(low_in):.1f} % below "
          f"5 Hz; within Fieller's band {100 * np.mean(fieller):.1f} % (seeds {100 * min(fieller):.0f}–"
          f"{100 * max(fieller):.0f} %), {100 * np.mean(low_fieller):.1f} % below 5 Hz, unbounded at "
          f"{100 * np.mean(unbounded):.1f} % of the lines ({100 * np.mean(low_unbounded):.1f} % below 5 Hz, where "
          f"it held G at {100 * sum(h for h, _ in bounded_low) / sum(n for _, n in bounded_low):.1f} % of the "
          f"{sum(n for _, n in bounded_low)} lines it bounded); mean relative error below 5 Hz: from the reference "
          f"{np.mean(cl_bias):.2f}, direct {np.mean(d_bias):.2f}")
    rng = np.random.default_rng(0)
    u = rng.standard_normal(10 ** 6)
    y = signal.lfilter(B, A, u)
    t = time.perf_counter()
    lpm_estimate(u, y, RATE)
    print(f"speed: LPM (R = 2, 9 lines) of 1e6 samples, 499 999 lines: {time.perf_counter() - t:.2f} s")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20)
