"""The figure of docs/friction.md#gms: the presliding loop of the generalised Maxwell-slip example (N = 4) under a
prescribed position, out to +1.5 mm, back to −1.5 mm with a 0.5 mm reversal at x = 0.6 mm on the way, against the
same path without the inner reversal (the outer loop) and against four Dahl elements of the same stiffnesses.

Everything comes from the package's own expressions (the law's CasADi force and state derivatives), so the figure
shows what the FMUs and the simulators compute.  Prints how far each model's force is from its outer branch where
the inner loop closes.

Usage: python scripts/plot_gms_presliding.py [OUTPUT.png]   (default docs/figures/gms-presliding.png)
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

from servofmu.model.plant import load_plant
from servofmu.model.symbolic import friction_force
from servofmu.output.plots import figure_axes

ROOT = Path(__file__).resolve().parent.parent
OUTER, TURN, INNER, SPEED = 1.5e-3, 0.6e-3, 0.5e-3, 1e-3  # m, m, m, m/s
MINOR = [0.0, OUTER, TURN, TURN + INNER, TURN, -OUTER]
MAJOR = [0.0, OUTER, -OUTER]


def law_function(plant):
    """(F, dz/dt) of ``plant``'s friction law as a CasADi function of (v, z), without the viscous term."""
    import casadi as ca

    n = len(plant.friction.states())
    v, z = ca.SX.sym("v"), ca.SX.sym("z", n)
    force, dz = friction_force(plant, {**plant.parameters(), "fv": 0.0}, v, [z[i] for i in range(n)])
    return ca.Function("f", [v, z], [force, ca.vertcat(*dz)]), n


def loop(function, n, corners, points=300):
    """(x, F) per segment of the prescribed path through ``corners`` at SPEED."""
    xs, fs, z = [], [], np.zeros(n)
    for a, b in zip(corners[:-1], corners[1:]):
        vel, duration = np.sign(b - a) * SPEED, abs(b - a) / SPEED
        sol = solve_ivp(lambda _, s: np.asarray(function(vel, s)[1]).ravel(), (0.0, duration), z, method="Radau",
                        rtol=1e-10, atol=1e-14, t_eval=np.linspace(0.0, duration, points))
        xs.append(a + vel * sol.t)
        fs.append(np.asarray(function(vel, sol.y)[0]).ravel())
        z = sol.y[:, -1]
    return xs, fs


def dahl_elements(plant):
    """The same stiffnesses and levels as Dahl elements, dz_i/dt = v − |v|·k_i·z_i/(s(v)/N): a function like
    :func:`law_function`'s, from the gms law's own force at attraction 1 replaced by the two-sided Dahl term."""
    import casadi as ca

    from servofmu.model.laws.gms import element_stiffness
    from servofmu.model.laws.stribeck import stribeck_level

    n = len(plant.friction.states())
    par = plant.parameters()
    v, z = ca.SX.sym("v"), ca.SX.sym("z", n)
    level = ca.if_else(v >= 0, stribeck_level(par, "pos", v), stribeck_level(par, "neg", v)) / n
    forces = [k * z[i] for i, k in enumerate(element_stiffness(par["sigma0"], n))]
    dz = [v - ca.fabs(v) * f / level for f in forces]
    return ca.Function("dahl", [v, z], [sum(forces[1:], forces[0]), ca.vertcat(*dz)]), n


def closure(function, n) -> float:
    """|F − F_outer| (N) where the inner loop closes (x back at TURN, moving down)."""
    x, f = loop(function, n, MINOR)
    x_outer, f_outer = loop(function, n, MAJOR, points=1200)
    return abs(f[4][0] - float(np.interp(-x[4][0], -x_outer[1], f_outer[1])))


def main(output: Path) -> None:
    """Write the figure to ``output`` and print the closure errors."""
    plant = load_plant(ROOT / "fmu_models" / "gms_servo.toml")
    fig, (left, right) = figure_axes(None, 2, (11, 4.2), nrows=1, ncols=2)
    for axis, (label, (function, n)) in zip((left, right), (("GMS, N = 4 (gms_servo)", law_function(plant)),
                                                           ("4 Dahl elements, same k_i", dahl_elements(plant)))):
        x, f = loop(function, n, MAJOR)
        axis.plot(np.concatenate(x) * 1e3, np.concatenate(f), color="0.6", lw=2.5, label="outer loop")
        x, f = loop(function, n, MINOR)
        axis.plot(np.concatenate(x) * 1e3, np.concatenate(f), color="C3", lw=1.0,
                  label="with a 0.5 mm reversal at 0.6 mm")
        axis.set(xlabel="position x (mm)", ylabel="friction F (N)", title=label)
        axis.legend(fontsize=7)
        print(f"{label}: {closure(function, n):.4g} N off the outer branch where the inner loop closes")
    fig.savefig(output, dpi=110)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "figures" / "gms-presliding.png")
