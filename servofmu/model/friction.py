"""The friction force of a plant as a curve: the model's own friction expression (servofmu.model.symbolic)
evaluated at constant velocities, for figures and for the drive's friction feed-forward."""
from __future__ import annotations

import numpy as np

from .plant import Plant

__all__ = ["steady_friction", "viscous_damping"]


def steady_friction(plant: Plant, v: np.ndarray) -> np.ndarray:
    """Friction force F(v) (N) at constant velocities ``v`` (m/s, none zero), from the model's own friction
    expression (servofmu.model.symbolic.friction_force); a law's states (LuGre's, Dahl's) at rest (dz/dt = 0)."""
    import casadi as ca  # only the curve needs CasADi (commands that never draw it start without it)

    from .symbolic import friction_force

    v = np.asarray(v, dtype=float).ravel()
    vel = ca.SX.sym("v")
    z = ca.vertcat(*[ca.SX.sym(state.name) for state in plant.friction.law.states])
    force, dz = friction_force(plant, plant.parameters(), vel, [z[i] for i in range(z.numel())])
    if dz:
        # the laws' state derivatives are linear in their states at a constant v: one Newton step from 0 lands on
        # their root exactly (v ≠ 0)
        dz = ca.vertcat(*dz)
        zero = ca.DM.zeros(z.numel())
        step = ca.substitute(dz, z, zero)
        z_rest = -step / ca.jacobian(dz, z) if z.numel() == 1 else -ca.solve(ca.jacobian(dz, z), step)
        force = ca.substitute(force, z, z_rest)
    curve = ca.Function("friction", [vel], [force]).map(v.size)
    return np.asarray(curve(v[None, :])).ravel()


def viscous_damping(plant: Plant) -> float:
    """The viscous friction a first-order G holds in its pole: G = K/(s − p) is a mass 1/K with damping −p/K
    (viscous friction cannot be told apart from G, so a structure file fixes fv and the pole takes it up).
    0 for other G."""
    if plant.order == 1 and not plant.zeros:
        return float(-plant.all_poles()[0].real / plant.numerator_gain())
    return 0.0
