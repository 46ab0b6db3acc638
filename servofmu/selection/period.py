"""Where a ripple candidate starts: the period, amplitude and phase of a position ripple found from the residuals of
the fit it extends, on records (open- or closed-loop).

A ripple A·sin(2π·x/P + φ) is no parameter a swarm finds from a box around a guess: the output error is
many-valleyed in P (an error of P²/travel slips the ripple by a whole period over the travel).  But a force along
the *measured* position x is a known input, and at a fixed P it is linear in (A·cos φ, A·sin φ): injected at the
plant's input (an open-loop record's input, a closed loop's disturbance and the command recorded with it),
sin(2π·x/P) and cos(2π·x/P) give two regressors, the changes of the fit's residuals per newton (finite
differences of the criterion at a probe force: the friction, the loop, the data's kind and weights included), and
every P is scored by the least-squares drop of the residuals on them — a periodogram over position made with the
model's own response.

The grid is uniform in spatial frequency 1/P, COARSE cycles over the travel apart (the drop's peak is about a
cycle over the travel wide), from two travels to RIPPLE_CYCLES cycles over the travel; the best PEAKS are
searched again on a grid REFINE times finer (unless the best coarse one could not pay for a ripple's
parameters, UNPAID: then it is the start).  Each is then moved by Gauss–Newton steps together with the
structure's own parameters (the model's position drifts with its velocity error, and its ripple with it: a gain
3 % off slips a ripple of 5 cm a period over 0.7 m), and the one whose model ripple — along the model's own
positions — fits best is polished on growing shares of the records (continued_start) and is the start, from which the
fit polishes within the prior's narrow period box (identification.prior.PERIOD_SHARE).  Stepped-sine data has no
measured position: its ripple is not searched.
"""
from __future__ import annotations

import copy
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.optimize import least_squares

from ..identification.criterion import RecordData, SineData
from ..identification.prior import identified_mask, identified_names
from ..model.plant import Plant
from ..runtime import available_cores
from .data import criterion_for, first_share

__all__ = ["ripple_start", "continued_start", "travel", "RIPPLE_CYCLES", "HORIZONS", "SEARCHED_PERIOD"]

RIPPLE_CYCLES = 100  # the shortest period searched: the travel over this many cycles
COARSE = 0.5  # the coarse grid's step in spatial frequency: cycles over the travel
REFINE = 8  # the refined grid's step: the coarse one's over this
PEAKS = 3  # coarse peaks searched again
PROBE = 0.05  # the probe force of the ripple's finite differences, times the friction level
DIFFERENCE = 1e-5  # the structure's parameters' relative step of their central differences
ITERATIONS = 3  # Gauss-Newton steps on a peak's ripple and the structure's parameters
RTOL = 1e-7
# The grids' tolerance: a probe's change of the residuals is ~1e-2 of the signal, a simulation's error at 1e-5 a
# thousandth of that, and the grid only ranks periods (the peaks are moved at RTOL)
GRID_RTOL = 1e-5
# A ripple's period is searched: in BIC's penalty it counts as this many parameters.  A frequency is determined to
# O(N^-3/2), not O(N^-1/2): its code length is 3/2·ln N, and the maximum of a search over many periods needs it
# (Djurić 1996, the MAP rule for sinusoids in white noise; on coulomb1_fv seed 0 a searched 3 mN ripple of 26 mm
# lowered −2·ln L by 25.7, more than 3·ln N = 22.8, and validated 21 worse).
SEARCHED_PERIOD = 3
HORIZONS = (0.2, 0.3, 0.4, 0.55, 0.7, 0.85)  # shares of the records the start is polished on in turn (continued_start)
# Where a share's polish stops: a relative change of the parameters or of the cost below this (scipy's default is
# 1e-8).  The shares only bring the start into its valley, and the candidate's polish on all of the data follows:
# on coulomb1_ripple (seeds 3, 6, 16, 17) the same structures were chosen, in 16.7–31.2 s instead of 16.8–51.3 s.
SHARE_TOL = 1e-4
# The coarse grid's best ripple must lower −2·ln L by more than this share of the ripple's BIC penalty to be
# searched further (the fine grid, the joint steps, the shares): one that does not cannot pay for its parameters,
# and its start is the coarse grid's best.  Without a ripple the grid's best drop is the largest of ~200 χ²(2):
# 7–13 on stribeck2_fv and lugre1_fv (seeds 0–5), against half the penalty, 19 for 2000 samples, and the search's
# end was at most 6 above the grid's; with one (coulomb1_ripple seeds 0–5) 1800–2900 on the grid, 640–5800 at
# the end.
UNPAID = 0.5


def _positions(data) -> list[np.ndarray]:
    """Every record's measured position at all its samples (m), in the model's frame: an open-loop record's from
    its first sample (the model starts there at 0, an encoder's zero being arbitrary), a closed loop's as
    measured (the loop follows the reference in its frame)."""
    if isinstance(data, RecordData):
        return [(r.y - r.y[0]) if r.output == "position" else cumulative_trapezoid(r.y, r.time, initial=0.0)
                for r in data.records]
    return [np.asarray(r.position, dtype=float) for r in data.records]


def travel(data) -> float:
    """The widest range of positions one record covers (m); 0 for stepped-sine data."""
    if isinstance(data, SineData):
        return 0.0
    return max(float(np.ptp(x)) if np.all(np.isfinite(x)) else 0.0 for x in _positions(data))


def _with_force(data, forces: list[np.ndarray]):
    """``data`` with a known force added at the plant's input of every record: to an open-loop record's input,
    to a closed-loop record's injected disturbance — and to its recorded command, which a model's loop returns
    with the disturbance in it: the force acts on the plant, as a ripple does, and the command compared is the
    controller's own."""
    if isinstance(data, RecordData):
        return replace(data, records=tuple(replace(r, u=r.u + f) for r, f in zip(data.records, forces)))
    return replace(data, records=tuple(replace(r, disturbance=f if r.disturbance is None else r.disturbance + f,
                                               command=r.command + f) for r, f in zip(data.records, forces)))


class _Forced:
    """The criterion of a structure on ``data`` with a known force along the measured positions added; the
    simulations of several forces run side by side on ``threads`` threads (a force is an input, which the batch
    simulator's rows cannot vary: each is a call of its own, and a call leaves Python while it simulates)."""

    def __init__(self, structure: Plant, data, threads: int | None):
        self.crit, self.data, self.positions = criterion_for(structure, data, threads), data, _positions(data)
        self.probe = PROBE * max(structure.friction.fc_pos, structure.friction.fc_neg, 1e-3)
        self.threads = threads or available_cores()

    def residuals(self, theta: np.ndarray, force=None, rtol: float = RTOL) -> np.ndarray:
        """(N, samples) weighted residuals of the rows of ``theta`` with the force ``force(position)`` added,
        simulated at ``rtol``."""
        crit = self.crit
        if force is not None:  # a criterion of its own: its data holds the force (the others' do not)
            crit = copy.copy(self.crit)
            crit.data = _with_force(self.data, [force(x) for x in self.positions])
        # simulate_errors: the criterion's cache of errors knows the parameters, not the data
        errors = crit.simulate_errors(np.atleast_2d(theta), rtol)
        return np.concatenate([e / s for e, s in zip(errors, self.crit.scales)], axis=1)

    def with_forces(self, theta: np.ndarray, forces: list, rtol: float = RTOL) -> list[np.ndarray]:
        """The residuals of the one candidate ``theta`` with each of ``forces`` added, simulated side by side."""
        with ThreadPoolExecutor(min(self.threads, len(forces))) as pool:
            return list(pool.map(lambda f: self.residuals(theta, f, rtol)[0], forces))

    def ripple_columns(self, theta: np.ndarray, ks, base: np.ndarray, coef=(0.0, 0.0), rtol: float = RTOL,
                       more: tuple = ()) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """For every spatial frequency of ``ks``, (samples, 2): the residuals' change per newton of a force
        sin(2π·k·x), cos(2π·k·x) beside the ripple ``coef`` (its (A·cos φ, A·sin φ)), whose residuals alone at
        ``rtol`` are ``base``; and the residuals with each force of ``more``, simulated with them."""
        forces = [_ripple(k, np.add(coef, d)) for k in ks for d in ((self.probe, 0.0), (0.0, self.probe))]
        out = self.with_forces(theta, forces + list(more), rtol)
        columns = [np.column_stack([(out[2 * i] - base) / self.probe, (out[2 * i + 1] - base) / self.probe])
                   for i in range(len(ks))]
        return columns, out[2 * len(ks):]


def _ripple(k: float, coef):
    """The force A·sin(2π·k·x + φ) of coef = (A·cos φ, A·sin φ), as a function of the position x."""
    return lambda x: coef[0] * np.sin(2 * np.pi * k * x) + coef[1] * np.cos(2 * np.pi * k * x)


def _least_squares(x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float]:
    """The coefficients c minimising |r + x·c|² and the drop of |r|² they give (−inf where x is not finite)."""
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(r))):
        return np.zeros(x.shape[1]), -np.inf
    c, *_ = np.linalg.lstsq(x, -r, rcond=None)
    fitted = x @ c
    return c, -2 * float(r @ fitted) - float(fitted @ fitted)


def _joint(forced: _Forced, theta: np.ndarray, free: np.ndarray, k: float, coef
           ) -> tuple[np.ndarray, float, np.ndarray]:
    """Gauss–Newton steps on the structure's parameters ``free`` and the ripple's spatial frequency k and coef
    together, the ripple a force along the measured positions (the model's own positions drift with its velocity
    error, and the ripple with them: a start found there is in the output error's valley)."""
    theta, coef = theta.copy(), np.asarray(coef, dtype=float)
    r = forced.residuals(theta, _ripple(k, coef))[0]
    for _ in range(ITERATIONS):
        h = DIFFERENCE * np.maximum(np.abs(theta[free]), 1e-3)
        steps = np.repeat(theta[None], 2 * free.size, axis=0)
        steps[np.arange(free.size), free] += h
        steps[free.size + np.arange(free.size), free] -= h
        rr = forced.residuals(steps, _ripple(k, coef))
        jac = ((rr[:free.size] - rr[free.size:]) / (2 * h[:, None])).T
        dk = DIFFERENCE * k
        (columns,), (moved,) = forced.ripple_columns(theta, [k], r, coef, more=(_ripple(k + dk, coef),))
        delta, drop = _least_squares(np.column_stack([jac, (moved - r) / dk, columns]), r)
        if not drop > 0:
            break
        for _ in range(4):  # halved while the step does not lower the residuals
            trial, trial_k, trial_coef = theta.copy(), k + delta[free.size], coef + delta[free.size + 1:]
            trial[free] += delta[:free.size]
            rt = forced.residuals(trial, _ripple(trial_k, trial_coef))[0] if trial_k > 0 else r
            if float(rt @ rt) < float(r @ r):
                theta, k, coef, r = trial, trial_k, trial_coef, rt
                break
            delta = delta / 2
        else:
            break
    return theta, k, coef


def ripple_start(structure: Plant, data, threads: int | None = None) -> Plant:
    """``structure`` — a fit with a ripple term at zero amplitude — with the ripple whose period, amplitude and
    phase lower the criterion on ``data`` the most, and the structure's other parameters moved with it (see the
    module docstring); unchanged for stepped-sine data, records without travel or a ripple of some force."""
    width = travel(data)
    if not width > 0 or structure.load.ripple_amplitude != 0:
        return structure
    forced = _Forced(structure, data, threads)
    names, mask = identified_names(structure), identified_mask(structure)
    theta0 = structure.parameter_vector()[mask]
    r0, r0_grid = forced.residuals(theta0)[0], forced.residuals(theta0, rtol=GRID_RTOL)[0]

    def drops(k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The least-squares drop of the residuals and the ripple (A·cos φ, A·sin φ) at spatial frequencies k."""
        columns, _ = forced.ripple_columns(theta0, k, r0_grid, rtol=GRID_RTOL)
        found = [_least_squares(x, r0_grid) for x in columns]
        return np.array([d for _, d in found]), np.array([c for c, _ in found]).reshape(-1, 2)

    ripple = [names.index(n) for n in ("ripple_amplitude", "ripple_period", "ripple_phase")]

    def with_ripple(theta: np.ndarray, k: float, coef) -> Plant:
        """``structure`` at ``theta`` with the ripple of spatial frequency k and (A·cos φ, A·sin φ) ``coef``."""
        theta, vector = theta.copy(), structure.parameter_vector()
        theta[ripple] = np.hypot(*coef) or forced.probe, 1 / k, np.arctan2(coef[1], coef[0])  # a box needs A > 0
        vector[mask] = theta
        return structure.with_parameters(vector)

    n = r0.size
    penalty = (2 + SEARCHED_PERIOD) * np.log(n)  # what a ripple's three parameters cost in BIC
    step = COARSE / width
    k = np.arange(0.5 / width, RIPPLE_CYCLES / width + step / 2, step)
    drop, coef = drops(k)
    if not np.any(np.isfinite(drop)):
        return structure
    best = int(np.argmax(drop))
    rss_grid = float(r0_grid @ r0_grid)
    if not n * np.log(rss_grid / (rss_grid - drop[best])) > UNPAID * penalty:
        return with_ripple(theta0, k[best], coef[best])
    peaks = []
    for i in np.argsort(-drop):  # the best coarse points at least two steps apart, each searched again
        if np.isfinite(drop[i]) and all(abs(i - j) > 2 for j in peaks):
            peaks.append(i)
        if len(peaks) == PEAKS:
            break
    fine = np.concatenate([k[i] + step * np.arange(-REFINE, REFINE + 1) / REFINE for i in peaks])
    fine = fine[fine > 0]
    fine_drop, fine_coef = drops(fine)
    k, drop, coef = np.concatenate([k, fine]), np.concatenate([drop, fine_drop]), np.concatenate([coef, fine_coef])
    # the best peaks with the structure's parameters moved with the ripple, then judged by the model's own ripple
    free = np.array([i for i in range(len(names)) if i not in ripple])
    tries = [with_ripple(*_joint(forced, theta0, free, k[i], coef[i])) for i in np.argsort(-drop)[:PEAKS]
             if np.isfinite(drop[i])]
    rss = np.sum(forced.residuals(np.array([t.parameter_vector()[mask] for t in tries])) ** 2, axis=1)
    rss[~np.isfinite(rss)] = np.inf
    found = tries[int(np.argmin(rss))]
    # polished on the records' shares only where the ripple pays for its parameters in BIC: one found in the
    # noise cannot be chosen, and the shares' polishes are most of the search's time
    pays = n * np.log(float(r0 @ r0) / np.min(rss)) > penalty
    return continued_start(found, data, threads) if pays else found


def continued_start(structure: Plant, data, threads: int | None = None) -> Plant:
    """``structure`` (a start) polished on the first HORIZONS of every record in turn, each share from the last,
    where that lowers its residuals on all of the records; unchanged for stepped-sine data.

    Where a ripple can trap a slow axis in one of its wells, the output error is rough at the scale of the
    noise's own parameter errors: on g1 with a 0.2 N ripple a polish from the search's start ended at ten times
    the truth's residuals, the truth's valley a tenth of a percent wide in the pole; on the records' first fifth
    the axis is fast and the valley wide, and each longer share starts inside its own (from a first share of
    40 % on, one seed of 20 still ended at six times the truth's residuals)."""
    if isinstance(data, SineData):
        return structure
    crit, mask = criterion_for(structure, data, threads), identified_mask(structure)
    theta = start = structure.parameter_vector()[mask]
    for share in HORIZONS:
        part = criterion_for(structure, first_share(data, share), threads)
        part.scales = crit.scales.copy()  # the weights of all of the data, not of its share's spread
        # scipy's trust-region solver, not the identifier's polish: with that in its place coulomb1_ripple's truth
        # came first in 18 of 20 seeds against 19 (docs/bench-select.md)
        residuals, jacobian = _batched(part)
        try:
            theta = least_squares(residuals, theta, jac=jacobian, x_scale=np.maximum(np.abs(theta), 1e-12),
                                  xtol=SHARE_TOL, ftol=SHARE_TOL).x
        except ValueError:  # the share's residuals not finite at its start: the last share's estimate stands
            break
    rss = np.sum(crit.residuals(np.array([start, theta]), RTOL) ** 2, axis=1)
    if not rss[1] < rss[0]:
        return structure
    vector = structure.parameter_vector()
    vector[mask] = theta
    return structure.with_parameters(vector)


def _batched(crit):
    """The residuals of one candidate on ``crit`` at RTOL, and their Jacobian by the forward differences scipy's
    least_squares makes with ``diff_step=DIFFERENCE`` (the step DIFFERENCE·|θ|, √eps·max(1, |θ|) where that is
    no step), its columns simulated in one batch call — side by side on the simulator's threads — from the
    residuals at θ the solver has just asked for."""
    last = {}

    def residuals(theta: np.ndarray) -> np.ndarray:
        last["theta"], last["r"] = theta.copy(), crit.residuals(theta[None], RTOL)[0]
        return last["r"]

    def jacobian(theta: np.ndarray) -> np.ndarray:
        sign = np.where(theta >= 0, 1.0, -1.0)
        h = DIFFERENCE * sign * np.abs(theta)
        h = np.where((theta + h) - theta == 0, np.sqrt(np.finfo(float).eps) * sign * np.maximum(1.0, np.abs(theta)),
                     h)
        rows = theta + np.diag(h)
        known = "theta" in last and np.array_equal(last["theta"], theta)
        r = crit.residuals(rows if known else np.vstack([rows, theta]), RTOL)
        base = last["r"] if known else r[-1]
        return ((r[:theta.size] - base) / (np.diag(rows) - theta)[:, None]).T

    return residuals, jacobian
