"""What a friction law is: its parameter keys (units, defaults, value rules), its internal states, its force and
state derivatives as CasADi expressions, and what the later stages need of it (starts, cost, feed-forward, result
rows).  One subclass instance per law, kept in the registry (servofmu.model.laws.registry); docs/friction.md has
the equations of the shipped laws."""
from __future__ import annotations

from typing import Callable

from .keys import SMOOTHING_KEY, LawKey, LawState
from .viscous import VISCOUS_KEYS, viscous_keys

__all__ = ["FrictionLaw"]


class FrictionLaw:
    """A friction law: subclass it, set the class attributes, write :meth:`force`, and register an instance
    (servofmu.model.laws.registry.register).  Every stage reads the law from there.

    Attributes
    ----------
    name : str
        The plant file's ``friction.model`` value and the selection's candidate prefix.
    title : str
        A short description (CLI help, docs).
    keys : tuple of LawKey
        The law's own keys in parameter-vector order; the viscous term (``fv``, or ``fv_pos``/``fv_neg``) and,
        where ``smoothing``, ``v_smooth`` follow them in every law.
    states : tuple of LawState
        Internal states (after G's realisation and the position) of a law whose states are the same for every
        friction; a law whose states depend on a structure choice writes :meth:`states_for` instead.
    structure : tuple of LawKey
        Structure choices (whole numbers, ``LawKey.whole``), e.g. a number of elements: plant-file keys that are
        no parameters; they may set the states (:meth:`states_for`).
    smoothing : bool
        The law's sign(v) is a tanh of scale ``v_smooth`` (a parameter); a law with presliding states has none.
    nested : str or None
        The law this one contains as a limit (the selection's nested starts and confounding checks).
    cost : int
        How much longer its fits take than the simplest law's (the selection sends costly fits first).
    default_candidate : bool
        Tried by a default selection.
    fixed : tuple of str
        Keys a fit keeps at the structure's values (besides fv and v_smooth).
    equations : str
        The law in ASCII, for the FMU's documentation.
    """

    name: str = ""
    title: str = ""
    keys: tuple[LawKey, ...] = ()
    states: tuple[LawState, ...] = ()
    structure: tuple[LawKey, ...] = ()
    smoothing: bool = True
    nested: str | None = None
    cost: int = 0
    default_candidate: bool = False
    fixed: tuple[str, ...] = ()
    equations: str = ""

    # ---- keys ---------------------------------------------------------------
    def all_keys(self) -> tuple[LawKey, ...]:
        """Every key a plant file of this law may give: its own, the viscous ones and v_smooth (where it has it)."""
        return self.structure + self.keys + VISCOUS_KEYS + ((SMOOTHING_KEY,) if self.smoothing else ())

    def key(self, name: str) -> LawKey | None:
        """The key ``name`` of this law, None where it has none."""
        return next((k for k in self.all_keys() if k.name == name), None)

    def parameter_keys(self, has: Callable[[str], bool]) -> tuple[str, ...]:
        """The parameter names of a friction of this law in vector order; ``has(name)``: the friction gives the
        optional key ``name`` (or, for the viscous term, its direction-dependent form)."""
        own = tuple(k.name for k in self.keys if not k.optional or has(k.name))
        return own + viscous_keys(has) + (("v_smooth",) if self.smoothing else ())

    def low_open(self, name: str) -> bool:
        """The key's lower bound 0 is excluded (the value rules of the plant format, checked by every simulator)."""
        key = self.key(name)
        return bool(key and key.positive)

    def at_least(self) -> tuple[tuple[str, str], ...]:
        """Pairs (a, b) of keys with a ≥ b in every valid friction."""
        return ()

    def check(self, values: dict[str, float], fail) -> None:
        """Rules across keys beyond each key's own (``fail(key, why)`` raises); ``values`` in vector order."""
        for a, b in self.at_least():
            if a in values and values[a] < values[b]:
                fail(f"friction.{a}", f"must not be below {b}")

    # ---- equations ------------------------------------------------------------
    def states_for(self, values: dict[str, float]) -> tuple[LawState, ...]:
        """The states of a friction of this law with ``values`` (its structure choices and parameters by name):
        :attr:`states` unless the law's states depend on a structure choice."""
        return self.states

    def force(self, par: dict, v, states: list) -> tuple:
        """(F, [d state/dt …]) as CasADi expressions of the velocity ``v`` (m/s), the law's ``states`` and the
        parameters ``par`` (name -> expression), without the viscous term (added by the model); ``states`` are
        the symbols of :meth:`states_for`."""
        raise NotImplementedError(f"friction law {self.name} has no force")

    def steady_states(self, par: dict, v, states: list, derivatives: list) -> list:
        """The states at rest in steady sliding at the velocity ``v`` (≠ 0) as CasADi expressions (``par`` as for
        :meth:`force`; ``derivatives`` :meth:`force`'s, of the symbols ``states``): one Newton step from 0, the
        root where the derivatives are linear in the states (LuGre's, Dahl's); a law whose are not writes its own."""
        import casadi as ca

        z, dz = ca.vertcat(*states), ca.vertcat(*derivatives)
        step = ca.substitute(dz, z, ca.DM.zeros(z.numel()))
        rest = -step / ca.jacobian(dz, z) if z.numel() == 1 else -ca.solve(ca.jacobian(dz, z), step)
        return [rest[i] for i in range(z.numel())]

    def state_nominals(self, values: dict[str, float]) -> tuple[float, ...]:
        """The nominal magnitudes of the law's states (absolute tolerances' scale), powers of two: plants of one
        structure whose values round alike share a compiled simulator; ``values`` as for :meth:`states_for`."""
        return tuple(1.0 for _ in self.states_for(values))

    # ---- what later stages need --------------------------------------------------
    def start_values(self, fc_pos: float, fc_neg: float, v_rms: float, mass: float) -> dict[str, float]:
        """First guesses of the law's keys beyond the Coulomb levels (a selection's candidate, before its fit),
        from the estimated levels (N), the RMS velocity of the data (m/s) and G's high-frequency mass (kg)."""
        return {}

    def levels_from(self, source: dict[str, float], mean_level: Callable[[float], float | None]) -> dict:
        """This law's values (without the viscous term) from a fit of a law that contains it (``source``: its
        values): the keys they share; ``mean_level(sign)`` is the richer law's steady friction averaged over the
        data's speeds in one direction (None where there are none)."""
        return {k.name: source[k.name] for k in self.keys if k.name in source}

    def feedforward(self, values: dict[str, float], v_smooth: float) -> dict[str, float]:
        """The drive's friction feed-forward (servofmu.model.controller): Coulomb and static levels, Stribeck
        velocity, its shape exponent δ (2 where the law has none) and the tanh sign's scale (the law's own, else
        ``v_smooth``, the controller file's) — the controller's curve is fc± + (fs± − fc±)·exp(−|v/vs|^δ)."""
        return {"fc_pos": values["fc_pos"], "fc_neg": values["fc_neg"],
                "fs_pos": values.get("fs_pos", values["fc_pos"]), "fs_neg": values.get("fs_neg", values["fc_neg"]),
                "vs": values.get("vs") or 1.0, "delta": values.get("delta", 2.0),
                "v_smooth": values["v_smooth"] if self.smoothing else v_smooth}

    def rows(self, values: dict[str, float]) -> list[tuple[str, str]]:
        """(label, value) rows of the results table for the law's structure choices and keys beyond the Coulomb
        levels."""
        return [(k.label or k.name, f"{values[k.name]:.6g}") for k in self.structure + self.keys
                if k.name in values and not k.name.startswith("fc_")]
