"""The reference rule: the classic tuning of a position/velocity cascade for an axis, at a given sensitivity peak.

The drive's velocity loop sees a mass m (1/K of the identified G) behind a sum of small lags, the equivalent dead
time of the sampled loop

    Tσ = (delay + 1/2)·Ts + T_v

(the computation delay, half a sample for the zero-order hold, and the lag of the velocity estimate: T_v = Ts/2
for the position difference, N·Ts/2 for its moving average over N samples, τ + Ts/2 for its first-order filter).
For an integrating plant with small lags the velocity PI is tuned by the *symmetric optimum* (Kessler): the
crossover at ω_c = 1/(a·Tσ), the integral corner a times below it at 1/(a²·Tσ) and the lags' corner a times above
it, so that the phase is at its maximum at the crossover:

    kp_velocity = m/(a·Tσ)        ki_velocity = kp_velocity/(a²·Tσ)

The closed velocity loop then acts like a first-order lag of about a²·Tσ, and the position P is tuned on it by
the *magnitude optimum* (a gain crossover at half its corner), the usual bandwidth ratio of a cascade:

    kp_position = 1/(2·a²·Tσ)

Feed-forward as a cascade's commissioning sets it: the whole reference velocity (share 1) and the identified
mass.  a = 2 is the textbook symmetric optimum (a phase margin of 37°, a sensitivity peak above 2 once the outer
loop is closed); the one free number ``a`` is raised until the whole cascade, sampled and delayed
(servofmu.tuning.loop), meets the sensitivity peak asked for — the rule at the same robustness as the tuned
gains.
"""
from __future__ import annotations

from ..errors import UserError
from ..model.controller import ControllerSpec
from ..model.plant import Plant
from .loop import axis_mass, sensitivity_peak

__all__ = ["equivalent_dead_time", "rule_gains", "tune_rule", "RULE_A_RANGE"]

RULE_A_RANGE = (1.2, 50.0)  # the symmetric optimum's a: from aggressive (no damping) to very slow


def equivalent_dead_time(controller: ControllerSpec) -> float:
    """Tσ (s): the computation delay, the hold's half sample and the velocity estimate's lag."""
    ts = controller.sample_time
    kind = int(controller["velocity_filter"])
    lag = {0: ts / 2, 1: controller["filter_window"] * ts / 2,
           2: controller["filter_time_constant"] + ts / 2}[kind]
    return (controller["delay"] + 0.5) * ts + lag


def rule_gains(plant: Plant, controller: ControllerSpec, a: float = 2.0) -> ControllerSpec:
    """The controller with the rule's gains for the plant at the symmetric optimum's ``a`` (the module's
    docstring), its feed-forward at the full reference velocity and the plant's mass."""
    mass = axis_mass(plant)
    t_sigma = equivalent_dead_time(controller)
    kp = mass / (a * t_sigma)
    return controller.with_values(kp_velocity=kp, ki_velocity=kp / (a * a * t_sigma),
                                  kp_position=1.0 / (2 * a * a * t_sigma), velocity_feedforward=1.0,
                                  mass_feedforward=mass)


def tune_rule(plant: Plant, controller: ControllerSpec, max_sensitivity: float, corners: tuple[Plant, ...] = (),
              tolerance: float = 1e-4) -> tuple[ControllerSpec, float]:
    """(controller, a): the rule's gains for ``plant`` with the smallest ``a`` whose linearised cascade has a
    sensitivity peak at most ``max_sensitivity`` on ``plant`` and on every plant of ``corners`` (the corners of
    its uncertainty box), by bisection on a (the peak falls as a grows)."""
    def peak(a: float) -> float:
        gains = rule_gains(plant, controller, a)
        return max(sensitivity_peak(p, gains, points=1500) for p in (plant, *corners))

    lo, hi = RULE_A_RANGE
    if peak(hi) > max_sensitivity:
        raise UserError(f"the reference rule reaches no sensitivity peak of {max_sensitivity:g} or less (at "
                        f"a = {hi:g}: {peak(hi):.3g}); the delay and the velocity estimate's lag leave no room")
    if peak(lo) <= max_sensitivity:
        return rule_gains(plant, controller, lo), lo
    while hi - lo > tolerance * lo:
        mid = (lo * hi) ** 0.5
        lo, hi = (lo, mid) if peak(mid) <= max_sensitivity else (mid, hi)
    return rule_gains(plant, controller, hi), hi
