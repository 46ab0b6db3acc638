"""Controller files (TOML): the cascade found in servo drives, as a parameter vector for its C law.

The law itself is C (simulation/batch_c/controller_law.h), compiled into the controller FMU and into the batch simulator's
closed loop; :data:`PARAMETERS` is the single source of the parameter vector's layout, units, defaults and limits
(generated into controller_params.h).  The file format is documented in docs/controller.md.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..display import Shown, figure, shown_html, shown_repr
from ..errors import UserError, name_problem
from ..text_digest import checked_text
from .friction import viscous_damping
from .laws.viscous import viscous_levels
from .plant import Plant

__all__ = ["Parameter", "PARAMETERS", "OPTIONAL_PARAMETERS", "FILTERS", "ControllerSpec", "ControllerError",
           "load_controller", "controller_from_dict", "controller_toml", "friction_feedforward", "params_header",
           "missing_parameter", "values_from", "parameter_set"]


@dataclass(frozen=True)
class Parameter:
    """One entry of the controller's parameter vector: name (the FMI variable), unit, meaning, default and the
    accepted range [low, high] (``low_open``: low itself excluded; ``integer``: whole numbers only)."""

    name: str
    unit: str
    description: str
    default: float
    low: float = 0.0
    high: float = math.inf
    low_open: bool = False
    integer: bool = False

    def error(self, value: float) -> str | None:
        """Why ``value`` is refused, or None."""
        if not math.isfinite(value):
            return "not a finite number"
        if value < self.low or (self.low_open and value == self.low) or value > self.high:
            low = "(" if self.low_open else "["
            return f"must be in {low}{self.low:g}, {self.high:g}]"
        if self.integer and value != round(value):
            return "must be a whole number"
        return None


MAX_WINDOW, MAX_DELAY = 64, 16  # CTRL_MAX_WINDOW, CTRL_MAX_DELAY of controller_law.h
FILTERS = ("none", "moving-average", "first-order")  # velocity_filter 0, 1, 2
PARAMETERS = (
    # from the fastest current loops (1 µs) to a slow positioner (1 s): beyond, a run is hours of steps or none
    Parameter("sample_time", "s", "controller sample time Ts", 1e-3, 1e-6, 1.0),
    Parameter("delay", "1", "samples from a measurement to the force computed from it (1: the next sample)", 1.0,
              1.0, MAX_DELAY, integer=True),
    Parameter("kp_position", "1/s", "position loop gain: velocity demand per position error", 0.0),
    Parameter("kp_velocity", "N.s/m", "velocity loop proportional gain", 1.0, low_open=True),
    Parameter("ki_velocity", "N/m", "velocity loop integral gain (0: P only)", 0.0),
    Parameter("velocity_filter", "1", "velocity estimate: 0 position difference, 1 its moving average, 2 its "
              "first-order filter", 0.0, 0.0, 2.0, integer=True),
    Parameter("filter_window", "1", "samples of the moving average", 1.0, 1.0, MAX_WINDOW, integer=True),
    Parameter("filter_time_constant", "s", "time constant of the first-order filter", 1e-3, low_open=True),
    Parameter("velocity_feedforward", "1", "share of the reference velocity added to the velocity demand", 0.0),
    Parameter("mass_feedforward", "kg", "force feed-forward per reference acceleration", 0.0),
    Parameter("force_limit", "N", "saturation of the force command", 1e9, low_open=True),
    Parameter("friction_feedforward", "1", "share of the friction feed-forward F_ff(v_ref) added (0: off)", 0.0),
    Parameter("ff_fc_pos", "N", "feed-forward Coulomb friction for v > 0", 0.0),
    Parameter("ff_fc_neg", "N", "feed-forward Coulomb friction for v < 0 (magnitude)", 0.0),
    Parameter("ff_fs_pos", "N", "feed-forward static friction for v > 0", 0.0),
    Parameter("ff_fs_neg", "N", "feed-forward static friction for v < 0 (magnitude)", 0.0),
    Parameter("ff_vs", "m/s", "feed-forward Stribeck velocity", 1.0, low_open=True),
    Parameter("ff_fv", "N.s/m", "feed-forward viscous friction", 0.0),
    Parameter("ff_v_smooth", "m/s", "velocity scale of the feed-forward's tanh sign", 1e-3, low_open=True),
    Parameter("encoder_resolution", "m", "encoder quantum of the measured position (0: exact)", 0.0),
    Parameter("force_noise", "N", "standard deviation of the actuator noise added to the applied force", 0.0),
    Parameter("noise_seed", "1", "seed of the actuator noise", 0.0, 0.0, 2.0**53, integer=True),
    # (after the others: the vector's earlier indices, and the FMU's value references, stay as they were)
    Parameter("ff_delta", "1", "shape exponent of the feed-forward's Stribeck curve exp(-|v/vs|^delta)", 2.0,
              low_open=True),
    Parameter("ff_fv_pos", "N.s/m", "feed-forward viscous friction added for v > 0 (direction-dependent part)", 0.0),
    Parameter("ff_fv_neg", "N.s/m", "feed-forward viscous friction added for v < 0 (direction-dependent part)", 0.0),
)
INDEX = {p.name: i for i, p in enumerate(PARAMETERS)}


class ControllerError(UserError):
    """A controller file or controller description is invalid; the message names file and key."""


@dataclass(frozen=True)
class ControllerSpec:
    """A drive's cascade controller: its name and its parameter vector (in :data:`PARAMETERS` order)."""

    name: str
    values: tuple[float, ...]
    source: str = "<memory>"

    def __getitem__(self, name: str) -> float:
        return self.values[INDEX[name]]

    __repr__, _repr_html_ = shown_repr, shown_html

    def _shown(self) -> Shown:
        key = ("kp_position", "kp_velocity", "ki_velocity", "sample_time", "delay")
        units = {p.name: "" if p.unit == "1" else p.unit for p in PARAMETERS} | {"delay": "samples"}
        figures = tuple(figure(n, self[n], units[n]) for n in key)
        if self["friction_feedforward"]:
            figures += (figure("friction_feedforward", self["friction_feedforward"]),)
        table = tuple(figure(p.name, v, units[p.name], ".6g") for p, v in zip(PARAMETERS, self.values))
        return Shown(type(self).__name__, f"{self.name!r} ({len(self.values)} parameters)", figures, table)

    def vector(self) -> np.ndarray:
        """The parameter values as an array, in :data:`PARAMETERS` order."""
        return np.array(self.values, dtype=float)

    def with_values(self, **changes: float) -> "ControllerSpec":
        """The same controller with some parameters changed (checked)."""
        values = list(self.values)
        for name, value in changes.items():
            if name not in INDEX:
                raise ControllerError(f"{self.source}: no controller parameter {name!r}")
            why = PARAMETERS[INDEX[name]].error(float(value))
            if why:
                raise ControllerError(f"{self.source}: {name} = {value!r}: {why}")
            values[INDEX[name]] = float(value)
        return ControllerSpec(self.name, tuple(values), self.source)

    @property
    def sample_time(self) -> float:
        """The controller's sample time Ts (s)."""
        return self["sample_time"]


# The file's keys: section -> key -> parameter name (or a handler for the velocity filter's name)
_FILE_KEYS = {
    "": {"sample_time": "sample_time", "delay": "delay"},
    "position": {"kp": "kp_position"},
    "velocity": {"kp": "kp_velocity", "ki": "ki_velocity", "filter": "velocity_filter", "window": "filter_window",
                 "time_constant": "filter_time_constant"},
    "feedforward": {"velocity": "velocity_feedforward", "mass": "mass_feedforward"},
    "output": {"limit": "force_limit"},
    "encoder": {"resolution": "encoder_resolution"},
    "compensation": {"v_smooth": "ff_v_smooth", "share": "friction_feedforward", "fc_pos": "ff_fc_pos",
                     "fc_neg": "ff_fc_neg", "fs_pos": "ff_fs_pos", "fs_neg": "ff_fs_neg", "vs": "ff_vs",
                     "fv": "ff_fv", "delta": "ff_delta", "fv_pos": "ff_fv_pos", "fv_neg": "ff_fv_neg"},
}
_REQUIRED = ("sample_time", "kp_velocity")
# Parameters a file, an FMU or an axis's parameter set need not hold (added later): written only where they differ
# from their default, so that a controller without them reads, runs and is written exactly as before they existed
OPTIONAL_PARAMETERS = ("ff_delta", "ff_fv_pos", "ff_fv_neg")
_PAIRED = (("fv_pos", "fv_neg"), ("fv_neg", "fv_pos"))  # [compensation] keys given together


def controller_from_dict(data: dict, source: str = "<memory>") -> ControllerSpec:
    """A controller from the contents of a controller file (docs/controller.md)."""
    def fail(key: str, why: str):
        raise ControllerError(f"{source}: {key}: {why}")

    values = {p.name: p.default for p in PARAMETERS}
    given = set()
    name = data.get("name", Path(source).stem if source != "<memory>" else "controller")
    if name_problem(name):
        fail("name", name_problem(name))
    for key, value in data.items():
        if key == "name":
            continue
        if isinstance(value, dict):
            if key not in _FILE_KEYS or key == "":
                fail(key, "unknown section")
            items = [(f"{key}.{k}", _FILE_KEYS[key].get(k), v) for k, v in value.items()]
        else:
            items = [(key, _FILE_KEYS[""].get(key), value)]
        for label, parameter, v in items:
            if parameter is None:
                fail(label, "unknown key")
            if parameter == "velocity_filter":
                if v not in FILTERS:
                    fail(label, f"must be one of {', '.join(FILTERS)}, not {v!r}")
                v = float(FILTERS.index(v))
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                fail(label, f"must be a number, not {v!r}")
            why = PARAMETERS[INDEX[parameter]].error(float(v))
            if why:
                fail(label, why)
            values[parameter] = float(v)
            given.add(parameter)
    section = data.get("compensation")
    for key, other in _PAIRED:
        if isinstance(section, dict) and key in section and other not in section:
            fail(f"compensation.{key}", f"direction-dependent viscous feed-forward needs {other} too")
    for parameter in _REQUIRED:
        if parameter not in given:
            fail(next(f"{s}.{k}".lstrip(".") for s, keys in _FILE_KEYS.items() for k, p in keys.items()
                      if p == parameter), "missing")
    return ControllerSpec(name, tuple(values[p.name] for p in PARAMETERS), source)


def controller_toml(spec: ControllerSpec, comment: str = "") -> str:
    """The controller file's text that :func:`load_controller` reads back to ``spec`` (every key written, values
    exact); ``comment`` lines go at its top as TOML comments.  Runtime values that are no part of a drive's
    settings (actuator noise and its seed) are left out."""
    lines = [f"# {line}".rstrip() for line in comment.splitlines()] + [f'name = "{spec.name}"']
    for section, keys in _FILE_KEYS.items():
        if section:
            lines += ["", f"[{section}]"]
        for key, parameter in keys.items():
            value = spec[parameter]
            if parameter in OPTIONAL_PARAMETERS and _left_out(spec):
                continue
            if parameter == "velocity_filter":
                lines.append(f'{key} = "{FILTERS[int(value)]}"')
            elif PARAMETERS[INDEX[parameter]].integer:
                lines.append(f"{key} = {int(value)}")
            else:
                lines.append(f"{key} = {float(value)!r}")
    return "\n".join(lines) + "\n"


def _left_out(spec: ControllerSpec) -> bool:
    """Whether the file leaves out the optional keys: the Gaussian curve and no direction-dependent viscous part."""
    return all(spec[p] == PARAMETERS[INDEX[p]].default for p in OPTIONAL_PARAMETERS)


def load_controller(path: str | Path) -> ControllerSpec:
    """Read a controller file.

    Parameters
    ----------
    path : str or Path
        A controller file (TOML, docs/controller.md) or the name of an example that ships with servofmu
        (``"axis_controller"``).

    Returns
    -------
    ControllerSpec
        The controller's name and parameter vector.

    Raises
    ------
    ControllerError
        (a UserError) when the file is missing or invalid; the message names file and key.
    """
    from ..model.plant import example_files

    path = Path(path)
    if not path.is_file():
        examples = example_files()
        if path.suffix == "" and str(path) in examples:
            path = examples[str(path)]
        else:
            raise ControllerError(f"{path}: no such controller file")
    try:
        data = tomllib.loads(checked_text(path, path.read_text()))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ControllerError(f"{path}: not a valid TOML file ({exc})") from exc
    return controller_from_dict(data, source=str(path))


def friction_feedforward(controller: ControllerSpec, plant: Plant, share: float = 1.0) -> ControllerSpec:
    """The controller with the feed-forward of ``plant``'s friction switched on (``share`` of it).

    The feed-forward is the plant model's steady friction curve F(v) (Coulomb: fs = fc; LuGre: its steady state)
    plus the viscous friction in a first-order G's pole (servofmu.model.friction.viscous_damping), evaluated by the controller at
    the reference velocity — known ahead and free of the encoder's noise, where the measured velocity would feed
    quantisation noise back and chatter around the reversals.  The tanh sign is smoothed by the plant's v_smooth
    (a law without one, LuGre or Dahl: the controller file's, default 1e-3 m/s).  The law gives the values
    (FrictionLaw.feedforward: Stribeck's curve with its shape exponent δ, 2 where the law has none).  A
    direction-dependent viscous friction is fed forward by direction (ff_fv_pos, ff_fv_neg), the damping of G's
    pole, common to both directions, as ff_fv."""
    values = plant.friction.values()
    ff = plant.friction.law.feedforward(values, controller["ff_v_smooth"])
    fv_pos, fv_neg = viscous_levels(values)
    if "fv_pos" in values:
        viscous = {"ff_fv": viscous_damping(plant), "ff_fv_pos": fv_pos, "ff_fv_neg": fv_neg}
    else:
        viscous = {"ff_fv": 0.5 * (fv_pos + fv_neg) + viscous_damping(plant), "ff_fv_pos": 0.0, "ff_fv_neg": 0.0}
    return controller.with_values(friction_feedforward=share, ff_fc_pos=ff["fc_pos"], ff_fc_neg=ff["fc_neg"],
                                  ff_fs_pos=ff["fs_pos"], ff_fs_neg=ff["fs_neg"], ff_vs=ff["vs"],
                                  ff_delta=ff["delta"], ff_v_smooth=ff["v_smooth"], **viscous)


def missing_parameter(names) -> str | None:
    """The first parameter of the vector that ``names`` (an FMU's variables, an axis's parameter set) lacks, None
    where it has them all (the optional ones may be missing)."""
    return next((p.name for p in PARAMETERS if p.name not in names and p.name not in OPTIONAL_PARAMETERS), None)


def values_from(values: dict) -> tuple[float, ...]:
    """The parameter vector from name -> value (an optional parameter missing: its default)."""
    return tuple(float(values.get(p.name, p.default)) for p in PARAMETERS)


def parameter_set(spec: ControllerSpec) -> dict[str, float]:
    """name -> value of ``spec`` for an axis's parameter set, the optional parameters left out at their defaults
    (an axis built before they existed runs as before)."""
    return {p.name: v for p, v in zip(PARAMETERS, spec.values)
            if p.name not in OPTIONAL_PARAMETERS or v != p.default}


def params_header() -> str:
    """controller_params.h: the parameter indices and limits for the C law and the FMU's checks."""
    def c(x: float) -> str:
        return "INFINITY" if x == math.inf else repr(float(x))

    lines = ["/* Controller parameter layout, generated from servofmu.model.controller.PARAMETERS. */",
             "#ifndef CONTROLLER_PARAMS_H", "#define CONTROLLER_PARAMS_H", f"#define CP_COUNT {len(PARAMETERS)}"]
    lines += [f"#define CP_{p.name.upper()} {i}" for i, p in enumerate(PARAMETERS)]
    lines += ["#define CP_LOW {" + ", ".join(c(p.low) for p in PARAMETERS) + "}",
              "#define CP_HIGH {" + ", ".join(c(p.high) for p in PARAMETERS) + "}",
              "#define CP_LOW_OPEN {" + ", ".join(str(int(p.low_open)) for p in PARAMETERS) + "}",
              "#define CP_INTEGER {" + ", ".join(str(int(p.integer)) for p in PARAMETERS) + "}",
              "#endif", ""]
    return "\n".join(lines)
