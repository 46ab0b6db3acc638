"""The drive's loop linearised about motion: a discrete-time loop transfer function at the controller's sample
time, its sensitivity peak and its margins.

About a motion (a velocity that does not change sign) the Coulomb and Stribeck friction is a constant force and
the loop is linear; what is left of the friction is its viscous part fv.  The plant from the force to the
velocity is then G_v(s) = G(s)/(1 + fv·G(s)), to the position G_v(s)/s (with a spring of stiffness k on the load:
G_v/(s + k·G_v); a constant load force drops out like the friction, a position ripple is left out).  The drive (controller_law.h) holds the
force between samples (zero-order hold) and applies the command computed from the measurement at t_k from
t_k+delay on, so the plant seen by the controller is the ZOH discretisation

    P(z) = (1 − z⁻¹)·Z{G_v(s)/s²}           (force applied → position at the samples)

and the loop, broken at the force, is

    L(z) = C(z)·(kp_position + F(z))·z^−delay·P(z),     C(z) = kp_velocity + ki_velocity·Ts·z/(z − 1)

with F(z) the velocity estimate from the measured position: (z − 1)/(Ts·z) (the position difference),
(z^N − 1)/(N·Ts·z^N) (its moving average over N samples) or α(z − 1)/(Ts(z − 1 + α)), α = Ts/(τ + Ts) (its
first-order filter).  The encoder's quantiser is left out (a gain of one on average).  S = 1/(1 + L) is the
sensitivity: its peak Ms bounds how much the loop amplifies disturbances and how close L comes to −1
(1/Ms is the distance of the Nyquist curve from −1).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..display import Shown, figure, gain_db, hz, shown_html, shown_repr
from ..errors import UserError
from ..model.controller import ControllerSpec
from ..model.laws.viscous import viscous_levels
from ..model.plant import Plant

__all__ = ["DiscreteLoop", "LoopAnalysis", "discrete_loop", "analyse_loop", "sensitivity_peak", "zoh_position_plant",
           "axis_mass", "frequency_grid", "velocity_estimate"]


def axis_mass(plant: Plant) -> float:
    """The mass the drive moves (kg): 1/K for G(s) = K·∏(s − zᵢ)/∏(s − pᵢ) with one pole more than zeros (a
    mass at high frequency).  Other G are refused: a cascade of position P and velocity PI is tuned for a plant
    that a force accelerates."""
    if len(plant.all_poles()) != len(plant.all_zeros()) + 1:
        raise UserError(f"{plant.source}: G(s) of {plant.name} has {len(plant.all_poles())} poles and "
                        f"{len(plant.all_zeros())} zeros; tuning a drive's cascade needs G from force to velocity "
                        "with one pole more than zeros (a mass at high frequency)")
    k = plant.numerator_gain()
    if not k > 0:
        raise UserError(f"{plant.source}: G(s) of {plant.name} has gain K = {k:g}; a force must accelerate the "
                        "axis (K > 0)")
    return 1.0 / k


@functools.lru_cache(maxsize=256)  # a tuning asks for the same few plants thousands of times
def zoh_position_plant(plant: Plant, sample_time: float) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) in z, highest power first, of the ZOH discretisation of G_v(s)/s (force → position, viscous
    friction fv closed around G, and a spring of the plant's load, −k·(x − x0), around G_v/s), from the matrix
    exponential of its controllable realisation."""
    num, den = plant.transfer_function()
    fv = 0.5 * sum(viscous_levels(plant.friction.values()))  # a direction-dependent one: its mean
    den = np.polyadd(den, fv * num)  # G/(1 + fv·G)
    den = np.polymul(den, [1.0, 0.0])  # the position integrates the velocity
    den = np.polyadd(den, (plant.load.stiffness or 0.0) * num)  # a spring on the load: −k·x fed back
    lead = den[0]
    num, den = num / lead, den / lead
    n = den.size - 1
    a = np.zeros((n, n))  # controllable canonical form
    a[0, :] = -den[1:]
    a[1:, :-1] = np.eye(n - 1)
    b = np.zeros(n)
    b[0] = 1.0
    c = np.zeros(n)
    c[n - num.size:] = num
    block = np.zeros((n + 1, n + 1))
    block[:n, :n], block[:n, n] = a * sample_time, b * sample_time
    from scipy.linalg import expm  # here, so that commands importing the tuning's names start without scipy

    m = expm(block)
    ad, bd = m[:n, :n], m[:n, n]
    den_z = np.real(np.poly(ad))
    # C·(zI − Ad)⁻¹·Bd = det(zI − Ad + Bd·C)/det(zI − Ad) − 1   (the determinant of a rank-one update)
    num_z = np.real(np.poly(ad - np.outer(bd, c))) - den_z
    return num_z[1:], den_z


def velocity_estimate(controller: ControllerSpec) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) in z, highest power first, of the drive's velocity estimate F(z) from the measured position."""
    ts = controller.sample_time
    kind = int(controller["velocity_filter"])
    if kind == 1:
        window = int(controller["filter_window"])
        return np.r_[1.0, np.zeros(window - 1), -1.0], np.r_[window * ts, np.zeros(window)]
    if kind == 2:
        alpha = ts / (controller["filter_time_constant"] + ts)
        return np.array([alpha, -alpha]), np.array([ts, -ts * (1.0 - alpha)])
    return np.array([1.0, -1.0]), np.array([ts, 0.0])


def _add(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The sum of two polynomials (highest power first) of any lengths."""
    n = max(a.size, b.size)
    return np.pad(a, (n - a.size, 0)) + np.pad(b, (n - b.size, 0))


@dataclass(frozen=True)
class DiscreteLoop:
    """L(z) = num(z)/den(z) (highest power first) at the sample time ``sample_time`` (s)."""

    num: np.ndarray
    den: np.ndarray
    sample_time: float

    def response(self, omega: np.ndarray) -> np.ndarray:
        """L(e^{jωTs}) at angular frequencies ``omega`` (rad/s)."""
        z = np.exp(1j * np.asarray(omega, dtype=float) * self.sample_time)
        return np.polyval(self.num, z) / np.polyval(self.den, z)

    def closed_loop_poles(self) -> np.ndarray:
        """The roots of den + num: the closed loop's poles in z."""
        return np.roots(_add(self.den, self.num))

    @property
    def stable(self) -> bool:
        """Every closed-loop pole strictly inside the unit circle."""
        return bool(np.max(np.abs(self.closed_loop_poles())) < 1.0 - 1e-9)


def discrete_loop(plant: Plant, controller: ControllerSpec) -> DiscreteLoop:
    """The loop broken at the force, linearised about motion (see the module's docstring)."""
    ts = controller.sample_time
    p_num, p_den = zoh_position_plant(plant, ts)
    kp, ki = controller["kp_velocity"], controller["ki_velocity"]
    # a P-only velocity loop (ki = 0) has no integrator: C(z) = kp, not kp·(z − 1)/(z − 1), whose common factor left
    # a closed-loop pole at z = 1 and called every such drive unstable (Ms = inf; the EMPS axis's drive)
    c_num, c_den = (np.array([kp + ki * ts, -kp]), np.array([1.0, -1.0])) if ki else (np.array([kp]), np.array([1.0]))
    f_num, f_den = velocity_estimate(controller)
    outer = _add(controller["kp_position"] * f_den, f_num)  # kp_position + F(z)
    delay = np.r_[1.0, np.zeros(int(controller["delay"]))]
    num = np.convolve(np.convolve(c_num, outer), p_num)
    den = np.convolve(np.convolve(np.convolve(c_den, f_den), delay), p_den)
    scale = den[0]
    return DiscreteLoop(num / scale, den / scale, ts)


def frequency_grid(sample_time: float, points: int = 3000) -> np.ndarray:
    """Angular frequencies (rad/s) from 10⁻⁴ of the Nyquist frequency to just below it, logarithmic."""
    nyquist = np.pi / sample_time
    return np.logspace(np.log10(nyquist * 1e-4), np.log10(nyquist * (1 - 1e-6)), points)


@dataclass(frozen=True)
class LoopAnalysis:
    """The linearised loop's robustness figures: the sensitivity peak ``ms`` (inf for an unstable loop) at
    ``ms_frequency`` (rad/s), the gain margin (a factor; inf without a phase crossover) and phase margin (deg),
    the gain crossover (rad/s), whether the closed loop is stable, and L on ``omega``."""

    ms: float
    ms_frequency: float
    gain_margin: float
    phase_margin: float
    crossover: float
    stable: bool
    omega: np.ndarray
    response: np.ndarray

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        figures = (figure("Ms", self.ms, "", ".3g"), figure("at", hz(self.ms_frequency), "Hz", ".3g"),
                   figure("gain margin", gain_db(self.gain_margin), "dB", ".3g"),
                   figure("phase margin", self.phase_margin, "deg", ".3g"),
                   figure("crossover", hz(self.crossover), "Hz", ".3g"))
        return Shown(type(self).__name__, f"{'stable' if self.stable else 'UNSTABLE'} loop, {self.omega.size} "
                     "frequencies", figures,
                     figures + (figure("gain margin (factor)", self.gain_margin, "", ".4g"),))

    def summary(self) -> dict:
        """The figures as plain numbers (the frequencies in Hz)."""
        return {"sensitivity_peak": self.ms, "sensitivity_peak_hz": self.ms_frequency / (2 * np.pi),
                "gain_margin": self.gain_margin, "gain_margin_db": 20 * np.log10(self.gain_margin),
                "phase_margin_deg": self.phase_margin, "crossover_hz": self.crossover / (2 * np.pi),
                "stable": self.stable}


def _refine_peak(loop: DiscreteLoop, omega: np.ndarray, s_mag: np.ndarray) -> tuple[float, float]:
    i = int(np.argmax(s_mag))
    lo, hi = omega[max(i - 1, 0)], omega[min(i + 1, omega.size - 1)]
    fine = np.linspace(lo, hi, 61)
    mag = np.abs(1.0 / (1.0 + loop.response(fine)))
    j = int(np.argmax(mag))
    return float(mag[j]), float(fine[j])


def _crossings(values: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Frequencies where ``values`` changes sign (linear interpolation on the logarithmic grid)."""
    i = np.flatnonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0)
    w = values[i] / (values[i] - values[i + 1])
    return np.exp(np.log(omega[i]) + w * (np.log(omega[i + 1]) - np.log(omega[i])))


def sensitivity_peak(plant: Plant, controller: ControllerSpec, points: int = 600) -> float:
    """Ms alone (inf for an unstable closed loop), on a coarser grid refined about its maximum: what a search
    asks thousands of times."""
    loop = discrete_loop(plant, controller)
    if not loop.stable:
        return float("inf")
    omega = frequency_grid(controller.sample_time, points)
    return _refine_peak(loop, omega, np.abs(1.0 / (1.0 + loop.response(omega))))[0]


def analyse_loop(plant: Plant, controller: ControllerSpec, points: int = 3000) -> LoopAnalysis:
    """Sensitivity peak, gain and phase margins of the drive's loop linearised about motion.

    Parameters
    ----------
    plant : Plant
        The axis: G(s) from force to velocity and its friction (of which the viscous part fv stays).
    controller : ControllerSpec
        The drive: sample time, delay, velocity estimate and gains (servofmu.model.controller).
    points : int
        Frequencies of the logarithmic grid up to the Nyquist frequency (the peak is refined about its maximum).

    Returns
    -------
    LoopAnalysis
        Ms (inf for an unstable closed loop) and where it is, the upper gain margin, the phase margin, the
        crossover, stability and L on the grid; the loop is the discrete L(z) of servofmu.tuning.loop's
        docstring, broken at the force.
    """
    from ..api_checks import check_arguments

    check_arguments(analyse_loop, locals())  # a wrong type: UserError naming it
    loop = discrete_loop(plant, controller)
    omega = frequency_grid(controller.sample_time, points)
    response = loop.response(omega)
    s_mag = np.abs(1.0 / (1.0 + response))
    stable = loop.stable
    ms, ms_frequency = _refine_peak(loop, omega, s_mag) if stable else (np.inf, float("nan"))
    gain_margin, phase_margin, crossover = np.inf, np.nan, np.nan
    # the upper gain margin: where L crosses the negative real axis inside the unit circle
    crossing = _crossings(response.imag, omega)
    at = loop.response(crossing) if crossing.size else np.empty(0, complex)
    inside = (at.real < 0) & (np.abs(at) < 1)
    if np.any(inside):
        gain_margin = float(np.min(1.0 / np.abs(at[inside])))
    gain_cross = _crossings(np.log(np.abs(response)), omega)
    if gain_cross.size:
        crossover = float(gain_cross[-1])
        phase_margin = float(180.0 + np.degrees(np.angle(loop.response(crossover))))
        phase_margin = phase_margin - 360.0 if phase_margin > 180.0 else phase_margin  # in (−180°, 180°]
    return LoopAnalysis(ms, ms_frequency, gain_margin, phase_margin, crossover, stable, omega, response)
