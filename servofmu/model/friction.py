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
    z = ca.vertcat(*[ca.SX.sym(state.name) for state in plant.friction.states()])
    force, dz = friction_force(plant, plant.parameters(), vel, [z[i] for i in range(z.numel())])
    if dz:  # the states at rest in steady sliding (FrictionLaw.steady_states)
        states = [z[i] for i in range(z.numel())]
        rest = plant.friction.law.steady_states(plant.parameters(), vel, states, dz)
        force = ca.substitute(force, z, ca.vertcat(*rest))
    curve = ca.Function("friction", [vel], [force]).map(v.size)
    return np.asarray(curve(v[None, :])).ravel()


def viscous_damping(plant: Plant) -> float:
    """The viscous friction a first-order G holds in its pole: G = K/(s − p) is a mass 1/K with damping −p/K
    (viscous friction cannot be told apart from G, so a structure file fixes fv and the pole takes it up).
    0 for other G."""
    if plant.order == 1 and not plant.zeros:
        return float(-plant.all_poles()[0].real / plant.numerator_gain())
    return 0.0
