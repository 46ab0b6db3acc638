"""`servofmu demo`: the paper's plants g1 and g2 end to end."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..fmu import build_fmu
from ..identification.ann import AnnModel, load_network
from ..identification.criterion import sine_data
from ..identification.identifier import PSOANNIdentifier
from ..identification.results import paper_rows, result_from_estimator, write_result
from ..identification.train import train_from_file
from ..identification.training_set import make_training_set
from ..measurement.measure import measure
from ..model.plant import load_plant
from .export import file_sha256, remeasure
from .paper import COLUMNS, TABLES
from .plots import bode_figure
from .report import make_report

__all__ = ["run_demo", "paper_comparison", "DEMO_PLANTS", "DEMO_PLANS", "DEMO_SAMPLES"]

DEMO_PLANTS = ("g1", "g2")
# Excitation magnitudes m1 > m2 and frequencies per plant.  g2 (as the paper defines it, with Coulomb friction in
# the feedback of a third-order G) has a friction-induced limit cycle near 5.2 Hz: at low magnitudes or above
# ~6 Hz its response never becomes periodic, so its plan keeps to magnitudes and frequencies that settle.
DEMO_PLANS = {"g1": ((2.0, 0.6), (0.5, 1.0, 2.0, 5.0, 10.0, 20.0)),
              "g2": ((4.0, 2.0), (0.5, 1.0, 2.0, 3.0, 4.0, 5.0))}
DEMO_SAMPLES = 3000  # training-set size of the demo (`servofmu dataset --samples`)


def run_demo(out: Path, report: Callable[[str], None], samples: int = DEMO_SAMPLES) -> dict:
    """The whole path for g1 and g2: build → measure → dataset → train → identify → report → export → re-measure.

    ``report`` receives one line (or table) of progress at a time.  Returns per plant the identification result.
    """
    out.mkdir(parents=True, exist_ok=True)
    command = f"servofmu demo --out {out}"
    results = {}
    for name in DEMO_PLANTS:
        plant = load_plant(name)
        amplitudes, frequencies = DEMO_PLANS[name]
        fmu = build_fmu(plant, out / f"{name}.fmu", fmi_version=3)
        report(f"built {fmu}")
        # the demo's own outputs of an earlier run are replaced: the FMU is new
        for suffix in (".h5", "-ds.h5", "-remeasured.h5"):
            (out / f"{name}{suffix}").unlink(missing_ok=True)
        data_file = out / f"{name}.h5"
        data = measure(fmu, data_file, amplitudes=amplitudes, frequencies=frequencies, command=command)
        unsettled = sum(not e.converged for e in data.experiments)
        report(f"measured {data_file}: {len(data.experiments)} experiments, magnitudes "
               f"{', '.join(map(str, amplitudes))} N at {', '.join(f'{f:g}' for f in frequencies)} Hz"
               + (f"; {unsettled} reached no steady state (flagged, not used)" if unsettled else ""))
        grid = np.logspace(np.log10(min(frequencies) / 2), np.log10(max(frequencies) * 2), 200)
        figure = bode_figure(data, out / f"{name}-bode.png",
                             references={"linear G(jw), no friction": (grid, plant.frequency_response(2 * np.pi * grid))},
                             title=f"{name}: first harmonic of v at two excitation magnitudes")
        report(f"wrote {figure}")

        sines = sine_data(data)
        t0 = time.perf_counter()
        make_training_set(plant, sines, samples, out / f"{name}-ds.h5", seed=0, command=command)
        net, rows = train_from_file(out / f"{name}-ds.h5", out / f"{name}-ann.h5", seed=0)
        report(f"trained {out / f'{name}-ann.h5'} on {rows} simulated plants ({time.perf_counter() - t0:.1f} s)")
        ann = AnnModel(*load_network(out / f"{name}-ann.h5"), source=str(out / f"{name}-ann.h5"))
        est = PSOANNIdentifier(plant, ann=ann, seed=0).fit(sines)
        result = result_from_estimator(est, "pso-ann", {"data_file": str(data_file),
                                                        "data_sha256": file_sha256(data_file), "command": command})
        write_result(out / f"{name}-result.h5", result)
        results[name] = result
        report(paper_comparison(name, result))

        page = make_report(out / f"{name}-result.h5", out / f"{name}-report.html", data=data_file, truth=name)
        report(f"wrote {page}")
        trip = remeasure(result, data_file, out / f"{name}-identified.fmu", out / f"{name}-remeasured.h5",
                         command=command)
        report(f"exported {trip.fmu} and re-measured it: largest |H − H_data|/|H_data| {trip.max_H_error:.2e} "
               f"(identification residual {result.fitness:.2e})")
    return results


def paper_comparison(name: str, result) -> str:
    """Our identified values beside the paper's published columns (Table II for g1, III for g2)."""
    table = TABLES[name]
    ours = dict(paper_rows(result.plant))
    head = ["parameter", *COLUMNS, "servofmu PSO-ANN"]
    rows = [[label, *values, ours.get(label, "")] for label, values in table.items()]
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths))]
    lines += ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)) for r in rows]
    lines.append(f"(servofmu: fitness {result.fitness:.2e}, {result.seconds:.2f} s, "
                 f"{result.evaluations} model evaluations)")
    return "\n".join(lines)
