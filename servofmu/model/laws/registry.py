"""The friction laws servofmu knows, by name: the shipped ones (one module each) and any a program registers.
Every stage finds a plant's law here; none tests a law's name."""
from __future__ import annotations

from .base import FrictionLaw
from .coulomb import COULOMB
from .dahl import DAHL
from .gms import GMS_LAW
from .lugre import LUGRE
from .stribeck import STRIBECK

__all__ = ["register", "unregister", "get_law", "law_names", "default_laws", "contained_laws", "law_key",
           "law_key_names",
           "base_law"]

_LAWS: dict[str, FrictionLaw] = {}


def register(law: FrictionLaw) -> FrictionLaw:
    """Add ``law`` (an instance of a FrictionLaw subclass) under its name; returns it.  A name already taken by
    another law is refused (ValueError: a programming error, not a user's)."""
    if not isinstance(law, FrictionLaw) or not law.name.isidentifier():
        raise ValueError(f"{law!r} is not a FrictionLaw with a name of letters, digits and underscores")
    if law.name in _LAWS and _LAWS[law.name] is not law:
        raise ValueError(f"a friction law named {law.name!r} is registered already")
    if any(key.whole is None for key in law.structure):
        raise ValueError(f"{law.name}: a structure choice needs its range of whole numbers (LawKey.whole)")
    if law.nested is not None and law.nested not in _LAWS:
        raise ValueError(f"{law.name} contains {law.nested!r}, which is not registered")
    _LAWS[law.name] = law
    return law


def unregister(name: str) -> None:
    """Remove the law ``name`` (a program's own; for tests)."""
    _LAWS.pop(name, None)


def get_law(name: str) -> FrictionLaw | None:
    """The law called ``name``, None for an unknown name."""
    return _LAWS.get(name) if isinstance(name, str) else None


def law_names() -> tuple[str, ...]:
    """The names of the registered laws, in the order registered (the shipped ones first)."""
    return tuple(_LAWS)


def default_laws() -> tuple[str, ...]:
    """The laws a default selection tries."""
    return tuple(name for name, law in _LAWS.items() if law.default_candidate)


def base_law() -> FrictionLaw:
    """The simplest law, which every other contains (Coulomb): the friction of a linear part alone at zero levels."""
    return COULOMB


def contained_laws(name: str) -> list[str]:
    """``name`` and the laws it contains (each law's ``nested``, all the way down), e.g. lugre, stribeck, coulomb."""
    laws = [name]
    while _LAWS[laws[-1]].nested:
        laws.append(_LAWS[laws[-1]].nested)
    return laws


def law_key_names() -> set[str]:
    """The names of the registered laws' own keys (not the viscous term's or v_smooth)."""
    return {k.name for law in _LAWS.values() for k in law.keys}


def law_key(name: str):
    """The LawKey ``name`` of the first registered law that has it (units and descriptions), None for none."""
    for law in _LAWS.values():
        key = law.key(name)
        if key is not None:
            return key
    return None


for _law in (COULOMB, STRIBECK, LUGRE, DAHL, GMS_LAW):
    register(_law)
