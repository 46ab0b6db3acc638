"""The FMU's variables: one table shared by the C configuration, both model descriptions and the docs.

Value references follow one fixed layout (docs/fmu.md): 0 time, 1 u, 2-4
outputs (v, position, friction_force), 1000+i parameters, 2000+i states,
3000+i state derivatives.  The position state is the output ``position``
itself (VR 3), so it has no 2000-series reference.  :data:`VALUE_REFERENCES`
is the single source of the layout: the C core reads it from the generated
model_config.h.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..model.plant import state_nominals as law_state_nominals
from ..model.symbolic import INPUT_INFO, OUTPUT_INFO, OUTPUT_NAMES, SymbolicModel

VR_TIME, VR_U, VR_Y0, VR_P0, VR_X0, VR_DX0 = 0, 1, 2, 1000, 2000, 3000
# C macro -> value reference, written into model_config.h
VALUE_REFERENCES = {"SV_VR_TIME": VR_TIME, "SV_VR_U": VR_U, "SV_VR_Y0": VR_Y0, "SV_VR_P0": VR_P0,
                    "SV_VR_X0": VR_X0, "SV_VR_DX0": VR_DX0}

__all__ = ["Variable", "VALUE_REFERENCES", "fmu_variables", "state_nominals", "position_index", "state_vr"]


@dataclass(frozen=True)
class Variable:
    """One FMU variable as both model descriptions declare it: name, value reference (``vr``), FMI causality and
    variability, description, unit, start value, initial and (for a derivative) the reference of its state."""

    name: str
    vr: int
    causality: str          # independent | input | output | parameter | local
    variability: str        # continuous | tunable
    description: str
    unit: str | None = None
    start: float | None = None
    initial: str | None = None      # exact | calculated | None
    derivative_of: int | None = None  # VR of the state this is the derivative of


def unit_or_none(unit: str) -> str | None:
    return None if unit == "1" else unit


def state_vr(model: SymbolicModel, i: int) -> int:
    """The value reference of state ``i``: the output ``position`` for the position state, 2000 + i otherwise."""
    return VR_Y0 + 1 if i == position_index(model) else VR_X0 + i


def position_index(model: SymbolicModel) -> int:
    """The index of the position state among the model's states."""
    return model.state_names.index("position")


def state_units(model: SymbolicModel) -> list[str | None]:
    # xi2.. are scaled derivatives of v with no physical unit of their own; the friction law's states have theirs
    law = {state.name: unit_or_none(state.unit) for state in model.plant.friction.states()}
    return ["m/s" if n == "xi1" else None if n.startswith("xi") else law.get(n, "m") for n in model.state_names]


def fmu_variables(model: SymbolicModel, excitation_amplitude: float = 0.0,
                  excitation_frequency: float = 1.0) -> list[Variable]:
    """Every variable of the plant FMU of ``model`` in value-reference order: time, the input ``u`` (N), the
    outputs, the parameters (with the built-in excitation's amplitude (N) and frequency (Hz) as start values),
    the states and their derivatives."""
    out = [Variable("time", VR_TIME, "independent", "continuous", "simulation time", unit="s"),
           Variable("u", VR_U, "input", "continuous", INPUT_INFO[1], unit=INPUT_INFO[0], start=0.0)]
    for i, name in enumerate(OUTPUT_NAMES):
        unit, text = OUTPUT_INFO[name]
        if name == "position":  # the position state itself
            out.append(Variable(name, VR_Y0 + i, "output", "continuous", text, unit=unit, start=0.0,
                                initial="exact"))
        else:
            out.append(Variable(name, VR_Y0 + i, "output", "continuous", text, unit=unit, initial="calculated"))
    start = model.parameter_start(excitation_amplitude, excitation_frequency)
    for i, name in enumerate(model.parameter_names):
        unit, text = model.parameter_info(name)
        out.append(Variable(name, VR_P0 + i, "parameter", "tunable", text, unit=unit_or_none(unit),
                            start=float(start[i]), initial="exact"))
    units = state_units(model)
    law_states = {state.name: state for state in model.plant.friction.states()}
    for i, name in enumerate(model.state_names):
        if name == "position":
            continue
        text = law_states[name].description if name in law_states else \
            f"state {i + 1} of the scaled observable realisation of G(s) (xi1 = v)"
        out.append(Variable(name, VR_X0 + i, "local", "continuous", text, unit=units[i], start=0.0,
                            initial="exact"))
    for i, name in enumerate(model.state_names):
        out.append(Variable(f"der({name})", VR_DX0 + i, "local", "continuous", f"time derivative of {name}",
                            derivative_of=state_vr(model, i)))
    return out


def state_nominals(model: SymbolicModel) -> list[float]:
    """Nominal magnitudes of the states (for absolute tolerances): 1 for G's and the position, the friction
    law's own for its states (LuGre's bristle deflection at sliding, g/sigma0 to a power of two)."""
    law = dict(zip((state.name for state in model.plant.friction.states()),
                   law_state_nominals(model.plant.friction)))
    return [law.get(name, 1.0) for name in model.state_names]
