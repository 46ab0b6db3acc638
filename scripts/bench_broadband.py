"""What the broadband measurement gives, in numbers pasted into docs/broadband.md.

1. Crest factors of the multisine: plain random phases against the clipping iterations (mean and worst of 8
   realisations), for the odd-random and the full grid, and of the chirp and the PRBS.
2. The BLA through an FMU: g2 with its friction set to zero (a linear plant), noise-free, against the zero-order-hold
   discretisation of G2(s) at every excited line.
3. Friction as distortion: g1, g2, stribeck_servo (and the friction-free g2) at 2.0 and 0.6 N RMS, 40 dB output
   noise: the distortion over the noise, the distortion relative to the linear part, the detection lines.
4. Speed: the BLA and the H1 estimate of a 10^6-sample record; the FMU run of each measurement above.

Usage: python scripts/bench_broadband.py
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import signal

from servofmu.broadband import BroadbandPlan, crest_factor, estimate_bla, h1_estimate, split_periods
from servofmu.broadband.measure import measure_broadband
from servofmu.fmu import build_fmu
from servofmu.measurement.measure import MeasureOptions
from servofmu.model.plant import load_plant

ROOT = Path(__file__).resolve().parent.parent
PLAN = dict(band=(0.2, 50.0), rate=1000.0, period=5.0, periods=2, transient_periods=1, realisations=4)


def crest_factors() -> None:
    print("| signal | grid | lines | crest factor, mean of 8 | worst |\n|---|---|---|---|---|")
    for grid in ("odd-random", "full"):
        for iterations in (0, 100):
            p = BroadbandPlan("multisine", (1.0,), grid=grid, crest_iterations=iterations,
                              **{**PLAN, "realisations": 8})
            c = [crest_factor(p.realisation(r)) for r in range(8)]
            what = "random phases" if iterations == 0 else f"random phases + {iterations} clipping iterations"
            print(f"| multisine, {what} | {grid} | {p.lines.size} | {np.mean(c):.2f} | {np.max(c):.2f} |")
    for kind in ("chirp", "prbs"):
        p = BroadbandPlan(kind, (1.0,), **{**PLAN, "period": None})
        print(f"| {kind} | full | {p.lines.size} | {crest_factor(p.realisation(0)):.2f} | |")


def friction_free(folder: Path, name: str) -> Path:
    text = (ROOT / "fmu_models" / f"{name}.toml").read_text()
    plant = load_plant(ROOT / "fmu_models" / f"{name}.toml")
    for key in ("fc_pos", "fc_neg"):
        text = text.replace(f"{key} = {getattr(plant.friction, key, None) or ''}", f"{key} = 0.0")
    text = text.replace(f'name = "{name}"', f'name = "{name}_linear"')
    (folder / f"{name}_linear.toml").write_text(text)
    return build_fmu(load_plant(folder / f"{name}_linear.toml"), folder / f"{name}_linear.fmu")


def linear_check(folder: Path, fmu: Path) -> None:
    plan = BroadbandPlan("multisine", (1.0,), (0.5, 40.0), 200.0, period=2.0, periods=2, transient_periods=4,
                         realisations=2)
    b = measure_broadband(fmu, folder / "lin.h5", plan).levels[0].bla
    den = np.polymul([1, 10], [1, 5, 2.5 ** 2 + 31.52 ** 2])
    a, bb, c, d, _ = signal.cont2discrete(signal.tf2ss([den[-1]], den), 1 / 200, "zoh")
    g = np.array([(c @ np.linalg.solve(z * np.eye(3) - a, bb))[0, 0] + d[0, 0]
                  for z in np.exp(2j * np.pi * b.frequencies / 200)])
    print(f"\nfriction-free g2 through its FMU, noise-free, {b.frequencies.size} lines 0.5..40 Hz at 200 Hz: "
          f"max |G_BLA − G_zoh| / |G_zoh| = {np.max(np.abs(b.G - g) / np.abs(g)):.2e}")


def friction_table(folder: Path, fmus: dict) -> None:
    print("\n| plant | level (N RMS) | distortion over noise (dB) | total over noise (dB) | distortion re linear "
          "part (dB) | odd / even detection lines over noise (dB) | min coherence | between the lines | FMU run (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, (fmu, levels) in fmus.items():
        start = time.perf_counter()
        data = measure_broadband(fmu, folder / f"{name}.h5", BroadbandPlan("multisine", levels, **PLAN),
                                 MeasureOptions(noise_snr_db=40.0, seed=1))
        seconds = time.perf_counter() - start
        for lv in data.levels:
            b = lv.bla
            between = "periodic" if b.periodic else (f"{b.nonsynchronous_frequency:.3g} Hz, "
                                                     f"{b.nonsynchronous_re_response_db:.0f} dB re the response")
            print(f"| {name} | {lv.level:g} | {b.distortion_to_noise_db:.1f} | {b.total_to_noise_db:.1f} | "
                  f"{b.relative_distortion_db:.1f} | {b.detection_to_noise_db('odd'):.1f} / "
                  f"{b.detection_to_noise_db('even'):.1f} | {np.min(b.coherence):.3f} | {between} | {seconds:.1f} |")


def speed() -> None:
    p = BroadbandPlan("multisine", (1.0,), (1.0, 400.0), 1000.0, period=1.0, periods=250, transient_periods=0,
                      realisations=4)
    u = p.signals()[0]
    y = np.stack([signal.lfilter([0.05], [1, -0.95], x) for x in u])
    start = time.perf_counter()
    estimate_bla(split_periods(u, p.samples, 250, 0), split_periods(y, p.samples, 250, 0), p.lines, p.rate,
                 p.free_lines)
    bla = time.perf_counter() - start
    start = time.perf_counter()
    h1_estimate(u.ravel(), y.ravel(), p.rate, segment=4096)
    h1 = time.perf_counter() - start
    print(f"\n{u.size:.0e} samples (4 realisations x 250 periods x 1000): BLA {bla:.2f} s, H1 (Welch, 4096) "
          f"{h1:.2f} s")


def main() -> None:
    crest_factors()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        linear = friction_free(folder, "g2")
        linear_check(folder, linear)
        fmus = {name: build_fmu(load_plant(name), folder / f"{name}.fmu") for name in ("g1", "g2", "stribeck_servo")}
        # g2's friction closes a relay loop that oscillates on its own below some level: the plan 6 and 2 N too
        friction_table(folder, {**{name: (fmu, (2.0, 0.6)) for name, fmu in fmus.items()},
                                "g2 (6 and 2 N)": (fmus["g2"], (6.0, 2.0)),
                                "g2, friction 0": (linear, (2.0, 0.6))})
    speed()


if __name__ == "__main__":
    main()
