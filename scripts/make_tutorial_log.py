"""Write docs/notebook/drive_log.csv, the drive log the tutorial notebook starts from: the axis of
docs/notebook/axis.toml in the loop of docs/notebook/drive.toml, simulated by servofmu's loop simulator, following a
reference of two slow strokes and a fast move, with a random force disturbance (not logged: the log's noise) and the
position read by the 1 µm encoder.  Columns: time (s), reference (m), position (m, as the encoder read it), force (N,
the drive's command).  Run it again only to change the tutorial's data (its seed is fixed)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from servofmu.model.controller import load_controller
from servofmu.model.plant import load_plant
from servofmu.simulation.closed_loop import LoopSimulator

HERE = Path(__file__).resolve().parent.parent / "docs" / "notebook"
DURATION, SEED, NOISE = 3.0, 7, 2.0  # s, the disturbance's seed, its RMS (N)


def reference(t: np.ndarray) -> np.ndarray:
    move = 0.01 * (1 + np.tanh((t - 2.2) / 0.02))
    return 0.02 * (1 - np.cos(2 * np.pi * 0.8 * t)) + 0.004 * np.sin(2 * np.pi * 3.1 * t) ** 2 + move - move[0]


def main() -> None:
    plant, drive = load_plant(HERE / "axis.toml"), load_controller(HERE / "drive.toml")
    t = np.arange(int(round(DURATION / drive.sample_time))) * drive.sample_time
    r = reference(t)
    disturbance = NOISE * np.random.default_rng(SEED).standard_normal(t.size)
    run = LoopSimulator(plant).simulate_loop(plant.parameter_vector()[None], t, r, drive, rtol=1e-10,
                                             disturbance=disturbance)
    quantum = drive["encoder_resolution"]
    position = quantum * np.floor(run.position[0] / quantum + 0.5)
    force = run.command[0] - disturbance  # what the drive commanded (the disturbance is the unknown force)
    np.savetxt(HERE / "drive_log.csv", np.column_stack([t, r, position, force]), delimiter=",",
               header="time,reference,position,force", comments="", fmt="%.10g")


if __name__ == "__main__":
    main()
