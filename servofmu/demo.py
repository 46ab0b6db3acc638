"""`servofmu demo`: the paper's plants g1 and g2 end to end."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from .fmu import build_fmu
from .plant import load_plant
from .simulate import simulate

DEMO_PLANTS = ("g1", "g2")
DEMO_MAGNITUDES = (2.0, 0.6)  # m1 > m2, the paper's two excitation magnitudes
DEMO_FREQUENCY = 1.0          # Hz


def run_demo(out: Path, report: Callable[[str], None]) -> dict:
    """Build, simulate and plot; ``report`` receives one line of progress at a time."""
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in DEMO_PLANTS:
        plant = load_plant(name)
        fmu = build_fmu(plant, out / f"{name}.fmu", fmi_version=3)
        report(f"built {fmu}")
        for m in DEMO_MAGNITUDES:
            res = simulate(fmu, stop_time=10.0, interface="cs", amplitude=m, frequency=DEMO_FREQUENCY,
                           output_interval=1e-3)
            last = res["time"] >= 10.0 - 1.0 / DEMO_FREQUENCY
            results[(name, m)] = res
            gain = abs(plant.frequency_response([2 * np.pi * DEMO_FREQUENCY])[0])
            report(f"{name}: magnitude {m}: peak |v| over the last period {np.abs(res['v'][last]).max():.4f} m/s "
                   f"(linear G alone: {m * gain:.4f})")
    figure = out / "demo.png"
    _plot(results, figure)
    report(f"wrote {figure}")
    return results


def _plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(DEMO_PLANTS), 1, figsize=(8, 3.2 * len(DEMO_PLANTS)), sharex=True)
    for ax, name in zip(np.atleast_1d(axes), DEMO_PLANTS):
        for m in DEMO_MAGNITUDES:
            res = results[(name, m)]
            ax.plot(res["time"], res["v"], label=f"magnitude {m}")
        ax.set_title(f"{name}: velocity under a {DEMO_FREQUENCY} Hz sine")
        ax.set_ylabel("v [m/s]")
        ax.grid(True)
        ax.legend()
    np.atleast_1d(axes)[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
