"""The candidate structures of a selection: a friction law, terms added to it (load terms where the plant format
has them, the friction terms its law has keys for), the order of G(s) and whether G has a zero; their names, the
default set, and each one's plant (its structure and first values, from the linear estimate of
servofmu.selection.estimate).

A candidate's name reads ``LAW[:CHOICE…][+TERM…]/ORDER[z]``: ``coulomb/1``, ``stribeck/2z`` (second order with one
zero), ``lugre+offset/3``, ``stribeck+delta/1`` (the Stribeck curve's shape exponent free), ``coulomb+fv_asym/2``
(direction-dependent viscous friction), ``gms:2/1`` (a law's structure choice: two Maxwell-slip elements).
``--candidates`` takes such names, or a law with terms alone (``stribeck``, ``coulomb+offset``), which is tried at
every order of ``--orders``, with and without a zero.

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
from ..model.laws.viscous import VISCOUS_KEYS
from ..model.plant import Plant, PlantError, plant_from_dict
from .estimate import LinearEstimate

__all__ = ["Candidate", "parse_candidates", "default_candidates", "term_candidates", "with_second_stage",
           "candidate_plant", "supported_load_terms", "term_applies", "with_friction_term", "with_viscous_share",
           "without_friction_term", "spring_form", "LOAD_TERMS", "FRICTION_TERMS", "TERMS", "MAX_ORDER",
           "SPRING_ZERO", "VISCOUS_SHARE"]

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
# The friction terms a candidate may add to a law that has their keys, each at the values where it changes nothing:
# the Stribeck curve's shape exponent (2: the Gaussian curve) and direction-dependent viscous friction (fv_pos and
# fv_neg, both the common fv that the string names and that they replace; a fit keeps fv_pos, which G holds with the
# common part, and the data decide fv_neg − fv_pos: servofmu.model.laws.viscous).
FRICTION_TERMS = {
    "delta": {"delta": 2.0},
    "fv_asym": {"fv_pos": "fv", "fv_neg": "fv"},
}
TERMS = {**LOAD_TERMS, **FRICTION_TERMS}
# Direction-dependent viscous friction starts with this share of the damping G holds at DC moved into the friction
# (with_viscous_share): fv_neg then moves either way of the fixed fv_pos on its log-scaled prior, and both stay
# positive for any asymmetry up to that share (at fv_pos = 0, fv_neg could only exceed it).
VISCOUS_SHARE = 0.5


@dataclass(frozen=True, order=True)
class Candidate:
    """One structure to try: ``law`` (a registered friction law's name), ``terms`` added to it (names of TERMS, in
    its order), the ``order`` of G(s) (its number of poles), ``zeros`` (0 or 1) and ``choices``, the law's structure
    choices (FrictionLaw.structure, e.g. the Maxwell-slip elements N; none: the law's starting values)."""

    law: str
    order: int
    zeros: int = 0
    terms: tuple[str, ...] = ()
    choices: tuple[int, ...] = ()

    @property
    def name(self) -> str:
        """``LAW[:CHOICE…][+TERM…]/ORDER[z]``."""
        law = self.law + "".join(f":{c}" for c in self.choices)
        return "+".join((law, *self.terms)) + f"/{self.order}" + ("z" if self.zeros else "")


def _sorted_terms(terms) -> tuple[str, ...]:
    return tuple(sorted(terms, key=list(TERMS).index))


def term_applies(term: str, law: str) -> bool:
    """Whether ``law`` takes ``term``: every load term, a friction term where the law has its keys."""
    if term in LOAD_TERMS:
        return True
    return set(FRICTION_TERMS[term]) <= {k.name for k in (*get_law(law).keys, *VISCOUS_KEYS)}


def with_friction_term(friction: dict, term: str, known: dict | None = None) -> dict:
    """A plant file's friction table with ``term``'s keys added: at their values in ``known`` (another fit's
    friction table) where it has them, else where they change nothing; the keys they replace removed."""
    out, known = dict(friction), known or {}
    for key, value in FRICTION_TERMS[term].items():
        out.setdefault(key, known.get(key, friction.get(value, 0.0) if isinstance(value, str) else value))
    for value in FRICTION_TERMS[term].values():
        if isinstance(value, str):
            out.pop(value, None)
    return out


def with_viscous_share(plant: Plant) -> Plant:
    """``plant`` with direction-dependent viscous friction at zero (fv_pos = fv_neg = 0) given VISCOUS_SHARE of
    the damping its G holds at DC, 1/G(0), as fv_pos = fv_neg = c, and G' = G/(1 − c·G) in its place: the same
    response (G'/(1 + c·G') = G).  Unchanged where it has no such friction, G(0) is not positive and finite, or G'
    would not be stable."""
    values = plant.friction.values()
    if values.get("fv_pos", 1.0) != 0.0 or values.get("fv_neg", 1.0) != 0.0:
        return plant
    num, den = plant.transfer_function()
    if not (den[-1] > 0 and num[-1] > 0):
        return plant
    c = VISCOUS_SHARE * den[-1] / num[-1]
    den = np.polysub(den, c * num)
    poles = np.roots(den)
    if not np.all(poles.real < 0):
        return plant
    gains = {"dc_gain": float(num[-1] / den[-1])} if plant.dc_gain is not None else {}
    return replace(plant, poles=tuple(_distinct(poles, stable=False)), friction=plant.friction.with_values(
        {"fv_pos": float(c), "fv_neg": float(c)}), **gains)


def without_friction_term(friction: dict, term: str) -> dict:
    """A plant file's friction table without ``term``'s keys; a key they replaced comes back at the first one's
    value (fv = fv_pos: the part a fit keeps)."""
    out = dict(friction)
    keys = FRICTION_TERMS[term]
    for key, value in keys.items():
        if isinstance(value, str) and key in out:
            out.setdefault(value, out[key])
    for key in keys:
        out.pop(key, None)
    return out


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


def _choices(text: str, law: str, given: list[str]) -> tuple[int, ...]:
    """The structure choices ``given`` after the law's name (``gms:2``), checked against the law's keys."""
    keys = get_law(law).structure
    if not given:
        return ()
    if not keys:
        raise UserError(f"candidate {text!r}: the {law} law has no structure choice to give after ':'")
    if len(given) != len(keys):
        raise UserError(f"candidate {text!r}: the {law} law takes {len(keys)} structure choice(s) after ':' "
                        f"({', '.join(k.name for k in keys)})")
    out = []
    for key, value in zip(keys, given):
        low, high = key.whole
        if not value.isdigit() or not low <= int(value) <= high:
            raise UserError(f"candidate {text!r}: {key.name} must be a whole number from {low} to {high}")
        out.append(int(value))
    return tuple(out)


def _family(text: str) -> tuple[str, tuple[str, ...], tuple[int, ...]]:
    """(law, terms, structure choices) of ``LAW[:CHOICE…][+TERM…]``, checked."""
    law, *terms = text.split("+")
    law, *given = law.split(":")
    if get_law(law) is None:
        hint = (" (viscous friction is part of every candidate's G: docs/selection.md)" if law == "fv" or
                "fv" in terms else "")
        raise UserError(f"candidate {text!r}: unknown friction law {law!r} (choose {', '.join(law_names())})"
                        + hint)
    supported = supported_load_terms()
    for term in terms:
        if term == "fv":
            raise UserError(f"candidate {text!r}: viscous friction fv is not told apart from G by any data; every "
                            "candidate's G holds it (docs/selection.md; fv_asym adds fv_neg − fv_pos)")
        if term not in TERMS:
            raise UserError(f"candidate {text!r}: unknown term {term!r} (choose {', '.join(TERMS)})")
        if term in LOAD_TERMS and term not in supported:
            raise UserError(f"candidate {text!r}: this plant format has no load term {term!r} yet")
        if not term_applies(term, law):
            raise UserError(f"candidate {text!r}: the {law} law has no {term} (its keys: "
                            f"{', '.join(FRICTION_TERMS[term])})")
    if len(set(terms)) != len(terms):
        raise UserError(f"candidate {text!r}: a term named twice")
    return law, _sorted_terms(terms), _choices(text, law, given)


def _with_orders(law: str, terms: tuple[str, ...], orders: tuple[int, ...], choices=()) -> list[Candidate]:
    return [Candidate(law, n, z, terms, choices) for n in orders for z in ((0, 1) if n >= 2 else (0,))]


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
            law, terms, choices = _family(family)
            zero = order_text.endswith("z")
            digits = order_text[:-1] if zero else order_text
            if not digits.isdigit():
                raise UserError(f"candidate {text!r}: the order after '/' must be a whole number (e.g. {family}/2 or "
                                f"{family}/2z)")
            (order,) = _orders([int(digits)])
            if zero and order < 2:
                raise UserError(f"candidate {text!r}: a zero needs G of order 2 or more (G strictly proper)")
            new = [Candidate(law, order, int(zero), terms, choices)]
        else:
            law, terms, choices = _family(text)
            new = _with_orders(law, terms, orders, choices)
        out += [c for c in new if c not in out]
    if not out:
        raise UserError("no candidates to try")
    return out


def default_candidates(orders=(1, 2, 3)) -> list[Candidate]:
    """Every friction law of the default set (servofmu.model.laws.registry.default_laws) at every order of
    ``orders``, with and without a zero (orders ≥ 2).  Load and friction terms are tried in a second stage, on the
    structure this set ranks first (:func:`term_candidates`)."""
    orders = _orders(orders)
    return [c for law in default_laws() for c in _with_orders(law, (), orders)]


def with_second_stage(names) -> bool:
    """Whether a selection over the candidate names ``names`` has the second stage (springs, the load and friction
    terms on the structure ranked first): the default set (None), or laws named alone — the user chose laws and
    left the structure to the data (``coulomb,stribeck,lugre,dahl``); not where a name gives terms or an order."""
    return names is None or all("/" not in str(n) and "+" not in str(n) for n in names)


def term_candidates(chosen: Candidate) -> list[Candidate]:
    """The second stage of a default selection: ``chosen`` with each term it does not have yet — every load term
    the plant format supports (supported_load_terms) and every friction term its law takes — but the offset: a
    constant force beside friction levels free in each direction is the same force as other levels, in every
    motion and at rest (docs/selection.md), so no data ranks it; it stays a term a user may name."""
    terms = [t for t in supported_load_terms() if t != "offset"] + [t for t in FRICTION_TERMS
                                                                    if term_applies(t, chosen.law)]
    return [replace(chosen, terms=_sorted_terms((*chosen.terms, term)))
            for term in terms if term not in chosen.terms]


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
    law = get_law(candidate.law)
    friction.update(law.start_values(fc_pos, fc_neg, v_rms, mass))
    friction.update({key.name: value for key, value in zip(law.structure, candidate.choices)})
    for term in candidate.terms:
        if term in FRICTION_TERMS:
            friction = with_friction_term(friction, term)
    data = {"name": "candidate", "linear": {"poles": pairs, "zeros": zpairs, "dc_gain": float(dc)},
            "friction": friction}
    load = {k: v for term in candidate.terms if term in LOAD_TERMS for k, v in LOAD_TERMS[term].items()}
    if load:
        data["load"] = load
    return with_viscous_share(plant_from_dict(data, source=f"candidate {candidate.name}"))


def spring_form(candidate: Candidate, plant: Plant) -> tuple[Candidate, Plant] | None:
    """A fitted candidate whose G has a real zero at the origin, read as a spring: G' = s·N/(s·D + k·N) is
    G = N/D with a spring of stiffness k on the load's position (the integral of G's velocity), so G' of order n
    with a zero at 0 is G of order n − 1 without it and k = D'(0)/N(0), D = (D' − k·N)/s.  The candidate with one
    pole and that zero fewer and a ``stiffness`` term, and its plant (x0 = 0, the other values kept); None when no
    real zero lies within SPRING_ZERO of the origin, the candidate has a spring already, or the G left over is not
    a stable one with a positive k."""
    poles, zeros = plant.all_poles(), plant.all_zeros()
    if "stiffness" in candidate.terms or "stiffness" not in supported_load_terms() or not zeros or not poles:
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
    target = replace(candidate, order=candidate.order - 1, zeros=candidate.zeros - 1,
                     terms=_sorted_terms((*candidate.terms, "stiffness")))
    spring = replace(plant, poles=tuple(_distinct(new_poles, stable=False)),
                     zeros=tuple(_distinct(np.roots(num), stable=False)) if num.size > 1 else (),
                     dc_gain=float(num[-1] / den[-1]), gain=None,
                     load=replace(plant.load, stiffness=float(k), x0=0.0))
    return target, spring
