"""modelDescription.xml (FMI 2.0 and 3.0), buildDescription.xml and documentation/index.html."""
from __future__ import annotations

import html
import xml.etree.ElementTree as ET

from .variables import Variable

__all__ = ["model_description_fmi3", "model_description_fmi2", "build_description", "documentation_html",
           "SOURCE_FILES", "ANNOTATION_TYPE", "base_unit"]

# Units used by the plant, as SI base-unit exponents.
BASE_UNITS = {
    "s": {"s": 1},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "Hz": {"s": -1},
    "1/s": {"s": -1},
    "kg": {"kg": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad": {"rad": 1},
    "m/(N.s)": {"kg": -1, "s": 1},  # G(s): velocity per force
}


def base_unit(name: str) -> dict:
    """SI base-unit exponents of a unit name: BASE_UNITS, or m/(N.s^k) (the numerator constant of G(s),
    servofmu.model.plant.gain_unit) = kg^-1·s^(2−k)."""
    if name in BASE_UNITS:
        return BASE_UNITS[name]
    if name.startswith("m/(N.s^") and name.endswith(")") and name[7:-1].isdigit():
        k = int(name[7:-1])
        return {"kg": -1, "s": 2 - k} if k != 2 else {"kg": -1}
    raise KeyError(f"unit {name!r} has no SI definition")
LOG_CATEGORIES = {
    "logStatusError": "errors: bad calls, unknown value references, integrator failures",
    "logSolver": "progress of the Co-Simulation integrator (with debug logging on)",
}
SOURCE_FILES = ("model_eqs.c", "servo_core.c")
ANNOTATION_TYPE = "servofmu.provenance"  # FMI 3.0 <Annotation type=...>; FMI 2.0: <Tool name="servofmu">


def _fmt(x: float) -> str:
    return repr(float(x))


def _unit_definitions(parent: ET.Element, variables: list[Variable]) -> None:
    used = sorted({v.unit for v in variables if v.unit})
    defs = ET.SubElement(parent, "UnitDefinitions")
    for name in used:
        unit = ET.SubElement(defs, "Unit", name=name)
        ET.SubElement(unit, "BaseUnit", {k: str(e) for k, e in base_unit(name).items()})


def _common_root(tag_version: str, info: dict) -> ET.Element:
    return ET.Element("fmiModelDescription", {"fmiVersion": tag_version, **info})


def _log_categories(root: ET.Element) -> None:
    cats = ET.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES.items():
        ET.SubElement(cats, "Category", name=name, description=text)


def _default_experiment(root: ET.Element, experiment: dict) -> None:
    ET.SubElement(root, "DefaultExperiment", {k: _fmt(v) for k, v in experiment.items()})


def _provenance_entries(parent: ET.Element, provenance: dict) -> None:
    """<Provenance><Entry name=... value=.../>...</Provenance>: tool-specific content both standards allow."""
    prov = ET.SubElement(parent, "Provenance")
    for name, value in provenance.items():
        ET.SubElement(prov, "Entry", name=str(name), value=str(value))


def model_description_fmi3(identifier: str, token: str, variables: list[Variable], info: dict,
                           experiment: dict, provenance: dict | None = None, continuous: bool = True) -> bytes:
    """FMI 3.0 modelDescription.xml: Model Exchange and Co-Simulation of a plant, or (``continuous=False``) the
    Co-Simulation of a sampled component, which has no states and no derivatives."""
    root = _common_root("3.0", {"modelName": identifier, "instantiationToken": token, **info,
                                "variableNamingConvention": "flat"})
    caps = {"modelIdentifier": identifier, "canGetAndSetFMUState": "true", "canSerializeFMUState": "true"}
    if continuous:
        caps.update({"providesDirectionalDerivatives": "true", "providesAdjointDerivatives": "true"})
        ET.SubElement(root, "ModelExchange", {**caps, "needsCompletedIntegratorStep": "false"})
    ET.SubElement(root, "CoSimulation", {**caps, "canHandleVariableCommunicationStepSize": "true",
                                         "hasEventMode": "false"})
    _unit_definitions(root, variables)
    _log_categories(root)
    _default_experiment(root, experiment)
    mv = ET.SubElement(root, "ModelVariables")
    for v in variables:
        attrs = {"name": v.name, "valueReference": str(v.vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.initial:
            attrs["initial"] = v.initial
        if v.unit:
            attrs["unit"] = v.unit
        if v.start is not None:
            attrs["start"] = _fmt(v.start)
        if v.derivative_of is not None:
            attrs["derivative"] = str(v.derivative_of)
        ET.SubElement(mv, "Float64", attrs)
    ms = ET.SubElement(root, "ModelStructure")
    for v in variables:
        if v.causality == "output":
            ET.SubElement(ms, "Output", valueReference=str(v.vr))
    for v in variables:
        if v.derivative_of is not None:
            ET.SubElement(ms, "ContinuousStateDerivative", valueReference=str(v.vr))
    for v in variables:
        if (v.causality == "output" and v.initial == "calculated") or v.derivative_of is not None:
            ET.SubElement(ms, "InitialUnknown", valueReference=str(v.vr))
    if provenance:
        _provenance_entries(ET.SubElement(ET.SubElement(root, "Annotations"), "Annotation", type=ANNOTATION_TYPE),
                            provenance)
    return _serialize(root)


def model_description_fmi2(identifier: str, guid: str, variables: list[Variable], info: dict,
                           experiment: dict, sources: list[str], provenance: dict | None = None,
                           continuous: bool = True) -> bytes:
    """FMI 2.0 modelDescription.xml (as model_description_fmi3).  FMI 2.0 needs no variable for the independent
    variable, and importers built on the FMI Library reject one without a start value: time is left out."""
    variables = [v for v in variables if v.causality != "independent"]
    root = _common_root("2.0", {"modelName": identifier, "guid": guid, **info,
                                "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    caps = {"modelIdentifier": identifier, "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true"}
    kinds = [("CoSimulation", {"canHandleVariableCommunicationStepSize": "true"})]
    if continuous:
        caps["providesDirectionalDerivative"] = "true"
        kinds.insert(0, ("ModelExchange", {"completedIntegratorStepNotNeeded": "true"}))
    for kind, extra in kinds:
        el = ET.SubElement(root, kind, {**caps, **extra})
        files = ET.SubElement(el, "SourceFiles")
        for name in sources:
            ET.SubElement(files, "File", name=name)
    _unit_definitions(root, variables)
    _log_categories(root)
    _default_experiment(root, experiment)
    if provenance:
        _provenance_entries(ET.SubElement(ET.SubElement(root, "VendorAnnotations"), "Tool", name="servofmu"),
                            provenance)
    mv = ET.SubElement(root, "ModelVariables")
    index = {v.vr: i + 1 for i, v in enumerate(variables)}  # FMI 2.0 refers to variables by 1-based index
    for v in variables:
        attrs = {"name": v.name, "valueReference": str(v.vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.initial:
            attrs["initial"] = v.initial
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        real = {}
        if v.unit:
            real["unit"] = v.unit
        if v.start is not None:
            real["start"] = _fmt(v.start)
        if v.derivative_of is not None:
            real["derivative"] = str(index[v.derivative_of])
        ET.SubElement(sv, "Real", real)
    ms = ET.SubElement(root, "ModelStructure")
    sections = {"Outputs": [v for v in variables if v.causality == "output"],
                "Derivatives": [v for v in variables if v.derivative_of is not None],
                "InitialUnknowns": [v for v in variables if (v.causality == "output" and v.initial == "calculated")
                                    or v.derivative_of is not None]}
    for tag, members in sections.items():
        if members:  # an empty section is not allowed
            section = ET.SubElement(ms, tag)
            for v in members:
                ET.SubElement(section, "Unknown", index=str(index[v.vr]))
    return _serialize(root)


def build_description(identifier: str, sources: list[str]) -> bytes:
    """sources/buildDescription.xml of an FMI 3.0 source FMU: one C99 build configuration of ``sources``."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    bc = ET.SubElement(root, "BuildConfiguration", modelIdentifier=identifier)
    fs = ET.SubElement(bc, "SourceFileSet", language="C99")
    for name in sources:
        ET.SubElement(fs, "SourceFile", name=name)
    return _serialize(root)


def documentation_html(title: str, summary: str, equations: str, variables: list[Variable],
                       extra_sections: list[tuple[str, str]] = ()) -> str:
    """documentation/index.html of an FMU: title, summary, the equations (preformatted), the table of
    ``variables`` (name, value reference, causality, start, unit, description) and ``extra_sections``
    ((heading, HTML body) pairs)."""
    rows = "\n".join(
        f"<tr><td>{html.escape(v.name)}</td><td>{v.vr}</td><td>{v.causality}</td>"
        f"<td>{'' if v.start is None else _fmt(v.start)}</td><td>{html.escape(v.unit or '')}</td>"
        f"<td>{html.escape(v.description)}</td></tr>"
        for v in variables)
    extra = "\n".join(f"<h2>{html.escape(h)}</h2>\n{body}" for h, body in extra_sections)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:2px 6px;text-align:left}}pre{{background:#f4f4f4;padding:1em}}</style>
</head><body>
<h1>{html.escape(title)}</h1>
<p>{html.escape(summary)}</p>
<h2>Equations</h2>
<pre>{html.escape(equations)}</pre>
<h2>Variables</h2>
<table><tr><th>name</th><th>value reference</th><th>causality</th><th>start</th><th>unit</th><th>description</th></tr>
{rows}
</table>
{extra}
</body></html>
"""


def _serialize(root: ET.Element) -> bytes:
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")
