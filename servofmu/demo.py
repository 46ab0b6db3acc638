"""`servofmu demo`: the paper's plants g1 and g2 end to end."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from .fmu import build_fmu
from .measure import measure
from .plant import load_plant
from .plots import bode_figure

DEMO_PLANTS = ("g1", "g2")
DEMO_MAGNITUDES = (2.0, 0.6)  # m1 > m2, the paper's two excitation magnitudes


def run_demo(out: Path, report: Callable[[str], None]) -> dict:
    """Build each plant's FMU, measure it at the two magnitudes over the default frequency grid and draw the
    Bode figure beside the linear G(jw); ``report`` receives one line of progress at a time."""
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in DEMO_PLANTS:
        plant = load_plant(name)
        fmu = build_fmu(plant, out / f"{name}.fmu", fmi_version=3)
        report(f"built {fmu}")
        data_file = out / f"{name}.h5"
        data_file.unlink(missing_ok=True)  # the demo's own output of an earlier run: the FMU is new
        data = measure(fmu, data_file, amplitudes=DEMO_MAGNITUDES, command=f"servofmu demo --out {out}")
        results[name] = data
        unsettled = [e for e in data.experiments if not e.converged]
        report(f"measured {data_file}: {len(data.experiments)} experiments at "
               f"{', '.join(f'{f:g}' for f in data.plan.frequencies)} Hz"
               + (f"; {len(unsettled)} reached no steady state (friction-induced limit cycle; flagged)"
                  if unsettled else ""))
        for f in data.plan.frequencies[:3]:
            gain = abs(plant.frequency_response([2 * np.pi * f])[0])
            shown = ", ".join(f"{abs(data.experiment(m, f).H):.4f} at m = {m:g}" for m in DEMO_MAGNITUDES)
            report(f"  {f:g} Hz: |H| = {shown} (linear G alone: {gain:.4f})")
        grid = np.logspace(np.log10(min(data.plan.frequencies) / 2), np.log10(max(data.plan.frequencies) * 2), 200)
        figure = bode_figure(data, out / f"{name}-bode.png",
                             references={"linear G(jw), no friction": (grid, plant.frequency_response(2 * np.pi * grid))},
                             title=f"{name}: first harmonic of v at two excitation magnitudes")
        report(f"wrote {figure}")
    return results
