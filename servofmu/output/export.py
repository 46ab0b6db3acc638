"""Exporting an identified model (docs/export.md): FMU with provenance, python-control, MATLAB, JSON, plant TOML.

Every format carries the identified plant of a RESULT.h5 (servofmu.identification.results) and its provenance:
how it was identified (method, fitness, 95 % intervals, the data file and its SHA-256, the identify command and
date) and how it was exported (RESULT file and its SHA-256, command, date, package version).

The FMU comes from the same generator as the plant FMUs (servofmu.fmu.build_fmu: ME + CS, the same variables) with
the identified values as parameter start values; the plant TOML is the file `servofmu build` reads back to an
FMU that responds identically.  Measuring the exported FMU again (the round trip) is servofmu.commands.roundtrip's.
"""
from __future__ import annotations

import io
import json
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..display import json_safe
from ..errors import UserError
from ..fileio import atomic_write, claim_output, file_sha256, output_mode
from ..identification.results import Result, read_result, to_json
from ..model.laws.registry import base_law
from ..model.plant import Friction, Load, Plant, plant_from_dict
from ..runtime import optional_import, utc_now
from ..version import __version__
from .formats import FORMATS, SUFFIX_FORMATS

__all__ = ["export_result", "export_fmu", "export_control", "export_mat", "export_json", "export_toml",
           "load_control", "identified_plant", "format_of",
           "toml_text", "linear_state_space", "export_provenance"]

CONTROL_FORMAT = "servofmu-control"   # the `control` file: JSON read by load_control
EXPORT_FORMAT = "servofmu-export"     # the `json` file
SCHEMA_VERSION = 1
NAME_SUFFIX = "_identified"


# ---------------------------------------------------------------------------
# What every format carries
# ---------------------------------------------------------------------------
def identified_plant(result: Result, name: str | None = None) -> Plant:
    """The identified plant under its export name (default ``<name>_identified``: not to be mistaken for the
    plant it models)."""
    plant = result.plant
    if name is None:
        name = plant.name if plant.name.endswith(NAME_SUFFIX) else plant.name + NAME_SUFFIX
    # through the plant-file reader, so that a bad --name is reported like a bad plant file
    data = tomllib.loads(plant.to_toml())
    data["name"] = name
    return plant_from_dict(data, source="the model name")


def intervals_text(result: Result) -> str:
    return ", ".join(f"{n} [{lo:.6g}, {hi:.6g}]" for n, (lo, hi) in zip(result.names, result.intervals))


def export_provenance(result: Result, result_file: str | Path | None = None, command: str = "") -> dict[str, str]:
    """Name/value pairs (strings) describing where the exported model comes from."""

    prov = {"method": result.method, "fitness": f"{result.fitness:.6g} (RMS relative output error)",
            "intervals_95": intervals_text(result)}
    # the identification's own record (data file, its hash, ...); its command and date are named apart from
    # the export's
    renamed = {"command": "identify_command", "date": "identify_date"}
    prov.update({renamed.get(str(k), str(k)): str(v) for k, v in result.provenance.items()
                 if v not in (None, "") and k != "data_digests"})  # (one digest per record: for validate, not a model)
    if result_file is not None:
        prov["result_file"] = Path(result_file).name
        prov["result_sha256"] = result.sha256 or file_sha256(result_file)  # the bytes read, when read from it
    prov.update({"export_command": command or "(library call)", "export_date": utc_now(),
                 "package_version": __version__})
    return prov


def linear_state_space(plant: Plant) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C, D) of G(s) from w = u − F(v) to v in the FMU's own realisation (states xi1..xin, v = xi1),
    read off the CasADi model with the friction switched off."""
    import casadi as ca

    from ..model.symbolic import build_model

    linear = replace(plant, friction=Friction(model=base_law().name, fc_pos=0.0, fc_neg=0.0, fv=0.0), load=Load())
    model = build_model(linear)
    n = plant.order  # xi1..xin come first in the state vector, v is the first output
    jac = np.asarray(ca.DM(model.io_jacobian(0.0, np.zeros(model.nx), 0.0, model.parameter_start())))
    nx = model.nx
    return jac[:n, :n], jac[:n, nx:nx + 1], jac[nx:nx + 1, :n], jac[nx:nx + 1, nx:nx + 1]


def _json_text(obj: dict) -> str:
    return json.dumps(json_safe(obj), indent=2, allow_nan=False) + "\n"


def _pairs(roots) -> list[list[float]]:
    return [[float(r.real), float(r.imag)] for r in roots]


# ---------------------------------------------------------------------------
# The formats
# ---------------------------------------------------------------------------
def export_fmu(result: Result, output: str | Path, fmi_version: int = 3, name: str | None = None,
               provenance: dict | None = None, overwrite: bool = False) -> Path:
    """The identified plant of ``result`` as an FMU (servofmu.build_fmu), its provenance in the description."""
    from ..fmu import build_fmu

    return build_fmu(identified_plant(result, name), output, fmi_version=fmi_version,
                     provenance=provenance if provenance is not None else export_provenance(result), overwrite=overwrite)


def control_document(result: Result, name: str | None = None, provenance: dict | None = None) -> dict:
    plant = identified_plant(result, name)
    num, den = plant.transfer_function()
    A, B, C, D = linear_state_space(plant)
    return {"format": CONTROL_FORMAT, "schema_version": SCHEMA_VERSION, "name": plant.name,
            "about": "G(s) = num(s)/den(s) from w = u - friction_force + load force (N) to the velocity v (m/s); "
                     "the friction acts in feedback: v = G(s)(u - F(v) + L(x)), with the load's force L(x) = offset "
                     "- stiffness*(x - x0) + ripple_amplitude*sin(2*pi*x/ripple_period + ripple_phase) of the "
                     "terms in `load` (docs/model.md). Coefficients highest power first.",
            "num": num.tolist(), "den": den.tolist(), "poles": _pairs(plant.all_poles()),
            "zeros": _pairs(plant.all_zeros()), "gain": plant.numerator_gain(),
            "state_space": {"A": A.tolist(), "B": B.tolist(), "C": C.tolist(), "D": D.tolist(),
                            "states": [f"xi{i + 1}" for i in range(plant.order)]},
            "friction": {"model": plant.friction.model, **plant.friction.structure(),
                         **plant.friction.values()},
            "load": plant.load.values(),
            "provenance": provenance if provenance is not None else export_provenance(result)}


def export_control(result: Result, output: str | Path, name: str | None = None,
                   provenance: dict | None = None) -> Path:
    """Write the python-control file of a result (:func:`control_document`, read back by :func:`load_control`);
    returns the path written."""
    return atomic_write(output, _json_text(control_document(result, name, provenance)))


def load_control(path: str | Path, state_space: bool = False, with_load: bool = False):
    """(control.TransferFunction, friction dict) from a file of ``servofmu export --format control``.

    ``state_space=True``: a control.StateSpace in the FMU's realisation (states xi1..xin) instead.
    The friction dict holds ``model`` and the friction parameters of docs/plant-format.md.  ``with_load=True``:
    (system, friction, load), the load dict holding the plant's [load] terms (empty without a load).  Needs
    python-control (``pip install 'servofmu[control]'``).
    """
    control = optional_import("control", "load_control", "control", package="python-control")

    doc = _read_json(path)
    if doc.get("format") != CONTROL_FORMAT:
        raise UserError(f"{path}: not a servofmu control file (format {doc.get('format')!r})")
    if doc.get("schema_version") != SCHEMA_VERSION:
        raise UserError(f"{path}: control file schema version {doc.get('schema_version')!r} is not the supported "
                        f"{SCHEMA_VERSION}")
    try:
        labels = dict(name=str(doc["name"]), inputs="w", outputs="v")
        if state_space:
            ss = doc["state_space"]
            system = control.ss(np.array(ss["A"], dtype=float), np.array(ss["B"], dtype=float),
                                np.array(ss["C"], dtype=float), np.array(ss["D"], dtype=float),
                                states=list(ss["states"]), **labels)
        else:
            system = control.tf(np.array(doc["num"], dtype=float), np.array(doc["den"], dtype=float), **labels)
        friction = dict(doc["friction"])
        load = {str(k): float(v) for k, v in doc.get("load", {}).items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise UserError(f"{path}: damaged control file ({type(exc).__name__}: {exc})") from exc
    return (system, friction, load) if with_load else (system, friction)


def _read_json(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        doc = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not a JSON file ({exc})") from exc
    if not isinstance(doc, dict):
        raise UserError(f"{path}: not a servofmu file (a JSON {type(doc).__name__}, not an object)")
    return doc


def export_mat(result: Result, output: str | Path, name: str | None = None, provenance: dict | None = None) -> Path:
    """MATLAB .mat (v5): num, den, A, B, C, D, poles, zeros, gain, friction (struct), load (struct of the plant's
    [load] terms, when it has any), method, fitness, parameter_names, theta, intervals, provenance (struct)."""
    import scipy.io

    doc = control_document(result, name, provenance)
    ss = doc["state_space"]

    def column(roots):
        return np.array([complex(re, im) for re, im in roots], dtype=complex).reshape(-1, 1)

    content = {
        "name": doc["name"], "num": np.atleast_2d(doc["num"]), "den": np.atleast_2d(doc["den"]),
        "A": np.array(ss["A"]), "B": np.array(ss["B"]), "C": np.array(ss["C"]), "D": np.array(ss["D"]),
        "poles": column(doc["poles"]), "zeros": column(doc["zeros"]), "gain": doc["gain"],
        "friction": doc["friction"], "method": result.method, "fitness": result.fitness,
        "parameter_names": np.array(result.names, dtype=object), "theta": np.asarray(result.theta, dtype=float),
        "intervals": np.asarray(result.intervals, dtype=float), "provenance": doc["provenance"],
    }
    if doc["load"]:
        content["load"] = doc["load"]
    buffer = io.BytesIO()
    scipy.io.savemat(buffer, content, oned_as="row")
    return atomic_write(output, buffer.getvalue())


def export_json(result: Result, output: str | Path, name: str | None = None, provenance: dict | None = None) -> Path:
    """The `--json` object of the identification plus the transfer function, all named parameters, the plant
    file text and the provenance."""
    plant = identified_plant(result, name)
    num, den = plant.transfer_function()
    doc = {"format": EXPORT_FORMAT, "schema_version": SCHEMA_VERSION, "name": plant.name, **to_json(result),
           "transfer_function": {"num": num.tolist(), "den": den.tolist()},
           "plant_parameters": plant.parameters(), "plant_toml": plant.to_toml(),
           "provenance": provenance if provenance is not None else export_provenance(result)}
    return atomic_write(output, _json_text(doc))


def toml_text(result: Result, name: str | None = None, provenance: dict | None = None) -> str:
    """The identified plant as a plant file (TOML), headed by comments with its provenance."""
    plant = identified_plant(result, name)
    prov = provenance if provenance is not None else export_provenance(result)
    head = ["# Identified plant, exported by servofmu; `servofmu build` turns it into an FMU.",
            *(f"# {k} = {json.dumps(str(v), ensure_ascii=False)}" for k, v in prov.items()), ""]
    return "\n".join(head) + plant.to_toml()


def export_toml(result: Result, output: str | Path, name: str | None = None, provenance: dict | None = None) -> Path:
    """Write :func:`toml_text` to ``output`` (atomically); returns the path written."""
    return atomic_write(output, toml_text(result, name, provenance))


def format_of(output: str | Path, fmt: str | None) -> str:
    """The export format: ``fmt`` if given, else from the output's suffix."""
    if fmt is not None:
        if fmt not in FORMATS:
            raise UserError(f"unknown export format {fmt!r} (choose {', '.join(FORMATS)})")
        return fmt
    suffix = Path(output).suffix.lower()
    if suffix not in SUFFIX_FORMATS:
        raise UserError(f"{output}: cannot tell the format from the suffix {suffix or '(none)'!r}; give the format "
                        f"({', '.join(FORMATS)})")
    return SUFFIX_FORMATS[suffix]


def export_result(result_file: str | Path, output: str | Path, fmt: str | None = None,
                  fmi_version: int | None = None, name: str | None = None, command: str = "",
                  overwrite: bool = False) -> tuple[Path, str]:
    """Export an identified model to another tool, with its provenance.

    Parameters
    ----------
    result_file : str or Path
        A result file (RESULT.h5).
    output : str or Path
        The file to write.
    fmt : {"fmu", "control", "mat", "json", "toml"}, optional
        Default: from the suffix of ``output``.
    fmi_version : {3, 2}, optional
        FMI version of an FMU (default 3).
    name : str, optional
        Model name in the export (default: the plant's name + ``_identified``).
    command : str
        The command line, for provenance.
    overwrite : bool
        Replace an existing ``output``; without it an existing file is refused.

    Returns
    -------
    tuple of (Path, str)
        The file written and its format.

    Raises
    ------
    UserError
        For an unreadable result, an unknown format, or an output that cannot be written, exists (without
        ``overwrite``) or is the result file itself.

    Notes
    -----
    Everything is checked before anything is written; a failure leaves ``output`` as it was.
    """
    from ..api_checks import check_arguments

    check_arguments(export_result, locals())  # a wrong type: UserError naming it
    fmt = format_of(output, fmt)
    if fmi_version is not None and fmt != "fmu":
        raise UserError(f"fmi_version applies to FMU export only, not to format {fmt}")
    claim_output(output, output_mode(overwrite), inputs=(result_file,))
    result = read_result(result_file)
    prov = export_provenance(result, result_file, command)
    if fmt == "fmu":
        return export_fmu(result, output, fmi_version or 3, name, prov, overwrite=True), fmt
    writer = {"control": export_control, "mat": export_mat, "json": export_json, "toml": export_toml}[fmt]
    return writer(result, output, name, prov), fmt
