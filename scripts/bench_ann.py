"""Which optimiser trains the identifier's network best within 60 s, and how do PSO and the GAs
compare at the same evaluation budget?  Writes a markdown report to stdout.

Network data: a smooth inverse problem of the identifier's size.  A third-order G(s) (complex
pole pair, real pole, DC gain) with asymmetric Coulomb friction (fc_pos, fc_neg) is sampled
±20 % around the paper's G2; the features are describing-function first-harmonic responses
(log gain of the velocity amplitude with fc_pos and with fc_neg, phase) at 4 frequencies × 2
excitation magnitudes = 24 features; the targets are the 6 parameters; 0.1 % noise on the
features.  10 000 samples (8 000 train, 2 000 validation), 2 000 fresh test samples.

Usage: python scripts/bench_ann.py [--seconds 60] [--samples 10000] [--two-threads] > docs/bench-ann.md
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import replace

import numpy as np

from servofmu.identification.ann_training import TrainOptions, train_network
from servofmu.identification.ga import AdaptiveGaOptions, GaOptions, minimize_ga
from servofmu.identification.pso import PsoOptions, minimize_pso

NOMINAL = np.array([-2.5, 31.52, -10.0, 1.0, 0.5, 0.4])   # pole1_re, pole1_im, pole2, dc_gain, fc_pos, fc_neg
FREQS_HZ = np.array([1.0, 3.0, 5.0, 8.0])
MAGNITUDES = np.array([4.0, 2.0])


def features(P: np.ndarray, rng) -> np.ndarray:
    re, im, p3, k, fp, fn = P.T
    s = 2j * np.pi * FREQS_HZ[None, :]
    pa, pb, pc = (re + 1j * im)[:, None], (re - 1j * im)[:, None], p3[:, None]
    G = (k * (re**2 + im**2) * (-p3))[:, None] / ((s - pa) * (s - pb) * (s - pc))
    phase_g = -(np.angle(s - pa) + np.angle(s - pb) + np.angle(s - pc))   # unwrapped
    cols = []
    for m in MAGNITUDES:
        amps = []
        for F in (fp, fn, (fp + fn) / 2):
            c = (4 * F / np.pi)[:, None]
            # velocity amplitude A of v = H·m with 1/H = 1/G + 4F/(πA):  |A + cG| = m|G|
            A = -c * G.real + np.sqrt(np.maximum(c**2 * G.real**2 - c**2 * abs(G) ** 2 + m**2 * abs(G) ** 2, 0.0))
            amps.append(np.maximum(A, 1e-6))
        phase = phase_g - np.angle(1 + G * (4 * ((fp + fn) / 2)[:, None] / np.pi) / amps[2])
        cols += [np.log(amps[0] / m), np.log(amps[1] / m), phase]
    X = np.concatenate(cols, axis=1)
    return X + 1e-3 * rng.normal(size=X.shape)


def make_data(n: int, seed: int):
    rng = np.random.default_rng(seed)
    P = NOMINAL * rng.uniform(0.8, 1.2, size=(n, 6))
    return features(P, rng), P


def train_curve(X, Y, Xt, Yt, options, seconds):
    """Best validation RMSE reached by given wall times, and the test error of the final network."""
    t0, curve = time.perf_counter(), []
    opts = replace(options, max_epochs=10**7, patience=10**7, time_limit=seconds)
    net = train_network(X, Y, hidden=20, seed=0, options=opts,
                        progress=lambda e, n, v: curve.append((time.perf_counter() - t0, v)))
    t = np.array(curve)
    rel = np.abs(net.predict(Xt) - Yt) / np.abs(Yt)
    return t, len(curve), rel


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--two-threads", action="store_true",
                    help="also train with 2 threads (slow: many times slower when the other core is busy)")
    args = ap.parse_args()
    X, Y = make_data(args.samples, 1)
    Xt, Yt = make_data(2000, 2)
    print(f"# Identifier network and optimisers: measurements\n\n{platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, training on 1 thread.  {args.samples} samples × {X.shape[1]} features → "
          f"{Y.shape[1]} parameters, 20 hidden neurons (tanh), z-score normalisation.\n")

    marks = [m for m in (5, 10, 20, 40, 60) if m <= args.seconds]
    configs = {
        "L-BFGS, 100 iterations per epoch (default)": TrainOptions(),
        "L-BFGS, 20 iterations per epoch": TrainOptions(lbfgs_iterations=20),
        "Adam, lr 1e-2, batch 256": TrainOptions(optimizer="adam", learning_rate=1e-2, batch_size=256),
        "Adam, lr 3e-3, batch 128": TrainOptions(optimizer="adam", learning_rate=3e-3, batch_size=128),
        "SGD, lr 0.5, batch 64 (paper's backpropagation)": TrainOptions(optimizer="sgd", learning_rate=0.5),
    }
    print("## Validation RMSE (normalised units) reached after a wall time\n")
    print("| optimiser | " + " | ".join(f"{m} s" for m in marks) + " | epochs | test median / p95 rel. error |")
    print("|---|" + "---|" * len(marks) + "---|---|")
    for name, opts in configs.items():
        t, epochs, rel = train_curve(X, Y, Xt, Yt, opts, args.seconds)
        cells = [f"{np.sqrt(t[t[:, 0] <= m, 1].min()):.4f}" if (t[:, 0] <= m).any() else "–" for m in marks]
        print(f"| {name} | " + " | ".join(cells) + f" | {epochs} | {np.median(rel):.2e} / "
              f"{np.percentile(rel, 95):.2e} |", flush=True)

    print("\n## Default training (early stopping)\n\n| options | seconds | epochs | test median / p95 rel. error |"
          "\n|---|---|---|---|")
    runs = {"defaults": TrainOptions()}
    if args.two_threads:
        runs["defaults, 2 threads"] = TrainOptions(threads=2)
    for name, opts in runs.items():
        t0 = time.perf_counter()
        net = train_network(X, Y, seed=0, options=opts)
        dt = time.perf_counter() - t0
        rel = np.abs(net.predict(Xt) - Yt) / np.abs(Yt)
        print(f"| {name} | {dt:.1f} | {net.validation_loss.size} | {np.median(rel):.2e} / "
              f"{np.percentile(rel, 95):.2e} |", flush=True)

    def rosen(P):
        return (100 * (P[:, 1:] - P[:, :-1] ** 2) ** 2 + (1 - P[:, :-1]) ** 2).sum(1)

    target, scale = np.array([-10.0, 10.0, 1.0, 0.5, 0.4]), np.array([1, 1, 0.1, 0.05, 0.05])
    problems = {
        "sphere 6-D, box ±2, minimum at 0.3": (lambda P: ((P - 0.3) ** 2).sum(1), -2 * np.ones(6), 2 * np.ones(6)),
        "Rosenbrock 2-D, box ±2": (rosen, -2 * np.ones(2), 2 * np.ones(2)),
        "Rosenbrock 4-D, box ±2": (rosen, -2 * np.ones(4), 2 * np.ones(4)),
        "scaled quadratic 5-D, box ±30 % around G1's parameters": (
            lambda P: (((P - target) / scale) ** 2).sum(1), target - 0.3 * abs(target), target + 0.3 * abs(target)),
    }
    print("\n## PSO (Table I settings) vs GA vs adaptive GA, 510 cost evaluations each\n\n"
          "Median best cost over 20 seeds.\n\n| problem | PSO | GA | adaptive GA |\n|---|---|---|---|")
    seeds = range(20)
    for name, (f, lo, hi) in problems.items():
        pso = np.median([minimize_pso(f, lo, hi, PsoOptions(), seed=s).cost for s in seeds])
        ga = np.median([minimize_ga(f, lo, hi, GaOptions(max_evaluations=510), seed=s).cost for s in seeds])
        aga = np.median([minimize_ga(f, lo, hi, AdaptiveGaOptions(max_evaluations=510), seed=s).cost for s in seeds])
        print(f"| {name} | {pso:.2e} | {ga:.2e} | {aga:.2e} |", flush=True)


if __name__ == "__main__":
    main()
