"""The controller file checked against the log: does its law, fed the log's own reference and encoder, give the
command the drive logged?

A drive computes its command from the reference and the encoder alone, so its log holds the controller's law
sample by sample: u_k = law(r_≤k, y_≤k), logged ``delay`` samples later (plus an injected disturbance after the
output limit).  The law here is a second implementation of controller_law.h in numpy (tests check the two against
each other): :func:`law_command` evaluates it on a whole log at once.  The residual between the logged command and
the file's law — relative to the command's variation, on the samples where the drive does not saturate — says
whether the file is the drive's: a closed-loop fit with the wrong controller is a confident wrong plant.

Where the file's law misses, the log itself says what it fits: the delay and the reference's alignment by
search, the encoder's quantum from the positions, the gains by linear least squares (the law is linear in
kv·kp, kv·vff, kv, ki·kp, ki·vff, ki and the mass feed-forward once the velocity estimate and the delay are
given).  The key whose change explains the log best is named in the refusal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.controller import MAX_DELAY, ControllerSpec

__all__ = ["law_command", "feedforward_force", "LawFit", "law_fit", "LAW_REFUSED", "LAW_SUSPECT", "LAW_WARNED", "EXPLAINS_BETTER"]

# The file's law may leave this share of the command's variation (relative RMS) unexplained before identify
# refuses the log: a drive's log holds its command to its number format, a measured current or a command logged
# through a filter a few per cent — a wrong gain leaves tens of per cent, a wrong delay or alignment a few
LAW_REFUSED, LAW_SUSPECT, LAW_WARNED = 0.2, 0.1, 0.02
# an alternative (another delay, alignment, quantum or gains) that leaves this many times less residual than the
# file's law is what the log says, and a mismatch beyond the log's own noise; one that leaves SUSPECT_BETTER times
# less is worth a warning (a real drive's log is never its law to the last digit: a few per cent are left either way)
EXPLAINS_BETTER, SUSPECT_BETTER = 4.0, 1.5
SEARCH_SAMPLES = 20_000  # the alternatives are searched on this many samples of the log (the check stays O(n))
MAX_SHIFT = 200  # samples: the reference's misalignment searched for, either way, on the first SHIFT_SAMPLES
SHIFT_SAMPLES = 4000
# the encoder quanta tried besides the one the log's positions show (a log may hold the position before the
# encoder, a simulation's): 1, 2 and 5 × 10^e m from 1 nm to 1 mm
QUANTA = tuple(m * 10.0 ** e for e in range(-9, -2) for m in (1, 2, 5))
GAIN_STEPS = 12
VECTOR_RUNS = 32  # free and held runs of the integral computed as whole arrays before going sample by sample  # least-squares steps per gain (the anti-windup's holds make the law piecewise linear in a gain)


def _encoder(position: np.ndarray, q: float) -> np.ndarray:
    return q * np.floor(position / q + 0.5) if q > 0 else position


def _previous(x: np.ndarray, lag: int) -> np.ndarray:
    """x_{k−lag}, with x_0 before the first sample (the law's history starts at its first reading)."""
    return np.concatenate([np.full(min(lag, x.size), x[0]), x[:x.size - lag]]) if lag else x


def _velocity(controller: ControllerSpec, y: np.ndarray) -> np.ndarray:
    """The law's velocity estimate from the encoder readings y."""
    ts, kind = controller.sample_time, int(controller["velocity_filter"])
    if kind == 1:
        window = int(controller["filter_window"])
        return (y - _previous(y, window)) / (window * ts)
    raw = (y - _previous(y, 1)) / ts
    if kind == 2:
        from scipy.signal import lfilter

        a = ts / (controller["filter_time_constant"] + ts)
        return lfilter([a], [1.0, a - 1.0], raw)
    return raw


def _reference_terms(reference: np.ndarray, ts: float) -> tuple[np.ndarray, np.ndarray]:
    v_ref = (reference - _previous(reference, 1)) / ts
    a_ref = (v_ref - _previous(v_ref, 1)) / ts
    a_ref[0] = 0.0
    return v_ref, a_ref


def feedforward_force(controller: ControllerSpec, v: np.ndarray) -> np.ndarray:
    """The friction feed-forward F_ff(v) (N) of controller_law.h at the reference velocities ``v`` (m/s), before
    its share: the Stribeck curve with exponent δ, the tanh sign, the viscous part and its direction-dependent
    part."""
    c = controller
    th = np.tanh(v / c["ff_v_smooth"])
    delta = c["ff_delta"]
    bump = np.exp(-(v / c["ff_vs"]) ** 2) if delta == 2.0 else np.exp(-np.abs(v / c["ff_vs"]) ** delta)
    g_pos = c["ff_fc_pos"] + (c["ff_fs_pos"] - c["ff_fc_pos"]) * bump
    g_neg = c["ff_fc_neg"] + (c["ff_fs_neg"] - c["ff_fc_neg"]) * bump
    f = g_pos * np.maximum(th, 0) + g_neg * np.minimum(th, 0) + c["ff_fv"] * v
    if c["ff_fv_pos"] or c["ff_fv_neg"]:
        f = f + c["ff_fv_pos"] * np.maximum(v, 0) + c["ff_fv_neg"] * np.minimum(v, 0)
    return f


def _integral(step: np.ndarray, f: np.ndarray, limit: float) -> np.ndarray:
    """The law's integral I_k = I_(k−1) + step_k, held at I_(k−1) where |f_k + I_(k−1) + step_k| would pass the
    limit (the anti-windup of controller_law.h), in runs: a free run is a cumulative sum up to its first hold, a
    hold run lasts while the held value keeps the condition — one vectorised pass per run, and after VECTOR_RUNS
    runs (a log that saturates often) the rest sample by sample."""
    out, start, held = np.empty(step.size), 0, 0.0
    for _ in range(VECTOR_RUNS):
        run = held + np.cumsum(step[start:])
        over = np.abs(f[start:] + run) > limit
        stop = int(np.argmax(over)) if over.any() else run.size
        out[start:start + stop] = run[:stop]
        start += stop
        if start == step.size:
            return out
        held = out[start - 1] if start else 0.0
        holding = np.abs(f[start:] + held + step[start:]) > limit
        stop = int(np.argmin(holding)) if not holding.all() else holding.size
        out[start:start + stop] = held
        start += stop
        if start == step.size:
            return out
    held = out[start - 1] if start else 0.0
    rest = []
    for fk, sk in zip(f[start:].tolist(), step[start:].tolist()):
        if abs(fk + held + sk) <= limit:
            held += sk
        rest.append(held)
    out[start:] = rest
    return out


def law_command(controller: ControllerSpec, reference: np.ndarray, position: np.ndarray,
                clip: bool = True) -> np.ndarray:
    """The law's command u_k at every sample (before its delay) from the reference r_k and the position x_k the
    drive read (quantised here by the file's encoder resolution, as the drive does), clipped to the output limit
    (``clip`` False: before the limit)."""
    c, ts = controller, controller.sample_time
    r, y = np.asarray(reference, float), _encoder(np.asarray(position, float), c["encoder_resolution"])
    v_ref, a_ref = _reference_terms(r, ts)
    e = c["kp_position"] * (r - y) + c["velocity_feedforward"] * v_ref - _velocity(c, y)
    f = c["kp_velocity"] * e + c["mass_feedforward"] * a_ref
    if c["friction_feedforward"]:
        f = f + c["friction_feedforward"] * feedforward_force(c, v_ref)
    u = f + _integral(c["ki_velocity"] * ts * e, f, c["force_limit"]) if c["ki_velocity"] else f
    return np.clip(u, -c["force_limit"], c["force_limit"]) if clip else u


def _delayed(u: np.ndarray, delay: int) -> np.ndarray:
    """The command as logged: u_{k−delay}, 0 before the first (the drive's output starts at 0)."""
    return np.concatenate([np.zeros(delay), u[:u.size - delay]])


@dataclass(frozen=True)
class LawFit:
    """How well a controller's law reproduces a log's command: ``residual`` (relative RMS of the logged command
    minus the law's, on the unsaturated samples), and where the file's law misses (residual > LAW_WARNED), the
    alternative that explains the log best: ``key`` (the controller file's key), ``logged`` (its value the log
    fits, as the file would write it), ``given`` (the file's) and that alternative's ``best`` residual."""

    residual: float
    key: str = ""
    logged: str = ""
    given: str = ""
    best: float = np.inf

    def verdict(self) -> str:
        """"refuse": the file's law is not the drive's — it misses by more than LAW_REFUSED, or an alternative
        explains the log EXPLAINS_BETTER times better (beyond LAW_WARNED); "warn": it misses by more than
        LAW_SUSPECT, or an alternative explains the log SUSPECT_BETTER times better; "ok" otherwise."""
        if self.residual <= LAW_WARNED:
            return "ok"
        if self.residual > LAW_REFUSED or self.best * EXPLAINS_BETTER < self.residual:
            return "refuse"
        return "warn" if self.residual > LAW_SUSPECT or self.best * SUSPECT_BETTER < self.residual else "ok"

    def question(self) -> str:
        """What the user should check first."""
        if self.key == "reference":
            return "is the reference column aligned with the encoder's?"
        return "is this the drive's controller file?"

    def describe(self, source: str) -> str:
        """The finding in words: how much of the command the file's law leaves and what the log fits instead."""
        text = f"the law of {source} leaves {100 * self.residual:.3g} % of the logged command unexplained"
        if self.key == "reference":
            text += f"; it fits the reference taken {self.logged} ({100 * self.best:.3g} % left)"
        elif self.key:
            text += (f"; the log's command fits {self.key} = {self.logged} ({100 * self.best:.3g} % left), "
                     f"the file says {self.given}")
        return text


class _Log:
    """A log's arrays as the check uses them: the controller's own command (the disturbance taken off) and the
    samples that show the law (not saturated, past the law's start-up)."""

    def __init__(self, reference: np.ndarray, position: np.ndarray, own: np.ndarray, use: np.ndarray,
                 scale: float):
        self.reference, self.position, self.own, self.use, self.scale = reference, position, own, use, scale

    @classmethod
    def of(cls, controller, reference, position, command, disturbance, fitted) -> "_Log":
        """The log of a record: ``fitted`` (bool per sample, or None) restricts the samples used."""
        own = np.asarray(command, float) - (0.0 if disturbance is None else np.asarray(disturbance, float))
        at_limit = np.abs(own) >= controller["force_limit"] * (1 - 1e-9)
        start = int(controller["delay"] + controller["filter_window"] + 2)
        use = ~at_limit & (np.arange(own.size) >= start)
        use = use & fitted if fitted is not None else use
        return cls(np.asarray(reference, float), np.asarray(position, float), own, use,
                   float(np.std(own[use])) if np.any(use) else 0.0)

    def residual(self, controller: ControllerSpec, shift: int = 0) -> float:
        """The relative RMS of the logged command minus the law's, the reference taken ``shift`` samples later than
        logged (the samples it leaves without one are left out).  With an integrator the law's command is known
        up to the integral's value when the log began (a log need not start at rest): that constant is fitted."""
        r, use = np.roll(self.reference, -shift), self.use.copy()
        if shift > 0:
            r[-shift:], use[-shift:] = r[-shift - 1], False
        elif shift < 0:
            r[:-shift], use[:-shift] = r[-shift], False
        u = _delayed(law_command(controller, r, self.position), int(controller["delay"]))
        error = self.own - u
        if controller["ki_velocity"] and np.any(use):
            error = error - np.mean(error[use])
        return self.rms(error, use)

    def rms(self, error: np.ndarray, use: np.ndarray) -> float:
        """The RMS of ``error`` on the samples ``use`` relative to the command's spread."""
        return float(np.sqrt(np.mean(error[use] ** 2))) / self.scale if self.scale > 0 and np.any(use) else 0.0

    def window(self, samples: int) -> "_Log":
        """The log's first ``samples`` samples (the alternatives' search), scaled as the whole log."""
        if self.own.size <= samples:
            return self
        return _Log(self.reference[:samples], self.position[:samples], self.own[:samples], self.use[:samples],
                    self.scale)


def _quantum(position: np.ndarray) -> float:
    """The encoder's quantum as the log shows it: its smallest position step, where (nearly) every step is a whole
    number of it; 0 where the positions look continuous."""
    steps = np.abs(np.diff(position))
    steps = steps[steps > 0]
    if steps.size == 0:
        return 0.0
    q = float(np.min(steps))
    multiples = steps / q
    return q if np.mean(np.abs(multiples - np.round(multiples)) < 0.01) > 0.9 else 0.0


_GAIN_KEYS = {"kp_velocity": "velocity.kp", "ki_velocity": "velocity.ki", "kp_position": "position.kp",
              "velocity_feedforward": "feedforward.velocity", "mass_feedforward": "feedforward.mass"}


def _gain_step(controller: ControllerSpec, name: str, log: _Log) -> float:
    """One least-squares step on the gain ``name`` from its value in ``controller`` (nan where it does not act)."""
    def logged(c):
        return _delayed(law_command(c, log.reference, log.position, clip=False), int(c["delay"]))[log.use]

    x0 = controller[name]
    h = max(abs(x0), 1.0)
    base = logged(controller)
    miss, slope = log.own[log.use] - base, (logged(controller.with_values(**{name: x0 + h})) - base) / h
    if controller["ki_velocity"] or name == "ki_velocity":  # the integral's value at the log's start (_Log.residual)
        miss, slope = miss - np.mean(miss), slope - np.mean(slope)
    return x0 + float(slope @ miss) / float(slope @ slope) if np.any(slope) else np.nan


def _gain_alternatives(controller: ControllerSpec, log: _Log) -> list[tuple[float, str, str, str]]:
    """Per gain of the file, the value the log fits with the other gains as the file says: the law is linear in
    each gain alone where the integral is not held, so a few least-squares steps from the file's value find it."""
    out = []
    for name, key in _GAIN_KEYS.items():
        fit = controller
        for _ in range(GAIN_STEPS):
            x = _gain_step(fit, name, log)
            if not (np.isfinite(x) and x > 0) or x == fit[name]:
                break
            done = abs(x - fit[name]) <= 1e-9 * x
            fit = fit.with_values(**{name: x})
            if done:
                break
        if fit is not controller:
            out.append((log.residual(fit), key, f"{fit[name]:.6g}", f"{controller[name]:.6g}"))
    return out


def law_fit(controller: ControllerSpec, reference, position, command, disturbance=None, fitted=None) -> LawFit:
    """How well ``controller``'s law reproduces a log's ``command`` (N) from its ``reference`` and ``position``
    (m), ``disturbance`` (N, injected after the limit) taken off; ``fitted`` (bool per sample) restricts the check
    to those samples.  Where the file's law misses (beyond LAW_WARNED), the delay (1–16), the reference's
    alignment (±MAX_SHIFT samples), the encoder quantum (the log's own, or none) and the gains are each tried on
    the log's first SEARCH_SAMPLES samples; the best alternative is kept."""
    log = _Log.of(controller, reference, position, command, disturbance, fitted)
    residual = log.residual(controller)
    if residual <= LAW_WARNED or log.scale == 0:
        return LawFit(residual)
    part = log.window(SEARCH_SAMPLES)
    tried = []  # (residual on the window, key, what the log fits, what the file says)
    d0 = int(controller["delay"])
    for delay in range(1, MAX_DELAY + 1):
        if delay != d0:
            tried.append((part.residual(controller.with_values(delay=delay)), "delay", str(delay), str(d0)))
    short = part.window(SHIFT_SAMPLES)
    shift = min((s for s in range(-MAX_SHIFT, MAX_SHIFT + 1) if s), key=lambda s: short.residual(controller, s))
    tried.append((part.residual(controller, shift), "reference",
                  f"{abs(shift)} samples {'later' if shift > 0 else 'earlier'} than logged", "as logged"))
    q0, own = controller["encoder_resolution"], _quantum(part.position)
    quanta = [(part.residual(controller.with_values(encoder_resolution=q)), q) for q in {own, 0.0, *QUANTA} - {q0}]
    if quanta:
        best_q = min(quanta)
        # the quantum the positions show, unless another explains the command clearly better
        best_q = next((x for x in quanta if x[1] == own and x[0] <= 1.1 * best_q[0]), best_q)
        tried.append((best_q[0], "encoder.resolution", f"{best_q[1]:.6g}", f"{q0:.6g}"))
    tried += _gain_alternatives(controller, part)
    best = min(tried, key=lambda x: x[0])
    # the alternatives are judged against the file's law on the same samples
    scale = residual / part.residual(controller) if part is not log else 1.0
    return LawFit(residual, best[1], best[2], best[3], best[0] * scale)
