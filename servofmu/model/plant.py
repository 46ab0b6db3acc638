"""Plant files (TOML) and the named parameter vector of a plant.

A plant is G(s) (poles, zeros and a gain) plus a friction model.  The plant file
format is documented in docs/plant-format.md.  Everything numerical downstream
sees a plant as a *structure* (which roots are real or complex, which gain key,
which friction model) plus a flat vector of named parameters; this module is
the only place that maps between the two.  It holds the whole format — the
dataclasses, the parameter vector, the value rules and the checks of every key
of every section — so that its rules are written in one place; that is why it
is longer than 500 lines.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from ..display import Shown, figure, parameter_figures, shown_html, shown_repr
from ..errors import MAX_MAGNITUDE, UserError, name_problem
from ..text_digest import checked_text
from .laws.base import FrictionLaw
from .laws.keys import power_of_two
from .laws.registry import get_law, law_key, law_names
from .laws.viscous import check_viscous

__all__ = ["Plant", "Friction", "PlantError", "ParameterRules", "parameter_rules", "state_scale", "bristle_nominal",
           "load_plant", "plant_from_dict",
           "resolve_plant_path", "example_files", "parameter_info", "MAX_ORDER", "gain_unit", "root_names",
           "PARAMETER_INFO", "Load", "LOAD_KEYS", "state_nominals"]

# The highest order of G(s): a servo axis is a mass with a few resonances; beyond, a plant is a mistake.
MAX_ORDER = 12

# Keys of the [load] section, in parameter-vector order: a constant force, a linear spring about x0 and a
# sinusoidal ripple in the position (docs/plant-format.md); only the keys a file gives (or implies) are parameters.
LOAD_KEYS = ("offset", "stiffness", "x0", "ripple_amplitude", "ripple_period", "ripple_phase")

# name -> (unit, description) for every parameter a plant can have but the friction law's (its LawKeys).
PARAMETER_INFO = {
    "dc_gain": ("m/(N.s)", "DC gain of G(s), G(0) (velocity per force)"),
    "gain": ("m/(N.s^(1+r))", "numerator constant of G(s) (leading coefficient of the numerator; r = poles − "
                              "zeros)"),
    "offset": ("N", "constant force on the load, adding to u (e.g. gravity m.g.sin(incline))"),
    "stiffness": ("N/m", "stiffness k of the linear spring force -k.(position - x0) on the load"),
    "x0": ("m", "position at which the spring force is zero"),
    "ripple_amplitude": ("N", "amplitude A of the ripple force A.sin(2.pi.position/ripple_period + ripple_phase)"),
    "ripple_period": ("m", "spatial period of the ripple force"),
    "ripple_phase": ("rad", "phase of the ripple force at position 0"),
    "excitation_amplitude": ("N", "amplitude of the built-in sine excitation added to u"),
    "excitation_frequency": ("Hz", "frequency of the built-in sine excitation"),
}


class PlantError(UserError):
    """A plant file or plant description is invalid; the message names file and key."""


@dataclass(frozen=True)
class Friction:
    """The friction of a plant: its law (``model``, a name in servofmu.model.laws.registry) and values
    (docs/plant-format.md, docs/friction.md): Coulomb and static levels fc±, fs± (N), Stribeck velocity vs (m/s),
    viscous fv (N·s/m), the tanh sign's velocity scale v_smooth (m/s) and LuGre's bristle stiffness sigma0 (N/m)
    and damping sigma1 (N·s/m) as fields; any other key of a law (direction-dependent fv_pos/fv_neg — then fv is
    None —, Stribeck's exponent delta, a registered law's own) in ``extra`` and readable as an attribute too; the
    values a law does not use are None.  ``symmetric``: the levels are the same in both directions (fc_neg =
    fc_pos, fs_neg = fs_pos), and an identification estimates one level each (servofmu.identification.prior)."""

    model: str
    fc_pos: float
    fc_neg: float
    fv: float | None = 0.0
    v_smooth: float = 1e-3
    fs_pos: float | None = None
    fs_neg: float | None = None
    vs: float | None = None
    sigma0: float | None = None
    sigma1: float | None = None
    symmetric: bool = False
    extra: tuple[tuple[str, float], ...] = ()

    def __getattr__(self, name: str):
        # a law's key that is no field: its value in ``extra``, None where this friction does not have it
        if name.startswith("_") or name == "extra":
            raise AttributeError(name)
        for key, value in self.extra:
            if key == name:
                return value
        if law_key(name) is not None:
            return None
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        values = self.values()
        units = [self.law.key(k).unit if get_law(self.model) and self.law.key(k) else "" for k in values]
        structure = "".join(f" {k}={v}" for k, v in self.structure().items()) if get_law(self.model) else ""
        return Shown(type(self).__name__, f"{self.model}{structure}{' symmetric' if self.symmetric else ''}, "
                     f"{len(values)} parameters", parameter_figures(list(values), list(values.values()), units))

    @classmethod
    def of(cls, model: str, values: dict[str, float], symmetric: bool = False) -> "Friction":
        """The friction of law ``model`` with ``values`` (key -> value; keys that are no field go to ``extra``,
        in the order given)."""
        fields = {k: v for k, v in values.items() if k in _FIELDS}
        extra = tuple((k, float(v)) for k, v in values.items() if k not in _FIELDS)
        if "fv_pos" in values:
            fields["fv"] = None
        return cls(model=model, symmetric=symmetric, extra=extra, **fields)

    @property
    def law(self) -> FrictionLaw:
        """The law (servofmu.model.laws.registry); a PlantError for a law no longer registered."""
        law = get_law(self.model)
        if law is None:
            raise PlantError(f"friction model {self.model!r} is not a registered friction law "
                             f"({', '.join(law_names())})")
        return law

    def get(self, key: str) -> float | None:
        """The value of ``key`` (a field or an ``extra`` key), None where this friction has none."""
        return getattr(self, key, None)

    def keys(self) -> tuple[str, ...]:
        """The names of the model's parameters, in parameter-vector order."""
        keys = self.__dict__.get("_keys")
        if keys is None:  # worked out once per friction (every simulation asks for the names)
            keys = self.law.parameter_keys(lambda k: self.get(k) is not None)
            object.__setattr__(self, "_keys", keys)
        return keys

    def values(self) -> dict[str, float]:
        """The model's parameters by name (units as in the class docstring)."""
        return {k: float(self.get(k)) for k in self.keys()}

    def structure(self) -> dict[str, int]:
        """The law's structure choices by name (FrictionLaw.structure: whole numbers, no parameters), e.g. the
        number of Maxwell-slip elements; empty for most laws."""
        return {k.name: int(self.get(k.name)) for k in self.law.structure}

    def states(self) -> tuple:
        """The law's internal states (LawState) for this friction's structure and values (FrictionLaw.states_for)."""
        return self.law.states_for({**self.structure(), **self.values()})

    def with_values(self, values: dict[str, float]) -> "Friction":
        """The same law and form with the values of ``values`` (a subset of :meth:`keys`) changed."""
        fields = {k: v for k, v in values.items() if k in _FIELDS}
        extra = tuple((k, float(values.get(k, v))) for k, v in self.extra)
        out = replace(self, extra=extra, **fields)
        if "_keys" in self.__dict__ and all(v is not None for v in values.values()):  # the same form: the same keys
            object.__setattr__(out, "_keys", self.__dict__["_keys"])
        return out

    def mirrored(self) -> dict[str, str]:
        """For a symmetric friction, each level for v < 0 with the level for v > 0 it equals; otherwise empty."""
        if not self.symmetric:
            return {}
        law = self.law
        return {k: law.key(k).mirror for k in self.keys() if law.key(k).mirror}


_FIELDS = {"fc_pos", "fc_neg", "fv", "v_smooth", "fs_pos", "fs_neg", "vs", "sigma0", "sigma1"}


@dataclass(frozen=True)
class Load:
    """Forces on the load besides friction (a plant file's ``[load]`` section, docs/plant-format.md), adding to
    the input u: ``offset`` (N, signed), the spring −``stiffness``·(position − ``x0``) (N/m, m) and the ripple
    ``ripple_amplitude``·sin(2π·position/``ripple_period`` + ``ripple_phase``) (N, m, rad).  A term the plant
    does not have is None; an empty Load (the default) adds nothing."""

    offset: float | None = None
    stiffness: float | None = None
    x0: float | None = None
    ripple_amplitude: float | None = None
    ripple_period: float | None = None
    ripple_phase: float | None = None

    def keys(self) -> tuple[str, ...]:
        """The names of the load's parameters, in parameter-vector order (LOAD_KEYS order)."""
        return tuple(k for k in LOAD_KEYS if getattr(self, k) is not None)

    def values(self) -> dict[str, float]:
        """The load's parameters by name (units as in the class docstring)."""
        return {k: float(getattr(self, k)) for k in self.keys()}

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        values = self.values()
        return Shown(type(self).__name__, f"{len(values)} parameters" if values else "none",
                     parameter_figures(list(values), list(values.values()), [PARAMETER_INFO[k][0] for k in values]))

    def depends_on_position(self) -> bool:
        """True when the force depends on the position (a spring or a ripple): the position is then a state
        that acts back, not only the integral of v."""
        return self.stiffness is not None or self.ripple_amplitude is not None

    def describe(self) -> str:
        """The load's force in words and numbers, for the model's description ("" without a load)."""
        parts = []
        if self.offset is not None:
            parts.append(f"constant force {self.offset:.6g} N")
        if self.stiffness is not None:
            parts.append(f"spring {self.stiffness:.6g} N/m about x0 = {self.x0:.6g} m")
        if self.ripple_amplitude is not None:
            parts.append(f"ripple {self.ripple_amplitude:.6g} N of period {self.ripple_period:.6g} m "
                         f"(phase {self.ripple_phase:.6g} rad)")
        return "; ".join(parts)


@dataclass(frozen=True)
class Plant:
    """A servo plant: G(s) = K·∏(s − zᵢ)/∏(s − pᵢ) in the forward path, friction in the feedback path.

    Read one with :func:`load_plant`; ``parameter_names()`` and ``parameter_vector()`` give the flat vector
    every numerical stage works with, ``with_parameters`` the plant of another vector.

    Parameters
    ----------
    name : str
        An identifier (letters, digits, underscores); names the FMU.
    poles, zeros : tuple of complex
        *Distinct roots* (rad/s): a real root as a real number, a complex pair once, as the root with positive
        imaginary part.
    friction : Friction
        The friction model and its values.
    load : Load
        Forces on the load besides friction (offset, spring, ripple); none by default.
    fixed : tuple of str
        Parameters an identification keeps at this plant's values (known from elsewhere, e.g. an offset
        m·g·sin θ); the file's ``fixed`` list.
    dc_gain, gain : float, optional
        Exactly one is set: G(0), or the numerator's leading coefficient K.
    source : str
        Where the plant was read from.
    """

    name: str
    poles: tuple[complex, ...]
    zeros: tuple[complex, ...]
    friction: Friction
    dc_gain: float | None = None
    gain: float | None = None
    source: str = field(default="<memory>", compare=False)
    load: Load = field(default_factory=Load)
    fixed: tuple[str, ...] = ()

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        values = self.parameters()
        units = [parameter_info(n, self)[0] for n in values]
        head = f"{self.name!r}: G(s) of order {self.order}, {self.friction.model} friction, {len(values)} parameters"
        figures = parameter_figures(list(values), list(values.values()), units)
        short = tuple(figure(f.label, f.value, f.unit) for f in figures)  # 4 digits in the repr, 6 in the table
        notes = (f"read from {self.source}",) + ((f"fixed: {', '.join(self.fixed)}",) if self.fixed else ())
        return Shown(type(self).__name__, head, short, figures, notes)

    # ---- structure -------------------------------------------------------
    @property
    def order(self) -> int:
        """The order of G(s): the number of poles, a complex pair counting two."""
        return sum(2 if r.imag != 0 else 1 for r in self.poles)

    @property
    def gain_key(self) -> str:
        """The name of the gain parameter: "dc_gain" (G(0), m/(N·s)) or "gain" (K, for an integrating plant)."""
        return "dc_gain" if self.dc_gain is not None else "gain"

    def all_poles(self) -> list[complex]:
        """Every pole (1/s), each complex pair as both conjugates."""
        return _expand(self.poles)

    def all_zeros(self) -> list[complex]:
        """Every zero (1/s), each complex pair as both conjugates."""
        return _expand(self.zeros)

    def numerator_gain(self) -> float:
        """K, the leading coefficient of the numerator."""
        if self.gain is not None:
            return float(self.gain)
        den0 = np.prod([-p for p in self.all_poles()]).real
        num0 = np.prod([-z for z in self.all_zeros()]).real if self.zeros else 1.0
        return float(self.dc_gain * den0 / num0)

    def transfer_function(self) -> tuple[np.ndarray, np.ndarray]:
        """(num, den) polynomial coefficients, highest power first; den is monic."""
        den = np.real(np.poly(self.all_poles())) if self.poles else np.array([1.0])
        num = self.numerator_gain() * (np.real(np.poly(self.all_zeros())) if self.zeros else np.array([1.0]))
        return num, den

    def frequency_response(self, omega: np.ndarray) -> np.ndarray:
        """G(jω) for angular frequencies ``omega`` (rad/s)."""
        num, den = self.transfer_function()
        s = 1j * np.asarray(omega, dtype=float)
        return np.polyval(num, s) / np.polyval(den, s)

    # ---- parameter vector --------------------------------------------------
    def parameter_names(self) -> list[str]:
        """The names of the parameter vector: poles and zeros (pole1, or pole1_re and pole1_im for a pair), the
        gain (:attr:`gain_key`), then the friction's (:meth:`Friction.keys`), then the load's (:meth:`Load.keys`)."""
        return root_names("pole", self.poles) + root_names("zero", self.zeros) + [self.gain_key] + list(
            self.friction.keys()
        ) + list(self.load.keys())

    def parameter_vector(self) -> np.ndarray:
        """The parameter values in :meth:`parameter_names` order."""
        values = []
        for r in (*self.poles, *self.zeros):
            values += [r.real, r.imag] if r.imag != 0 else [r.real]
        values.append(self.dc_gain if self.dc_gain is not None else self.gain)
        values += list(self.friction.values().values())
        values += list(self.load.values().values())
        return np.array(values, dtype=float)

    def parameters(self) -> dict[str, float]:
        """The parameters by name."""
        return dict(zip(self.parameter_names(), self.parameter_vector().tolist()))

    def with_parameters(self, vector: ArrayLike) -> "Plant":
        """The same structure with the parameters of ``vector`` (order of parameter_names); a symmetric friction's
        levels for v < 0 take the values of its levels for v > 0."""
        vector = np.asarray(vector, dtype=float).ravel()
        if vector.size != len(self.parameter_names()):
            raise PlantError(f"{self.name}: expected {len(self.parameter_names())} parameters, got {vector.size}")
        it = iter(vector.tolist())

        def roots(template):
            return tuple(complex(next(it), next(it)) if r.imag != 0 else complex(next(it), 0.0) for r in template)

        poles, zeros = roots(self.poles), roots(self.zeros)
        k = next(it)
        friction = self.friction.with_values({key: next(it) for key in self.friction.keys()})
        friction = friction.with_values({neg: friction.get(pos) for neg, pos in friction.mirrored().items()})
        load = replace(self.load, **{key: next(it) for key in self.load.keys()})
        gains = {"dc_gain": k, "gain": None} if self.dc_gain is not None else {"dc_gain": None, "gain": k}
        return replace(self, poles=poles, zeros=zeros, friction=friction, load=load, **gains)

    def to_toml(self) -> str:
        """The plant file text that ``load_plant`` reads back to this plant."""
        def pairs(roots):
            return "[" + ", ".join(f"[{r.real!r}, {r.imag!r}]" for r in _expand(roots)) + "]"

        lines = [f'name = "{self.name}"']
        if self.fixed:
            lines.append("fixed = [" + ", ".join(f'"{n}"' for n in self.fixed) + "]")
        lines += ["", "[linear]", f"poles = {pairs(self.poles)}", f"zeros = {pairs(self.zeros)}",
                  f"{self.gain_key} = {self.parameters()[self.gain_key]!r}", "", "[friction]",
                  f'model = "{self.friction.model}"'] + (["symmetric = true"] if self.friction.symmetric else [])
        lines += [f"{k} = {v!r}" for k, v in self.friction.structure().items()]
        lines += [f"{k} = {v!r}" for k, v in self.friction.values().items()]
        if self.load.keys():
            lines += ["", "[load]"] + [f"{k} = {v!r}" for k, v in self.load.values().items()]
        return "\n".join(lines) + "\n"


def state_scale(plant: Plant) -> float:
    """c of G's realisation (servofmu.model.symbolic: ``xi_k = x_k / c^(k-1)``): the power of two nearest the
    geometric mean of the nonzero pole magnitudes, 1 without one.  A constant of the model, not a parameter (the
    realisation is exact for any c); rounded, so that plants of one structure whose geometric means round to the
    same power of two share one compiled simulator (the compiled libraries' cache key holds c, not the values)."""
    nominal = [abs(r) for r in plant.all_poles() if abs(r) > 0]
    return power_of_two(float(np.exp(np.mean(np.log(nominal))))) if nominal else 1.0


def state_nominals(friction: Friction) -> tuple[float, ...]:
    """The nominal magnitudes of the friction law's states (their absolute tolerances' scale), powers of two as
    :func:`state_scale` is (FrictionLaw.state_nominals)."""
    return tuple(friction.law.state_nominals({**friction.structure(), **friction.values()}))


def bristle_nominal(friction: Friction) -> float:
    """The nominal magnitude of the friction law's first state (LuGre's bristle deflection at sliding,
    min(fc)/sigma0, to a power of two); 1 for a law without states."""
    nominals = state_nominals(friction)
    return nominals[0] if nominals else 1.0


@dataclass(frozen=True)
class ParameterRules:
    """What values of a plant's parameter vector the plant file format accepts (docs/plant-format.md), as data
    for every checker (the batch simulator vectorised, the FMU in C):

    every value finite; ``low[i] ≤ x[i] ≤ high[i]`` (within ±MAX_MAGNITUDE; ``low_open[i]``: low itself
    excluded); ``x[i] ≠ 0`` where ``nonzero[i]``; ``x[a] ≥ x[b]`` for every pair (a, b) of ``at_least``; and for
    every pair (re, im) of ``not_zero_root`` (a root with dc_gain), not both zero (im is −1 for a real root)."""

    low: tuple[float, ...]
    high: tuple[float, ...]
    low_open: tuple[bool, ...]
    nonzero: tuple[bool, ...]
    at_least: tuple[tuple[int, int], ...]
    not_zero_root: tuple[tuple[int, int], ...]


def parameter_rules(plant: Plant) -> ParameterRules:
    """The value rules of plant_from_dict for ``plant``'s structure."""
    names = plant.parameter_names()
    low, high = [-MAX_MAGNITUDE] * len(names), [MAX_MAGNITUDE] * len(names)
    low_open, nonzero = [False] * len(names), [False] * len(names)
    index = {n: i for i, n in enumerate(names)}
    not_zero_root = []
    for kind, roots in (("pole", plant.poles), ("zero", plant.zeros)):
        for i, root in enumerate(roots, start=1):
            re = index[f"{kind}{i}_re"] if root.imag != 0 else index[f"{kind}{i}"]
            if kind == "pole":
                high[re] = 0.0  # no pole with a positive real part
            if plant.dc_gain is not None:
                not_zero_root.append((re, index[f"{kind}{i}_im"] if root.imag != 0 else -1))
    nonzero[index[plant.gain_key]] = True
    law = plant.friction.law
    for key in plant.friction.keys():
        low[index[key]] = 0.0
        low_open[index[key]] = law.low_open(key)
    for key in ("stiffness", "ripple_amplitude", "ripple_period"):
        if key in index:
            low[index[key]] = 0.0
            low_open[index[key]] = key == "ripple_period"
    at_least = tuple((index[a], index[b]) for a, b in law.at_least() if a in index and b in index)
    return ParameterRules(tuple(low), tuple(high), tuple(low_open), tuple(nonzero), at_least, tuple(not_zero_root))


def root_names(prefix: str, roots) -> list[str]:
    """Parameter names of distinct roots: ``pole1`` for a real one, ``pole1_re``/``pole1_im`` for a pair."""
    names = []
    for i, r in enumerate(roots, start=1):
        names += [f"{prefix}{i}_re", f"{prefix}{i}_im"] if r.imag != 0 else [f"{prefix}{i}"]
    return names


def gain_unit(plant: Plant) -> str:
    """The unit of ``plant``'s numerator constant K in G(s) = K·Π(s − z)/Π(s − p): G is a velocity per force,
    m/(N·s), and s a rate, 1/s, so K is m/(N·s^(1+r)) for r = poles − zeros (r = 1: 1/kg, the inverse mass)."""
    r = len(plant.all_poles()) - len(plant.all_zeros())
    return "m/(N.s)" if r == 0 else f"m/(N.s^{1 + r})"


def parameter_info(name: str, plant: Plant | None = None) -> tuple[str, str]:
    """(unit, description) of a parameter name; with ``plant``, the unit of ``gain`` for its relative degree
    (:func:`gain_unit`).  Units are ASCII ("N.s/m" for N·s/m), as an FMU's unit names."""
    if name == "gain" and plant is not None:
        return gain_unit(plant), PARAMETER_INFO[name][1]
    if name in PARAMETER_INFO:
        return PARAMETER_INFO[name]
    key = plant.friction.law.key(name) if plant is not None else None
    key = key or law_key(name)
    if key is not None:
        return key.unit, key.description
    kind = "pole" if name.startswith("pole") else "zero"
    part = " (real part)" if name.endswith("_re") else " (imaginary part, > 0; the conjugate is implied)" \
        if name.endswith("_im") else ""
    return "rad/s", f"{kind} {name[len(kind):].split('_')[0]} of G(s){part}"


def _expand(roots) -> list[complex]:
    out = []
    for r in roots:
        out += [r, r.conjugate()] if r.imag != 0 else [r]
    return out


# ---------------------------------------------------------------------------
# Reading plant files
# ---------------------------------------------------------------------------
def example_files() -> dict[str, Path]:
    """The example files that ship with servofmu (package ``servofmu.fmu_models``): name -> path."""
    from importlib.resources import as_file, files

    out = {}
    for entry in files("servofmu.fmu_models").iterdir():
        if entry.name.endswith(".toml"):
            with as_file(entry) as path:  # a real file in any installation that is not zipped
                out[entry.name[:-5]] = Path(path)
    return out


def resolve_plant_path(plant: str | Path) -> Path:
    """A path to a plant file, or the name of one of the example plants that ship with servofmu (``g1``...)."""
    path = Path(plant)
    if path.is_file():
        return path
    if path.suffix == "" and str(plant) in example_files():
        return example_files()[str(plant)]
    raise PlantError(f"{plant}: no such plant file (and no example plant of that name; examples: "
                     f"{', '.join(sorted(example_files()))})")


def load_plant(plant: str | Path) -> Plant:
    """Read a plant file.

    Parameters
    ----------
    plant : str or Path
        A plant file (TOML, docs/plant-format.md) or the name of an example plant that ships with servofmu
        (``"g1"``, ``"g2"``, ``"stribeck_servo"``, ``"lugre_servo"``).

    Returns
    -------
    Plant
        The plant: G(s) (poles, zeros, gain) and its friction model.

    Raises
    ------
    PlantError
        (a UserError) when the file is missing or invalid; the message names file and key.

    Examples
    --------
    >>> from servofmu import load_plant
    >>> g1 = load_plant("g1")
    >>> g1.poles, g1.friction.fc_pos
    (((-10+0j),), 0.5)
    """
    from ..api_checks import check_arguments

    check_arguments(load_plant, locals())  # a wrong type: UserError naming it
    path = resolve_plant_path(plant)
    try:
        data = tomllib.loads(checked_text(path, path.read_text()))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PlantError(f"{path}: not a valid TOML file ({exc})") from exc
    if "sample_time" in data and "linear" not in data:  # a mix-up worth naming: the keys would be "unknown"
        raise PlantError(f"{path}: is a controller file, not a plant file (its FMU is built by `servofmu "
                         "controller`, servofmu.control.fmus.build_controller_fmu)")
    return plant_from_dict(data, source=str(path))


def plant_from_dict(data: dict, source: str = "<memory>") -> Plant:
    """A plant from the contents of a plant file (docs/plant-format.md), every key and value checked; ``source``
    names the file in errors (PlantError, a UserError, naming the key)."""
    def fail(key: str, why: str):
        raise PlantError(f"{source}: {key}: {why}")

    _check_keys(data, {"name", "fixed", "linear", "friction", "load"}, "", fail)
    for section in ("linear", "friction"):
        if not isinstance(data.get(section), dict):
            fail(section, "missing section")
    name = data.get("name", Path(source).stem)
    if name_problem(name):
        fail("name", name_problem(name))

    lin = data["linear"]
    _check_keys(lin, {"poles", "zeros", "dc_gain", "gain"}, "linear.", fail)
    poles = _read_roots(lin, "poles", fail, required=True)
    zeros = _read_roots(lin, "zeros", fail, required=False)
    for i, p in enumerate(_expand(poles)):
        if p.real > 0:
            fail("linear.poles", f"pole {p} has a positive real part (unstable plants are not supported)")
    if len(_expand(poles)) > MAX_ORDER:
        fail("linear.poles", f"G(s) of order {len(_expand(poles))}: servofmu models axes up to order {MAX_ORDER} "
             "(a higher order makes every simulation hours long and its identification ill-posed)")
    if len(_expand(zeros)) >= len(_expand(poles)):
        fail("linear.zeros", "G(s) must be strictly proper (fewer zeros than poles)")
    has_dc, has_gain = "dc_gain" in lin, "gain" in lin
    if has_dc == has_gain:
        fail("linear.dc_gain", "give exactly one of `dc_gain` and `gain`")
    key = "linear.dc_gain" if has_dc else "linear.gain"
    k = _number(lin["dc_gain" if has_dc else "gain"], key, fail)
    if k == 0:
        fail(key, "must not be zero")
    if has_dc and any(p == 0 for p in poles):
        fail("linear.dc_gain", "a pole at 0 has no finite DC gain: give `gain` instead")
    if has_dc and any(z == 0 for z in zeros):
        fail("linear.dc_gain", "a zero at 0 makes the DC gain 0: give `gain` instead")

    model, symmetric, values = _read_friction(data["friction"], fail)
    load = _read_load(data["load"], fail) if "load" in data else Load()
    plant = Plant(name=name, poles=poles, zeros=zeros, friction=Friction.of(model, values, symmetric),
                  dc_gain=k if has_dc else None, gain=None if has_dc else k, source=source, load=load)
    return replace(plant, fixed=_read_fixed(data.get("fixed", []), plant, fail))


def _read_friction(fr: dict, fail) -> tuple[str, bool, dict[str, float]]:
    """The [friction] section: (law, symmetric, structure choices then values in parameter-vector order), each key
    checked against the law's (servofmu.model.laws): known, a number (a structure choice: a whole number in its
    range), not negative (positive where the law says so), a default where it has one, a symmetric friction's
    levels for v < 0 equal to those for v > 0, then the law's own rules."""
    model = fr.get("model")
    law = get_law(model)
    if law is None:
        fail("friction.model", f"must be one of {', '.join(law_names())}, not {model!r}")
    _check_keys(fr, {"model", "symmetric", *(k.name for k in law.all_keys())}, "friction.", fail)
    check_viscous(fr, fail)
    symmetric = fr.get("symmetric", False)
    if not isinstance(symmetric, bool):
        fail("friction.symmetric", f"must be true or false, not {symmetric!r}")
    structure = {key.name: _whole(fr, key, model, fail) for key in law.structure}
    keys = law.parameter_keys(lambda k: k in fr)
    values = {}
    for k_ in keys:
        key = law.key(k_)
        if symmetric and key.mirror and k_ not in fr:
            continue  # the level of v > 0, set below
        if k_ not in fr:
            if key.default is not None:
                values[k_] = key.default
                continue
            fail(f"friction.{k_}", f"missing (required by the {model} model)")
        values[k_] = _number(fr[k_], f"friction.{k_}", fail)
        if values[k_] < 0:
            fail(f"friction.{k_}", "must not be negative")
    for neg in keys:
        pos = law.key(neg).mirror
        if symmetric and pos and pos in values:
            if neg in values and values[neg] != values[pos]:
                fail(f"friction.{neg}", f"a symmetric friction has {neg} = {pos} ({values[pos]!r}), not "
                                        f"{values[neg]!r}: give one of them")
            values[neg] = values[pos]
    values = {k_: values[k_] for k_ in keys}  # in parameter-vector order
    for k_ in keys:
        if law.key(k_).positive and values[k_] <= 0:
            fail(f"friction.{k_}", "must be positive")
    law.check({**structure, **values}, fail)
    return model, symmetric, {**structure, **values}


def _whole(fr: dict, key, model: str, fail) -> int:
    """A structure choice of the [friction] section (LawKey.whole): a whole number within the key's range."""
    low, high = key.whole
    if key.name not in fr:
        if key.default is not None:
            return int(key.default)
        fail(f"friction.{key.name}", f"missing (required by the {model} model: a whole number from {low} to {high})")
    value = fr[key.name]
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        fail(f"friction.{key.name}", f"must be a whole number from {low} to {high}, not {value!r}")
    return value


def _read_fixed(names, plant: Plant, fail) -> tuple[str, ...]:
    """The ``fixed`` list: names of the plant's parameters, each once; not a symmetric friction's level for v < 0
    (it follows the level for v > 0)."""
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        fail("fixed", f"must be a list of parameter names, not {names!r}")
    for n in names:
        if n not in plant.parameter_names():
            fail("fixed", f"{n!r} is not a parameter of this plant ({', '.join(plant.parameter_names())})")
        if n in plant.friction.mirrored():
            fail("fixed", f"{n} follows {plant.friction.mirrored()[n]} in a symmetric friction: fix that instead")
    if len(set(names)) < len(names):
        fail("fixed", "names a parameter twice")
    return tuple(names)


def _read_load(table, fail) -> Load:
    """The [load] section: each key a finite number; a spring's x0 defaults to 0, a ripple needs its period."""
    if not isinstance(table, dict):
        fail("load", "must be a table (a [load] section)")
    _check_keys(table, set(LOAD_KEYS), "load.", fail)
    values = {k: _number(table[k], f"load.{k}", fail) for k in LOAD_KEYS if k in table}
    for key in ("stiffness", "ripple_amplitude"):
        if values.get(key, 0.0) < 0:
            fail(f"load.{key}", "must not be negative")
    if "x0" in values and "stiffness" not in values:
        fail("load.x0", "is the spring's rest position: give `stiffness` too")
    if "stiffness" in values:
        values.setdefault("x0", 0.0)
    for key in ("ripple_period", "ripple_phase"):
        if key in values and "ripple_amplitude" not in values:
            fail(f"load.{key}", "belongs to a ripple: give `ripple_amplitude` too")
    if "ripple_amplitude" in values:
        if "ripple_period" not in values:
            fail("load.ripple_period", "missing (a ripple needs its period)")
        if values["ripple_period"] <= 0:
            fail("load.ripple_period", "must be positive")
        values.setdefault("ripple_phase", 0.0)
    return Load(**values)


def _check_keys(table: dict, allowed: set, prefix: str, fail):
    for key in table:
        if key not in allowed:
            fail(f"{prefix}{key}", "unknown key")


def _number(value, key, fail) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(key, f"must be a finite number, not {value!r}")
    if abs(value) > MAX_MAGNITUDE:
        fail(key, f"must be within ±{MAX_MAGNITUDE:g}, not {value!r}")
    return float(value)


def _read_roots(table, key, fail, required) -> tuple[complex, ...]:
    if key not in table:
        if required:
            fail(f"linear.{key}", "missing")
        return ()
    raw = table[key]
    if not isinstance(raw, list):
        fail(f"linear.{key}", "must be a list of [re, im] pairs")
    roots = []
    for item in raw:
        if not (isinstance(item, list) and len(item) == 2):
            fail(f"linear.{key}", f"{item!r} is not a [re, im] pair")
        roots.append(complex(_number(item[0], f"linear.{key}", fail), _number(item[1], f"linear.{key}", fail)))
    if required and not roots:
        fail(f"linear.{key}", "G(s) needs at least one pole")
    # Pair up conjugates; keep each pair once as its upper-half-plane member.
    distinct, unmatched = [], list(roots)
    while unmatched:
        r = unmatched.pop(0)
        if r.imag == 0:
            distinct.append(r)
            continue
        conj = r.conjugate()
        if conj not in unmatched:
            fail(f"linear.{key}", f"complex root {r} comes without its conjugate {conj}")
        unmatched.remove(conj)
        distinct.append(r if r.imag > 0 else conj)
    return tuple(distinct)
