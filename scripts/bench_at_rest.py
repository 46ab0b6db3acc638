"""What the smoothed friction does at rest under a load's force, against a true stick–slip solution.

Writes docs/bench-at-rest.md: for G = 10/(s + 10) (a 0.1 kg mass with 1 N·s/m damping) with Coulomb friction
fc± = 0.5/0.4 N and v_smooth = 1e-3 m/s,
- the creep under a constant offset with u = 0 (batch simulator, 4 s) beside v_smooth·atanh(|F|/Fs);
- the largest velocity and position errors against tests/stick_slip.py's Karnopp integration (which holds the axis
  exactly) in three runs: at rest, a ramp to breakaway, a sine against a spring that sticks at every reversal;
- LuGre (lugre_servo's friction) under offsets below the static level: where the axis settles, and whether it
  still moves between 5 s and 20 s.
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from stick_slip import stick_slip  # noqa: E402

from servofmu.model.plant import plant_from_dict  # noqa: E402
from servofmu.simulation.batch import BatchSimulator  # noqa: E402

COULOMB = {"model": "coulomb", "fc_pos": 0.5, "fc_neg": 0.4}
LUGRE = {"model": "lugre", "fc_pos": 0.3, "fc_neg": 0.25, "fs_pos": 0.4, "fs_neg": 0.3, "vs": 0.05, "sigma0": 1000.0,
         "sigma1": 5.0}
M, C, V_SMOOTH = 0.1, 1.0, 1e-3


def plant(load, friction=COULOMB):
    return plant_from_dict({"name": "bench", "linear": {"poles": [[-10.0, 0.0]], "dc_gain": 1.0},
                            "friction": friction, "load": load})


def simulate(p, t, u, hold="zoh"):
    r = BatchSimulator(p).simulate_record(p.parameter_vector()[None], t, u, hold=hold, rtol=1e-10)
    return r.v[0], r.position[0]


def creep_rows():
    t = np.linspace(0.0, 4.0, 401)
    rows = []
    for offset in (0.3, -0.3, 0.45, -0.36, 0.49):
        v, x = simulate(plant({"offset": offset}), t, np.zeros_like(t))
        bound = V_SMOOTH * np.arctanh(abs(offset) / (0.5 if offset > 0 else 0.4))
        rows.append(f"| {offset:+.2f} | {v[-1]:.4e} | {bound:.4e} | {v[-1] / np.sign(offset) / bound:.4f} | "
                    f"{x[-1] * 1e3:+.2f} mm |")
    return rows


def karnopp_rows():
    runs = []
    t = np.linspace(0.0, 3.0, 301)
    runs.append(("at rest: offset 0.3 N, u = 0, 3 s", t, lambda s: 0.0 * s, {"offset": 0.3}, "zoh"))
    t = np.linspace(0.0, 4.0, 4001)
    runs.append(("breakaway: offset 0.3 N, u = 0.1 N/s·t, 4 s", t, lambda s: 0.1 * s, {"offset": 0.3}, "foh"))
    t = np.linspace(0.0, 4.0, 401)
    runs.append(("stick-slip on a spring: 1.2 N sine at 0.5 Hz, k = 20 N/m, offset 0.1 N, 4 s", t,
                 lambda s: 1.2 * np.sin(np.pi * s), {"offset": 0.1, "stiffness": 20.0, "x0": 0.0}, "foh"))
    rows = []
    for label, t, u, load, hold in runs:
        def force(x, load=load):
            return load.get("offset", 0.0) - load.get("stiffness", 0.0) * x
        x_ref, v_ref = stick_slip(M, C, 0.5, 0.4, u, force, t)
        v, x = simulate(plant(load), t, u(t), hold)
        stuck = np.mean(v_ref == 0.0)
        rows.append(f"| {label} | {stuck:.0%} | {np.abs(v - v_ref).max() / V_SMOOTH:.2f} | "
                    f"{np.abs(x - x_ref).max() * 1e3:.3f} mm | {np.ptp(x_ref) * 1e3:.1f} mm |")
    return rows


def lugre_rows():
    t = np.linspace(0.0, 20.0, 2001)
    rows = []
    for offset in (0.15, 0.28, 0.35):
        v, x = simulate(plant({"offset": offset}, LUGRE), t, np.zeros_like(t))
        rows.append(f"| {offset:.2f} | {x[-1] * 1e3:.3f} mm | {abs(x[-1] - x[500]):.1e} m | {abs(v[-1]):.1e} m/s |")
    return rows


def main():
    lines = ["# The axis at rest under a load's force", "",
             "Made by `scripts/bench_at_rest.py` ([model.md](model.md#at-rest) states the tolerance). G = 10/(s + 10), "
             "Coulomb friction fc± = 0.5/0.4 N, v_smooth = 1e-3 m/s; the batch simulator at rtol 1e-10.", "",
             "## Creep of the smoothed friction (u = 0, 4 s)", "",
             "| offset (N) | v at 4 s (m/s) | v_smooth·atanh(\\|F\\|/Fs) | ratio | drift |", "|---|---|---|---|---|",
             *creep_rows(), "",
             "## Against a true stick–slip solution (tests/stick_slip.py)", "",
             "| run | time stuck | max \\|v − v_ref\\| / v_smooth | max \\|x − x_ref\\| | stroke |",
             "|---|---|---|---|---|", *karnopp_rows(), "",
             "## LuGre (lugre_servo's friction, u = 0, 20 s)", "",
             "| offset (N) | position at 20 s | change 5 s → 20 s | \\|v\\| at 20 s |", "|---|---|---|---|",
             *lugre_rows(), ""]
    (ROOT / "docs" / "bench-at-rest.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
