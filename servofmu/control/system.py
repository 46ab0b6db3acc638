"""An axis as a system of FMUs in a standard SSP archive (SSP 1.0): reference source → controller ⇄ plant, and
optionally a disturbance source → controller.

The archive holds SystemStructure.ssd, the FMUs under resources/, and the controller's parameter values in
resources/controller.ssv (a ParameterBinding of the controller component).  The default experiment carries the
controller's sample time as the fixed communication step, in the annotation libcosim reads
(com.opensimulationplatform FixedStepAlgorithm).  Connections:

    reference.position_reference → controller.position_reference
    plant.position               → controller.position
    controller.force             → plant.u
    disturbance.force_disturbance → controller.force_disturbance   (with a disturbance source)

libcosim and FMPy's SSP runner use FMI 2.0 Co-Simulation, so the FMUs of a system are FMI 2.0 (docs/control.md).
"""
from __future__ import annotations

import io
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode, write_failures
from ..runtime import temporary_folder
from ..simulation.fmpy_runs import FmuInfo, read_fmu
from ..model.controller import ControllerSpec, missing_parameter, parameter_set, values_from
from .fmus import (
    CONTROLLER_INPUTS,
    CONTROLLER_OUTPUTS,
    DISTURBANCE_OUTPUT,
    REFERENCE_OUTPUT,
    build_disturbance_fmu,
    build_reference_fmu,
)

__all__ = ["System", "write_system", "read_system", "controller_from_fmu", "parameter_set_xml", "COMPONENTS",
           "DISTURBANCE"]

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
COMPONENTS = ("reference", "controller", "plant")
CONNECTIONS = (("reference", "position_reference", "controller", "position_reference"),
               ("plant", "position", "controller", "position"),
               ("controller", "force", "plant", "u"))
DISTURBANCE = "disturbance"  # the optional component, and its connection
DISTURBANCE_CONNECTION = (DISTURBANCE, DISTURBANCE_OUTPUT[0], "controller", DISTURBANCE_OUTPUT[0])
# what a controller FMU must have to be servofmu's (one built before the disturbance input existed runs without one)
_CONTROLLER_VARIABLES = [n for n, _, _ in CONTROLLER_INPUTS + CONTROLLER_OUTPUTS if n != DISTURBANCE_OUTPUT[0]]
PLANT_CONNECTORS = (("u", "input"), ("v", "output"), ("position", "output"))


@dataclass(frozen=True)
class System:
    """What an axis archive holds: its folder once extracted, the controller's parameter values, the
    communication step (the sample time), the reference's duration and its components (COMPONENTS, and
    DISTURBANCE when it has a disturbance source)."""

    folder: Path
    controller: dict
    step_size: float
    stop_time: float
    components: tuple = COMPONENTS

    def fmu(self, component: str) -> Path:
        """The extracted FMU of a component ("plant", "controller", "reference" or "disturbance")."""
        return self.folder / "resources" / f"{component}.fmu"


def _tag(ns: str, name: str) -> str:
    return f"{{{ns}}}{name}"


def controller_from_fmu(path: str | Path) -> ControllerSpec:
    """The controller an FMU built by servofmu was made of (its parameters' start values)."""
    info = read_fmu(path)
    missing = [n for n in (missing_parameter(info.variables), *_CONTROLLER_VARIABLES)
               if n is not None and n not in info.variables]
    if missing:
        raise UserError(f"{path}: not a servofmu controller FMU (it has no variable {missing[0]!r})")
    return ControllerSpec(info.model_name, values_from({n: v.start for n, v in info.variables.items()}), str(path))


def _check_fmi2_cs(path: Path, role: str) -> FmuInfo:
    """The FMU's description, after checking that it can be a part of a system (FMI 2.0 Co-Simulation)."""
    info = read_fmu(path)
    if not info.fmi_version.startswith("2") or "cs" not in info.interfaces:
        raise UserError(f"{path}: the {role} of a system must be an FMI 2.0 Co-Simulation FMU (libcosim and FMPy's "
                        f"SSP runner use FMI 2.0), not FMI {info.fmi_version}")
    return info


def _ssd(controller: ControllerSpec, stop_time: float, connectors: dict, connections) -> bytes:
    ET.register_namespace("ssd", SSD)
    ET.register_namespace("ssc", SSC)
    ET.register_namespace("osp", OSP)
    root = ET.Element(_tag(SSD, "SystemStructureDescription"), {"name": "servofmu-axis", "version": "1.0"})
    system = ET.SubElement(root, _tag(SSD, "System"), {"name": "axis", "description":
                                                       "reference source, drive controller and plant"})
    elements = ET.SubElement(system, _tag(SSD, "Elements"))
    for name in connectors:
        comp = ET.SubElement(elements, _tag(SSD, "Component"), {"name": name, "source": f"resources/{name}.fmu",
                                                                 "type": "application/x-fmu-sharedlibrary"})
        conns = ET.SubElement(comp, _tag(SSD, "Connectors"))
        for connector, kind in connectors[name]:
            ET.SubElement(ET.SubElement(conns, _tag(SSD, "Connector"), {"name": connector, "kind": kind}),
                          _tag(SSC, "Real"))
        if name == "controller":
            bindings = ET.SubElement(comp, _tag(SSD, "ParameterBindings"))
            ET.SubElement(bindings, _tag(SSD, "ParameterBinding"), {"source": "resources/controller.ssv",
                                                                    "type": "application/x-ssp-parameter-set"})
    connections_element = ET.SubElement(system, _tag(SSD, "Connections"))
    for a, ac, b, bc in connections:
        ET.SubElement(connections_element, _tag(SSD, "Connection"), {"startElement": a, "startConnector": ac,
                                                             "endElement": b, "endConnector": bc})
    experiment = ET.SubElement(root, _tag(SSD, "DefaultExperiment"), {"startTime": "0.0",
                                                                      "stopTime": repr(float(stop_time))})
    annotation = ET.SubElement(ET.SubElement(experiment, _tag(SSD, "Annotations")), _tag(SSC, "Annotation"),
                               {"type": "com.opensimulationplatform"})
    ET.SubElement(ET.SubElement(annotation, _tag(OSP, "Algorithm")), _tag(OSP, "FixedStepAlgorithm"),
                  {"baseStepSize": repr(float(controller.sample_time))})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def parameter_set_xml(values: dict) -> bytes:
    """An SSP parameter set (.ssv) of Real values by name."""
    ET.register_namespace("ssv", SSV)
    root = ET.Element(_tag(SSV, "ParameterSet"), {"version": "1.0", "name": "controller"})
    params = ET.SubElement(root, _tag(SSV, "Parameters"))
    for name, value in values.items():
        ET.SubElement(ET.SubElement(params, _tag(SSV, "Parameter"), {"name": name}), _tag(SSV, "Real"),
                      {"value": repr(float(value))})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def write_system(plant_fmu: str | Path, controller_fmu: str | Path, reference: tuple[np.ndarray, np.ndarray],
                 output: str | Path, controller: ControllerSpec | None = None, overwrite: bool = False,
                 disturbance: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write the SSP archive of an axis.

    Parameters
    ----------
    plant_fmu, controller_fmu : str or Path
        FMI 2.0 Co-Simulation FMUs: a plant (input ``u``, outputs ``v``, ``position``) and a servofmu controller.
    reference : tuple of ndarray
        The reference trajectory: times (s) and positions (m); it sets the system's duration.
    output : str or Path
        The .ssp archive to write (atomically).
    controller : ControllerSpec, optional
        The controller parameter values to bind (default: the controller FMU's own).
    overwrite : bool
        Replace an existing ``output``; without it an existing file is refused.
    disturbance : tuple of ndarray, optional
        A known disturbance: times (s) and forces (N) that the controller adds after its output limit, the force
        of time t_k applied from t_k on (a disturbance source FMU, connected to ``force_disturbance``); 0 at the
        first two samples.

    Returns
    -------
    Path
        The archive written.

    Raises
    ------
    UserError
        For FMUs that are not FMI 2.0 Co-Simulation, a plant without ``u``/``v``/``position``, a bad reference or
        disturbance, a disturbance for a controller FMU without the ``force_disturbance`` input.
    """
    output = claim_output(output, output_mode(overwrite), inputs=(plant_fmu, controller_fmu))
    plant_fmu, controller_fmu = Path(plant_fmu), Path(controller_fmu)
    plant = _check_fmi2_cs(plant_fmu, "plant")
    plant.require(*(n for n, _ in PLANT_CONNECTORS))
    variables = _check_fmi2_cs(controller_fmu, "controller").variables
    controller = controller or controller_from_fmu(controller_fmu)
    if disturbance is not None and DISTURBANCE_OUTPUT[0] not in variables:
        raise UserError(f"{controller_fmu}: the controller FMU has no input {DISTURBANCE_OUTPUT[0]!r} for the "
                        "disturbance (built by an older servofmu: build it again with `servofmu controller`)")
    time, position = reference
    connectors = {"reference": [(REFERENCE_OUTPUT[0], "output")],
                  "controller": [(n, "input") for n, _, _ in CONTROLLER_INPUTS
                                 if n in variables and (disturbance is not None or n != DISTURBANCE_OUTPUT[0])]
                  + [(n, "output") for n, _, _ in CONTROLLER_OUTPUTS],
                  "plant": list(PLANT_CONNECTORS)}
    connections = CONNECTIONS
    if disturbance is not None:
        connectors[DISTURBANCE] = [(DISTURBANCE_OUTPUT[0], "output")]
        connections = CONNECTIONS + (DISTURBANCE_CONNECTION,)
    with temporary_folder("ssp") as tmp:
        fmus = {"reference": build_reference_fmu(time, position, Path(tmp) / "reference.fmu", fmi_version=2,
                                                 sample_time=controller.sample_time),
                "controller": controller_fmu, "plant": plant_fmu}
        if disturbance is not None:
            fmus[DISTURBANCE] = build_disturbance_fmu(*disturbance, Path(tmp) / "disturbance.fmu", fmi_version=2,
                                                      sample_time=controller.sample_time)
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("SystemStructure.ssd", _ssd(controller, float(time[-1]), connectors, connections))
            zf.writestr("resources/controller.ssv", parameter_set_xml(parameter_set(controller)))
            for name, path in fmus.items():
                zf.write(path, f"resources/{name}.fmu")
    atomic_write(output, buffer.getvalue())
    return output


def _check_connections(path: Path, root: ET.Element, fmus: dict[str, Path]) -> None:
    """Every connection joins an output of one component's FMU to an input of another's, and the loop's three
    connections are all there.  Checked against the FMUs' model descriptions before any engine runs: FMPy runs a
    connection to a variable that does not exist without a word, and the plant then never receives the force."""
    causality = {}
    for name, fmu in fmus.items():
        causality[name] = {v: var.causality for v, var in read_fmu(fmu).variables.items()}
    found = set()
    for c in root.iter(_tag(SSD, "Connection")):
        ends = (c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
        for element, connector, role in ((ends[0], ends[1], "output"), (ends[2], ends[3], "input")):
            if element not in causality:
                raise UserError(f"{path}: a connection names the component {element!r}, which the system does not "
                                "have")
            kind = causality[element].get(connector)
            if kind is None:
                raise UserError(f"{path}: a connection names {element}.{connector}, which the FMU of {element!r} "
                                "does not have")
            if kind != role:
                raise UserError(f"{path}: the connection {ends[0]}.{ends[1]} → {ends[2]}.{ends[3]} needs "
                                f"{element}.{connector} to be an {role}, not an {kind}")
        found.add(ends)
    required = CONNECTIONS + ((DISTURBANCE_CONNECTION,) if DISTURBANCE in fmus else ())
    for a, ac, b, bc in required:
        if (a, ac, b, bc) not in found:
            raise UserError(f"{path}: the system does not connect {a}.{ac} to {b}.{bc}")


def read_system(path: str | Path, folder: str | Path) -> System:
    """Extract an axis archive into ``folder`` and read what running it needs; a damaged archive, a missing FMU
    or an archive that is not an axis of servofmu's layout is a UserError naming it."""
    path, folder = Path(path), Path(folder)
    if not path.is_file():
        raise UserError(f"{path}: no such SSP file")
    try:
        with zipfile.ZipFile(path) as zf, write_failures(f"the extracted copy of {path} in {folder}"):
            zf.extractall(folder)
    except (zipfile.BadZipFile, OSError) as exc:
        raise UserError(f"{path}: not an SSP archive ({exc})") from exc
    ssd = folder / "SystemStructure.ssd"
    try:
        root = ET.parse(ssd).getroot()
    except (OSError, ET.ParseError) as exc:
        raise UserError(f"{path}: no readable SystemStructure.ssd ({exc})") from exc
    sources = {c.get("name"): c.get("source") for c in root.iter(_tag(SSD, "Component"))}
    for name in COMPONENTS + tuple(n for n in sources if n not in COMPONENTS):
        if name not in sources:
            raise UserError(f"{path}: the system has no component {name!r}")
        if not sources[name] or not (folder / sources[name]).is_file():
            raise UserError(f"{path}: the component {name!r} names a missing FMU ({sources[name]})")
    _check_connections(path, root, {name: folder / src for name, src in sources.items()})
    step = root.find(f".//{_tag(OSP, 'FixedStepAlgorithm')}")
    experiment = root.find(_tag(SSD, "DefaultExperiment"))
    if step is None or experiment is None or experiment.get("stopTime") is None:
        raise UserError(f"{path}: the system has no default experiment with a fixed step")
    values = {}
    ssv = folder / "resources" / "controller.ssv"
    if ssv.is_file():
        for p in ET.parse(ssv).getroot().iter(_tag(SSV, "Parameter")):
            real = p.find(_tag(SSV, "Real"))
            values[p.get("name")] = float(real.get("value"))
    return System(folder=folder, controller=values, step_size=float(step.get("baseStepSize")),
                  stop_time=float(experiment.get("stopTime")),
                  components=COMPONENTS + ((DISTURBANCE,) if DISTURBANCE in sources else ()))
