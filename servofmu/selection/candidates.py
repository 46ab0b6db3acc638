"""The candidate structures of a selection: a friction law, load terms (where the plant format has them), the
order of G(s) and whether G has a zero; their names, the default set, and each one's plant (its structure and
first values, from the linear estimate of servofmu.selection.estimate).

A candidate's name reads ``LAW[+TERM…]/ORDER[z]``: ``coulomb/1``, ``stribeck/2z`` (second order with one zero),
``lugre+offset/3``.  ``--candidates`` takes such names, or a law with terms alone (``stribeck``,
``coulomb+offset``), which is tried at every order of ``--orders``, with and without a zero.

Viscous friction is no candidate of its own: a viscous force fv·v in the feedback path turns G into G/(1 + fv·G),
which has as many poles and zeros as G, so every input–output record of a plant with viscous friction is matched
exactly by the same friction law with fv = 0 and another G of the same order (servofmu.identification.prior fixes
fv for this reason).  Each candidate's G holds the viscous damping; docs/selection.md shows it on data.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import UserError
from ..model.laws.registry import base_law, default_laws, get_law, law_names
from ..model.plant import Plant, PlantError, plant_from_dict
from .estimate import LinearEstimate

__all__ = ["Candidate", "parse_candidates", "default_candidates", "load_candidates", "candidate_plant",
           "supported_load_terms", "spring_form", "LOAD_TERMS", "MAX_ORDER", "SPRING_ZERO"]

# A real zero this close to the origin (relative to the smallest pole's magnitude) is read as a spring's
# (spring_form): a fit of a plant without one puts its zeros where the response shows them, far from 0.
SPRING_ZERO = 0.01

MAX_ORDER = 6  # G(s) of higher order is no candidate: a structure to choose, not a fit of any response
# The load terms a candidate may add, with the plant-file keys of each and their first values (docs/plant-format.md)
LOAD_TERMS = {
    "offset": {"offset": 0.0},
    "stiffness": {"stiffness": 0.0, "x0": 0.0},
    "ripple": {"ripple_amplitude": 0.0, "ripple_period": 1.0, "ripple_phase": 0.0},
}


@dataclass(frozen=True, order=True)
class Candidate:
    """One structure to try: ``law`` (a registered friction law's name), ``load`` terms (names of LOAD_TERMS), the
    ``order`` of G(s) (its number of poles) and ``zeros`` (0 or 1)."""

    law: str
    order: int
    zeros: int = 0
    load: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        """``LAW[+TERM…]/ORDER[z]``."""
        return "+".join((self.law, *self.load)) + f"/{self.order}" + ("z" if self.zeros else "")


def supported_load_terms() -> tuple[str, ...]:
    """The load terms the plant format accepts in this installation (a plant file's ``[load]`` section)."""
    out = []
    for term, keys in LOAD_TERMS.items():
        probe = {"name": "probe", "linear": {"poles": [[-1.0, 0.0]], "dc_gain": 1.0},
                 "friction": {"model": base_law().name, "fc_pos": 0.1, "fc_neg": 0.1}, "load": dict(keys)}
        try:
            plant_from_dict(probe)
        except PlantError:
            continue
        out.append(term)
    return tuple(out)


def _orders(orders) -> tuple[int, ...]:
    out = []
    for o in orders:
        if isinstance(o, bool) or not isinstance(o, (int, np.integer)) or not 1 <= o <= MAX_ORDER:
            raise UserError(f"order {o!r} of G(s): give whole numbers from 1 to {MAX_ORDER}")
        out.append(int(o))
    if not out:
        raise UserError("no orders of G(s) to try")
    return tuple(sorted(set(out)))


def _family(text: str) -> tuple[str, tuple[str, ...]]:
    """(law, load terms) of ``LAW[+TERM…]``, checked."""
    law, *terms = text.split("+")
    if get_law(law) is None:
        hint = (" (viscous friction is part of every candidate's G: docs/selection.md)" if law == "fv" or
                "fv" in terms else "")
        raise UserError(f"candidate {text!r}: unknown friction law {law!r} (choose {', '.join(law_names())})"
                        + hint)
    supported = supported_load_terms()
    for term in terms:
        if term == "fv":
            raise UserError(f"candidate {text!r}: viscous friction fv is not told apart from G by any data; every "
                            "candidate's G holds it (docs/selection.md)")
        if term not in LOAD_TERMS:
            raise UserError(f"candidate {text!r}: unknown load term {term!r} (choose {', '.join(LOAD_TERMS)})")
        if term not in supported:
            raise UserError(f"candidate {text!r}: this plant format has no load term {term!r} yet")
    if len(set(terms)) != len(terms):
        raise UserError(f"candidate {text!r}: a load term named twice")
    return law, tuple(sorted(terms, key=list(LOAD_TERMS).index))


def _with_orders(law: str, load: tuple[str, ...], orders: tuple[int, ...]) -> list[Candidate]:
    return [Candidate(law, n, z, load) for n in orders for z in ((0, 1) if n >= 2 else (0,))]


def parse_candidates(names, orders=(1, 2, 3)) -> list[Candidate]:
    """The candidates of ``names`` (``LAW[+TERM…]`` tried at every order of ``orders`` with and without a zero, or
    ``LAW[+TERM…]/ORDER[z]`` alone), in the order given, each once; None gives :func:`default_candidates`.

    Raises UserError for an unknown law or load term, a term the plant format lacks, an order outside
    1..MAX_ORDER, a zero with a first-order G, or no candidates."""
    orders = _orders(orders)
    if names is None:
        return default_candidates(orders)
    out: list[Candidate] = []
    for text in names:
        text = str(text).strip()
        if "/" in text:
            family, _, order_text = text.partition("/")
            law, load = _family(family)
            zero = order_text.endswith("z")
            digits = order_text[:-1] if zero else order_text
            if not digits.isdigit():
                raise UserError(f"candidate {text!r}: the order after '/' must be a whole number (e.g. {family}/2 or "
                                f"{family}/2z)")
            (order,) = _orders([int(digits)])
            if zero and order < 2:
                raise UserError(f"candidate {text!r}: a zero needs G of order 2 or more (G strictly proper)")
            new = [Candidate(law, order, int(zero), load)]
        else:
            law, load = _family(text)
            new = _with_orders(law, load, orders)
        out += [c for c in new if c not in out]
    if not out:
        raise UserError("no candidates to try")
    return out


def default_candidates(orders=(1, 2, 3)) -> list[Candidate]:
    """Every friction law of the default set (servofmu.model.laws.registry.default_laws) at every order of
    ``orders``, with and without a zero (orders ≥ 2).  Load terms are tried in a second stage, on the structure
    this set ranks first (:func:`load_candidates`)."""
    orders = _orders(orders)
    return [c for law in default_laws() for c in _with_orders(law, (), orders)]


def load_candidates(chosen: Candidate) -> list[Candidate]:
    """The second stage of a default selection: ``chosen`` with each load term the plant format supports
    (supported_load_terms) that it does not have yet, but the offset: a constant force beside friction levels
    free in each direction is the same force as other levels, in every motion and at rest (docs/selection.md), so
    no data ranks it; it stays a term a user may name."""
    return [Candidate(chosen.law, chosen.order, chosen.zeros, tuple(sorted((*chosen.load, term),
                                                                          key=list(LOAD_TERMS).index)))
            for term in supported_load_terms() if term not in chosen.load and term != "offset"]


def _left(root: complex) -> complex:
    """A root moved into the left half-plane (mirrored), away from 0: the structure's poles must be stable."""
    mag = max(abs(root), 1e-6)
    re = -max(abs(root.real), 1e-3 * mag)
    return complex(re, abs(root.imag))


def _distinct(roots, stable: bool) -> list[complex]:
    """Distinct roots as the plant keeps them: a real one as real, a complex pair once (positive imaginary part)."""
    out = []
    for r in sorted(roots, key=lambda z: (abs(z.imag) > 1e-9 * max(abs(z), 1), -z.real)):
        r = complex(r)
        if abs(r.imag) <= 1e-9 * max(abs(r), 1e-300):
            r = complex(r.real, 0.0)
        elif r.imag < 0:
            continue  # its conjugate stands for the pair
        out.append(_left(r) if stable else r)
    return out


def candidate_plant(candidate: Candidate, estimate: LinearEstimate) -> Plant:
    """The plant a candidate's fit starts from: G from the linear estimate (poles mirrored into the left
    half-plane), its DC gain, the Coulomb levels estimated, and first guesses of the other friction values
    scaled to the data (the law's FrictionLaw.start_values: static friction 1.5·fc, Stribeck velocity a fifth of the
    RMS velocity, LuGre bristles deflecting by a thousandth of the RMS velocity's second at rest, critically damped
    on G's high-frequency mass);
    the load terms start at zero."""
    poles = _distinct(estimate.poles, stable=True)
    zeros = _distinct(estimate.zeros, stable=False)
    pairs = [[r.real, r.imag] for r in poles] + [[r.real, -r.imag] for r in poles if r.imag]
    zpairs = [[r.real, r.imag] for r in zeros] + [[r.real, -r.imag] for r in zeros if r.imag]
    den0 = np.prod([abs(p) ** (2 if p.imag else 1) for p in poles])
    num0 = np.prod([(-z.real if not z.imag else abs(z) ** 2) for z in zeros]) if zeros else 1.0
    dc = estimate.gain * num0 / den0
    if not np.isfinite(dc) or dc == 0:
        dc = 1.0
    level = max(abs(estimate.fc_pos), abs(estimate.fc_neg), 1e-6)
    fc_pos, fc_neg = (max(x, 0.05 * level) for x in (estimate.fc_pos, estimate.fc_neg))
    friction = {"model": candidate.law, "fc_pos": fc_pos, "fc_neg": fc_neg}
    v_rms = max(estimate.v_rms, 1e-9)
    mass = 1.0 / max(abs(estimate.gain), 1e-12) if candidate.order - candidate.zeros == 1 else 0.1
    friction.update(get_law(candidate.law).start_values(fc_pos, fc_neg, v_rms, mass))
    data = {"name": "candidate", "linear": {"poles": pairs, "zeros": zpairs, "dc_gain": float(dc)},
            "friction": friction}
    if candidate.load:
        data["load"] = {k: v for term in candidate.load for k, v in LOAD_TERMS[term].items()}
    return plant_from_dict(data, source=f"candidate {candidate.name}")


def spring_form(candidate: Candidate, plant: Plant) -> tuple[Candidate, Plant] | None:
    """A fitted candidate whose G has a real zero at the origin, read as a spring: G' = s·N/(s·D + k·N) is
    G = N/D with a spring of stiffness k on the load's position (the integral of G's velocity), so G' of order n
    with a zero at 0 is G of order n − 1 without it and k = D'(0)/N(0), D = (D' − k·N)/s.  The candidate with one
    pole and that zero fewer and a ``stiffness`` term, and its plant (x0 = 0, the other values kept); None when no
    real zero lies within SPRING_ZERO of the origin, the candidate has a spring already, or the G left over is not
    a stable one with a positive k."""
    poles, zeros = plant.all_poles(), plant.all_zeros()
    if "stiffness" in candidate.load or "stiffness" not in supported_load_terms() or not zeros or not poles:
        return None
    z0 = min(zeros, key=abs)
    if z0.imag != 0 or abs(z0) > SPRING_ZERO * min(abs(p) for p in poles):
        return None
    rest = list(zeros)
    rest.remove(z0)
    num = plant.numerator_gain() * (np.real(np.poly(rest)) if rest else np.array([1.0]))
    den_full = np.real(np.poly(poles))
    k = den_full[-1] / num[-1]
    den = np.polysub(den_full, k * num)[:-1]  # its constant term is 0 by k's choice
    new_poles = np.roots(den) if den.size > 1 else np.array([])
    if not (np.isfinite(k) and k > 0 and new_poles.size and np.all(new_poles.real < 0)):
        return None
    load = tuple(sorted((*candidate.load, "stiffness"), key=list(LOAD_TERMS).index))
    target = Candidate(candidate.law, candidate.order - 1, candidate.zeros - 1, load)
    spring = replace(plant, poles=tuple(_distinct(new_poles, stable=False)),
                     zeros=tuple(_distinct(np.roots(num), stable=False)) if num.size > 1 else (),
                     dc_gain=float(num[-1] / den[-1]), gain=None,
                     load=replace(plant.load, stiffness=float(k), x0=0.0))
    return target, spring
