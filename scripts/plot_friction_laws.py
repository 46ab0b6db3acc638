"""The figure of docs/friction.md: each shipped law's steady friction curve F(v), and the presliding loops F(x) of
the laws with a state under a small back-and-forth motion with a smaller reversal inside it.

Everything comes from the package's own expressions (servofmu.model.friction.steady_friction and the laws'
CasADi force and state derivatives), so the figure shows what the FMUs and the simulators compute.

Usage: python scripts/plot_friction_laws.py [OUTPUT.png]   (default docs/figures/friction-laws.png)
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from servofmu.model.friction import steady_friction
from servofmu.model.plant import load_plant
from servofmu.model.symbolic import friction_force
from servofmu.output.plots import figure_axes

ROOT = Path(__file__).resolve().parent.parent
CURVES = ["g1", "stribeck_servo", "stribeck_shaped", "viscous_axis", "lugre_servo", "dahl_servo", "gms_servo"]
LOOPS = ["lugre_servo", "dahl_servo", "gms_servo"]


def presliding_loop(name: str, amplitude: float = 4e-4, minor: float = 1.5e-4):
    """(x, F) of the law of example ``name`` driven by a prescribed position: out to +amplitude, back to −amplitude
    with a reversal of depth ``minor`` on the way, and out again (m, N)."""
    import casadi as ca

    plant = load_plant(ROOT / "fmu_models" / f"{name}.toml")
    v, z = ca.SX.sym("v"), ca.SX.sym("z", len(plant.friction.states()))
    force, dz = friction_force(plant, plant.parameters(), v, [z[i] for i in range(z.numel())])
    f = ca.Function("f", [v, z], [force, ca.vertcat(*dz)])
    corners = [0.0, amplitude, -amplitude + minor, -amplitude + 2 * minor, -amplitude + minor, -amplitude, amplitude]
    speed = 1e-3  # m/s: slow, so that the loop is the presliding's, not the damping's
    xs, fs, z0 = [], [], np.zeros(z.numel())
    for a, b in zip(corners[:-1], corners[1:]):
        vel, duration = np.sign(b - a) * speed, abs(b - a) / speed
        sol = solve_ivp(lambda t, s: np.asarray(f(vel, s)[1]).ravel(), (0.0, duration), z0, method="Radau",
                        rtol=1e-10, atol=1e-14, t_eval=np.linspace(0.0, duration, 200))
        xs.append(a + vel * sol.t)
        fs.append([float(f(vel, s)[0]) for s in sol.y.T])
        z0 = sol.y[:, -1]
    return np.concatenate(xs), np.concatenate(fs)


def main(output: Path) -> None:
    """Write the figure to ``output``."""
    fig, (left, right) = figure_axes(None, 2, (11, 4.2), nrows=1, ncols=2)
    v = np.concatenate([-np.geomspace(0.3, 1e-4, 300), np.geomspace(1e-4, 0.3, 300)])
    for name in CURVES:
        plant = load_plant(ROOT / "fmu_models" / f"{name}.toml")
        left.plot(v, steady_friction(plant, v), label=f"{name} ({plant.friction.model})")
    left.set(xlabel="v (m/s)", ylabel="steady friction F (N)", title="Steady curves (states at rest)")
    left.axhline(0, color="0.8", lw=0.5)
    left.legend(fontsize=7)
    for name in LOOPS:
        x, force = presliding_loop(name)
        right.plot(x * 1e6, force, label=name)
    right.set(xlabel="position x (µm)", ylabel="friction F (N)",
              title="Presliding: ±400 µm at 1 mm/s with an inner reversal")
    right.legend(fontsize=7)
    fig.savefig(output, dpi=110)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "figures" / "friction-laws.png")
