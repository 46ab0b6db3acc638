"""`servofmu demo`: the paper's plants g1 and g2 end to end, then the example axis (inclined: gravity on it) in its
loop: co-simulated with test pulses, written as its drive would log it (volts, the drive's clock) and imported,
identified from that log, validated on a second one, its friction compensated, its drive's gains tuned on the
identified model and checked on the axis."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..identification.closed_loop import closed_loop_data
from ..model.controller import load_controller
from ..control.cosim import cosimulate
from ..control.fmus import build_controller_fmu
from ..control.system import write_system
from ..fmu import build_fmu
from ..identification.ann import AnnModel, load_network
from ..identification.criterion import sine_data
from ..identification.identifier import PSOANNIdentifier
from ..identification.prior import identified_mask
from ..identification.results import paper_rows, result_from_estimator, write_result
from ..identification.train import train_from_file
from ..identification.training_set import make_training_set
from ..measurement.measure import PROGRESS_SCALE, measure
from ..measurement.records import LoopChannels, import_records
from ..runtime import Progress, RunOptions
from ..model.plant import load_plant
from ..control.compensation import compensate_files
from ..output.compensation_report import compensation_page, compensation_text
from ..claims import refuse_package_data
from ..fileio import OutputExists, atomic_write, file_sha256, staged_folder
from .roundtrip import remeasure
from ..output.paper import COLUMNS, TABLES
from ..output.plots import bode_figure
from ..output.report import make_report
from ..tuning.search import TuneOptions
from ..tuning.run import tune_files
from ..output.tune_report import tune_html, tune_text
from ..validation.replay import validate

__all__ = ["run_demo", "run_closed_loop_demo", "paper_comparison", "reference_trajectories", "demo_pulses",
           "write_drive_log", "DEMO_PLANTS", "DEMO_PLANS", "DEMO_SAMPLES", "DEMO_AXIS_LOAD", "FORCE_CONSTANT",
           "PULSE_FORCE", "CLOCK_FAST", "CLOCK_JITTER", "REST", "resting_first"]

DEMO_PLANTS = ("g1", "g2")
# Excitation magnitudes m1 > m2 and frequencies per plant.  g2 (as the paper defines it, with Coulomb friction in
# the feedback of a third-order G) has a friction-induced limit cycle near 5.2 Hz: at low magnitudes or above
# ~6 Hz its response never becomes periodic, so its plan keeps to magnitudes and frequencies that settle.
DEMO_PLANS = {"g1": ((2.0, 0.6), (0.5, 1.0, 2.0, 5.0, 10.0, 20.0)),
              "g2": ((4.0, 2.0), (0.5, 1.0, 2.0, 3.0, 4.0, 5.0))}
DEMO_SAMPLES = 3000  # training-set size of the demo (`servofmu dataset --samples`)


def run_demo(out: Path, report: Callable[[str], None], samples: int = DEMO_SAMPLES, overwrite: bool = False,
             stage: Callable[..., Progress | None] | None = None) -> dict:
    """The whole path for g1 and g2: build → measure → dataset → train → identify → report → export → re-measure.

    ``out`` is the demo's folder: a folder that exists and is not empty is refused unless ``overwrite`` (the demo's
    files in it are then replaced, all together when the demo ends: a demo stopped or failing before leaves the
    folder as it was).  ``report`` receives one line (or table) of progress at a time; ``stage(label, unit,
    scale)``, if given, the Progress callback of each long step (measure, training set, training).  Returns per
    plant the identification result.
    """
    out = Path(out)
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputExists(out)  # a folder that is not empty: the rule of every output
    refuse_package_data(out)
    with staged_folder(out) as work:  # all of the demo's files, or none: a stopped demo leaves the old ones
        return _demo(work, lambda line: report(line.replace(str(work), str(out))), samples,
                     f"servofmu demo -o {out}", out, stage or (lambda *_: None))


def _demo(out: Path, report: Callable[[str], None], samples: int, command: str, final: Path,
          stage: Callable[..., Progress | None]) -> dict:
    """:func:`run_demo` into the folder ``out`` (its staging folder); the results name their data in ``final``,
    where it will be."""
    results = {}
    for name in DEMO_PLANTS:
        plant = load_plant(name)
        amplitudes, frequencies = DEMO_PLANS[name]
        fmu = build_fmu(plant, out / f"{name}.fmu", fmi_version=3, overwrite=True)
        report(f"built {fmu}")
        data_file = out / f"{name}.h5"
        data = measure(fmu, data_file, amplitudes=amplitudes, frequencies=frequencies,
                       run=RunOptions(command=command, progress=stage(f"{name}: measure", "experiment",
                                                                      PROGRESS_SCALE)))
        unsettled = sum(not e.converged for e in data.experiments)
        report(f"measured {data_file}: {len(data.experiments)} experiments, magnitudes "
               f"{', '.join(map(str, amplitudes))} N at {', '.join(f'{f:g}' for f in frequencies)} Hz"
               + (f"; {unsettled} reached no steady state (flagged, not used)" if unsettled else ""))
        grid = np.logspace(np.log10(min(frequencies) / 2), np.log10(max(frequencies) * 2), 200)
        figure = bode_figure(data, out / f"{name}-bode.png",
                             references={"linear G(jw), no friction": (grid, plant.frequency_response(2 * np.pi * grid))},
                             title=f"{name}: first harmonic of v at two excitation magnitudes", overwrite=True)
        report(f"wrote {figure}")

        sines = sine_data(data)
        t0 = time.perf_counter()
        make_training_set(plant, sines, samples, out / f"{name}-ds.h5", seed=0,
                          run=RunOptions(command=command, progress=stage(f"{name}: training set", "plant")))
        net, rows = train_from_file(out / f"{name}-ds.h5", out / f"{name}-ann.h5", seed=0,
                                    run=RunOptions(overwrite=True, progress=stage(f"{name}: train", "epoch")))
        report(f"trained {out / f'{name}-ann.h5'} on {rows} simulated plants ({time.perf_counter() - t0:.1f} s)")
        ann = AnnModel(*load_network(out / f"{name}-ann.h5"), source=str(out / f"{name}-ann.h5"))
        est = PSOANNIdentifier(plant, ann=ann, seed=0).fit(sines)
        result = result_from_estimator(est, "pso-ann", {"data_file": str(final / data_file.name),
                                                        "data_sha256": file_sha256(data_file), "command": command})
        write_result(out / f"{name}-result.h5", result, overwrite=True)
        results[name] = result
        report(paper_comparison(name, result))

        page = make_report(out / f"{name}-result.h5", out / f"{name}-report.html", data=data_file, truth=name,
                           overwrite=True)
        report(f"wrote {page}")
        trip = remeasure(result, data_file, out / f"{name}-identified.fmu", out / f"{name}-remeasured.h5",
                         command=command)
        report(f"exported {trip.fmu} and re-measured it: largest |H − H_data|/|H_data| {trip.max_H_error:.2e} "
               f"(identification residual {result.fitness:.2e})")
    results["axis"] = run_closed_loop_demo(out, report, command, final)
    return results


def reference_trajectories(sample_time: float = 1e-3) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The demo's references, each from rest at 0 (m):

    - ``identify`` (16 s): 4 s of two superposed reversing motions (up to 0.17 m/s), then 12 s of a slow
      reversing stroke (up to 0.015 m/s) that dwells in the Stribeck region of low velocities;
    - ``validate`` (3 s): other reversing motions;
    - ``reversals`` (4 s): a 0.05 m stroke at 0.5 Hz, for the compensation."""
    def t(duration):
        return np.arange(0.0, duration + sample_time / 2, sample_time)

    a, b, c = t(16.0), t(3.0), t(4.0)
    fast = 0.03 * (1 - np.cos(np.pi * a)) + 0.01 * (1 - np.cos(2 * np.pi * 2.25 * a))  # back at rest at 4 s
    slow = 0.0095 * (1 - np.cos(2 * np.pi * 0.25 * (a - 4.0)))
    return {"identify": (a, np.where(a < 4.0, fast, slow)),
            "validate": (b, 0.04 * (1 - np.cos(2 * np.pi * 0.7 * b)) - 0.015 * (1 - np.cos(2 * np.pi * 1.9 * b))),
            "reversals": (c, 0.05 * (1 - np.cos(np.pi * c)))}


# The demo's axis: linear_axis on a 3° incline, gravity pulling it towards negative positions (m·g·sin 3°); its
# drive's log in volts with a force constant, test pulses injected after the output limit, a clock of its own.
DEMO_AXIS_LOAD = "\n[load]\noffset = -51.3\n"
FORCE_CONSTANT = 50.0  # N/V
PULSE_FORCE = 150.0  # N, for 10 ms every 0.2 s
CLOCK_FAST, CLOCK_JITTER = 5e-6, 2e-5  # the log's clock rate error and its jitter (RMS), relative to a sample
# The identification run first holds the axis at rest: the force that holds it against gravity, with no friction
# at rest, tells the offset from the friction (in motion only their sums offset ∓ fc± show).
REST = 1.0  # s


def resting_first(reference: tuple[np.ndarray, np.ndarray], rest: float) -> tuple[np.ndarray, np.ndarray]:
    """``reference`` (times from 0, a position from 0) delayed by ``rest`` seconds at 0."""
    t, x = reference
    ts = t[1] - t[0]
    extra = int(round(rest / ts))
    return np.arange(t.size + extra) * ts, np.concatenate([np.zeros(extra), x])


def demo_pulses(time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The drive's test pulses (N) at the samples ``time``: ±PULSE_FORCE for 10 ms every 0.2 s, signs alternating
    irregularly."""
    on = (time % 0.2 >= 0.1) & (time % 0.2 < 0.11 - 1e-9)
    return time, np.where(on, PULSE_FORCE * np.sign(np.sin(2 * np.pi * 1.3 * time) + 1e-12), 0.0)


def write_drive_log(result, path: Path, seed: int) -> Path:
    """A co-simulated run as the drive logs it (CSV): its clock's time stamps (CLOCK_FAST fast, CLOCK_JITTER of a
    sample RMS jitter, from a generator seeded by ``seed``), the reference (m), the encoder (m), the total output
    command and the injected pulse, both in volts (force / FORCE_CONSTANT).  The columns line up as
    write_cosim_records aligns them: at stamp k the encoder's reading at t_k and the output applied from t_k on."""
    t = result.time[:-1]
    pulse = np.concatenate([[0.0], result["disturbance"][:-2]])  # the source's force at t_k-1, applied from t_k
    ts = float(t[1] - t[0])
    rng = np.random.default_rng(seed)
    stamps = 1000.0 + np.arange(t.size) * ts * (1 + CLOCK_FAST) + CLOCK_JITTER * ts * rng.standard_normal(t.size)
    columns = np.column_stack([stamps, result["reference"][:-1], result["position_measured"][1:],
                               result["force_command"][:-1] / FORCE_CONSTANT, pulse / FORCE_CONSTANT])
    np.savetxt(path, columns, delimiter=",", header="stamp,reference,encoder,command_V,pulse_V", comments="",
               fmt="%.17g")
    return path


def run_closed_loop_demo(out: Path, report: Callable[[str], None], command: str = "",
                         final: Path | None = None):
    """An inclined linear_axis with axis_controller: system with test pulses → co-simulation (libcosim) with a
    1 µm encoder and actuator noise → written as a drive's log (volts, its own clock) and imported → closed-loop
    identification → validation on a second log → friction compensation → the drive's gains tuned on the
    identified model and checked on the axis.  Returns the result (whose provenance names its data in ``final``,
    where the files will be, when it is given)."""
    axis_file = out / "axis.toml"
    axis_file.write_text(load_plant("linear_axis").to_toml().replace('name = "linear_axis"', 'name = "inclined_linear_axis"')
                         + DEMO_AXIS_LOAD)
    plant, controller = load_plant(axis_file), load_controller("axis_controller")
    build_fmu(plant, out / "axis.fmu", fmi_version=2, overwrite=True)
    build_controller_fmu(controller, out / "axis-controller.fmu", fmi_version=2, overwrite=True)
    references = reference_trajectories(controller.sample_time)
    references["identify"] = resting_first(references["identify"], REST)
    loop = LoopChannels(reference="reference", disturbance="pulse_V", input_scale=FORCE_CONSTANT,
                        disturbance_scale=FORCE_CONSTANT)
    runs = {}
    for seed, role in enumerate(("identify", "validate")):
        noisy = controller.with_values(force_noise=1.5, noise_seed=seed)  # about 40 dB below the force command
        ssp = write_system(out / "axis.fmu", out / "axis-controller.fmu", references[role],
                           out / f"axis-{role}.ssp", controller=noisy, overwrite=True,
                           disturbance=demo_pulses(references[role][0]))
        result = cosimulate(ssp, engine="libcosim")
        log = write_drive_log(result, out / f"axis-{role}.csv", seed)
        runs[role] = import_records([log], out / f"axis-{role}.h5", time="stamp", input="command_V",
                                    output_column="encoder", kind="position", loop=loop,
                                    run=RunOptions(command=command, overwrite=True))
        error = result["reference"] - result["position"]
        report(f"co-simulated {ssp} on {result.engine} (test pulses of ±{PULSE_FORCE:g} N), logged as the drive "
               f"would into {log} (volts, its own clock) and imported into {out / f'axis-{role}.h5'}: tracking "
               f"error RMS {np.sqrt(np.mean(error ** 2)):.3g} m")
    data = closed_loop_data(runs["identify"], controller)
    est = PSOANNIdentifier(plant, method="pso", seed=0).fit(data)
    provenance = {"data_file": str((final or out) / "axis-identify.h5"), "data_sha256": file_sha256(out / "axis-identify.h5"),
                  "controller_file": str(controller.source), "command": command}
    result = est.result(provenance)
    write_result(out / "axis-result.h5", result, overwrite=True)
    true = plant.parameter_vector()[identified_mask(plant)]
    report("identified inclined_linear_axis in the loop from its log: "
           + ", ".join(f"{n} {v:.6g} (true {t:g})" for n, v, t in zip(est.names_, est.theta_, true))
           + f"; worst relative error {np.max(np.abs(est.theta_ / true - 1)):.2e}")
    for group in result.confounded():  # the gravity force against the friction levels: what the log determines
        report(group.line())
    check = validate(result, runs["validate"], controller=controller)
    report("validated on the second log: " + ", ".join(f"{r.output} fit {r.fit:.3f} %" for r in check.records)
           + ("; residuals independent of the reference" if check.passed else "; verdict FAILED"))
    ssp = write_system(out / "axis.fmu", out / "axis-controller.fmu", references["reversals"],
                       out / "axis-reversals.ssp", overwrite=True)
    (out / "axis-compensation.html").unlink(missing_ok=True)
    tracking = compensate_files(out / "axis-result.h5", ssp, truth=axis_file)
    atomic_write(out / "axis-compensation.html", compensation_page(tracking))
    report(compensation_text(tracking.runs))
    report(f"wrote {out / 'axis-compensation.html'}")
    # the drive's gains tuned on the identified model for the same stroke, checked on the axis (a short swarm)
    tuning = tune_files(out / "axis-result.h5", controller.source, out / "axis-tuned.toml", stroke=0.1,
                        speed=0.05 * np.pi, axis=ssp, overwrite=True, options=TuneOptions(particles=10, iterations=10))
    atomic_write(out / "axis-tune.html", tune_html(tuning, "axis-result.h5", Path(controller.source).name))
    report(tune_text(tuning))
    report(f"wrote {out / 'axis-tuned.toml'} and {out / 'axis-tune.html'}")
    return result


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
