"""A drive's loops as python-control systems: the tuned (or any) controller on an identified axis, for
``control.margin``, ``control.step_response``, ``control.bode_plot`` and the rest of python-control.

The systems are discrete-time at the controller's sample time Ts, the loop servofmu tunes and analyses
(servofmu.tuning.loop): the plant seen by the controller is the zero-order-hold discretisation P(z) of G's
velocity response integrated to the position (the viscous friction closed around G, the Coulomb part a constant
force about motion); the delay of ``delay`` samples is z^−delay exactly (no Padé approximation is needed in discrete
time); the velocity estimate F(z) and the PI velocity controller C(z) are the drive's.  So ``control.margin`` of
:attr:`ControlLoops.loop` gives the gain and phase margins of :func:`servofmu.analyse_loop` (the same L(z)).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..api_checks import check_arguments
from ..errors import UserError
from ..runtime import optional_import
from ..model.controller import ControllerSpec
from ..tuning.loop import axis_mass, discrete_loop, velocity_estimate, zoh_position_plant
from .workflow import check_plant

__all__ = ["ControlLoops", "control_loops"]


@dataclass(frozen=True)
class ControlLoops:
    """The drive's cascade on the axis as python-control TransferFunctions (discrete, ``dt`` = Ts).

    plant: P(z), the force applied → the position at the samples (m/N); velocity_estimate: F(z), position →
    velocity estimate (1/s); velocity_controller: C(z), velocity error → force (N·s/m); delay: z^−delay;
    position_gain: kp of the position loop (1/s); loop: L(z) = C·(kp + F)·z^−delay·P, broken at the force
    (``control.margin(loop)``); sensitivity: 1/(1 + L); position_loop: reference → position (closed);
    velocity_loop: velocity set-point → velocity estimate with the position loop open (closed).
    """

    plant: object
    velocity_estimate: object
    velocity_controller: object
    delay: object
    position_gain: float
    loop: object
    sensitivity: object
    position_loop: object
    velocity_loop: object

    def margins(self) -> dict:
        """The margins of ``loop`` by python-control, as servofmu states them: the upper gain margin (the smallest
        of python-control's gain margins above 1, a factor and dB; inf without one), the phase margin (deg) at the
        last gain crossover and the frequencies (Hz).  ``control.margin`` returns the gain margin nearest 1, which
        for a loop that an integrator makes conditionally stable may be a lower margin (below 1)."""
        import control

        gms, pms, _, wpcs, wgcs = control.stability_margins(self.loop, returnall=True)[:5]
        gms, wpcs, pms, wgcs = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (gms, wpcs, pms, wgcs))
        above = np.flatnonzero(gms > 1)
        i = above[np.argmin(gms[above])] if above.size else None
        j = int(np.argmax(wgcs)) if wgcs.size else None
        return {"gain_margin": float(gms[i]) if i is not None else np.inf,
                "gain_margin_db": float(20 * np.log10(gms[i])) if i is not None else np.inf,
                "phase_margin_deg": float(pms[j]) if j is not None else np.nan,
                "phase_crossover_hz": float(wpcs[i]) / (2 * np.pi) if i is not None else np.nan,
                "crossover_hz": float(wgcs[j]) / (2 * np.pi) if j is not None else np.nan}

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        m = self.margins()
        figures = (figure("gain margin", m["gain_margin_db"], "dB", ".3g"),
                   figure("phase margin", m["phase_margin_deg"], "deg", ".3g"),
                   figure("crossover", m["crossover_hz"], "Hz", ".3g"),
                   figure("sample time", float(self.loop.dt), "s"))
        return Shown("ControlLoops", f"python-control, discrete, order {len(self.loop.poles())}", figures)


def control_loops(axis: object, controller: ControllerSpec | None = None) -> ControlLoops:
    """The drive's loops on an identified axis as python-control systems.

    Parameters
    ----------
    axis : Result, Plant or Tuning
        The identified axis (a Tuning: its model, and its controller when ``controller`` is None).
    controller : ControllerSpec, optional for a Tuning
        The drive: sample time, delay, velocity estimate and gains (a tuning's ``controller``).

    Returns
    -------
    ControlLoops
        P, F, C, the delay, L and the closed loops (the module's docstring); ``control.margin(loops.loop)``
        agrees with :func:`servofmu.analyse_loop`.

    Raises
    ------
    UserError
        Without python-control (``pip install servofmu[control]``), or for an axis a force does not accelerate.
    """
    check_arguments(control_loops, locals())
    control = optional_import("control", "control_loops", "control", package="python-control")
    if hasattr(axis, "runs") and hasattr(axis, "result"):  # a Tuning
        controller = axis.controller if controller is None else controller
        axis = axis.result
    plant = check_plant(axis)
    if not isinstance(controller, ControllerSpec):
        raise UserError(f"controller: give a ControllerSpec, not {type(controller).__name__}")
    axis_mass(plant)  # refuses, in one line, an axis that a force does not accelerate
    ts = controller.sample_time
    num, den = zoh_position_plant(plant, ts)
    p = control.tf(num, den, ts)
    f = control.tf(*velocity_estimate(controller), ts)
    kp, ki = controller["kp_velocity"], controller["ki_velocity"]
    c = control.tf([kp + ki * ts, -kp], [1.0, -1.0], ts) if ki else control.tf([kp], [1.0], ts)
    d = control.tf([1.0], np.r_[1.0, np.zeros(int(controller["delay"]))], ts)
    k = controller["kp_position"]
    forward = c * d * p
    loop = _loop_tf(plant, controller, control)  # = forward·(k + F), its polynomials as servofmu analyses them
    position_loop = control.feedback(k * forward, 1 + f / k) if k else control.tf([0.0], [1.0], ts)
    return ControlLoops(plant=p, velocity_estimate=f, velocity_controller=c, delay=d, position_gain=k, loop=loop,
                        sensitivity=control.feedback(1, loop), position_loop=position_loop,
                        velocity_loop=control.feedback(forward * f, 1))


def _loop_tf(plant, controller: ControllerSpec, control):
    """L(z) as one transfer function, its polynomials those of servofmu.tuning.loop.discrete_loop."""
    loop = discrete_loop(plant, controller)
    return control.tf(loop.num, loop.den, loop.sample_time)
