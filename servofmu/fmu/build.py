"""Build an FMU (FMI 2.0 or 3.0, Model Exchange + Co-Simulation) from a plant.

The equations are C code that CasADi generates from the plant's symbolic model
(servofmu.fmu.sources); the FMI interface is the fixed C in ``c/`` (servo_core.c
plus one fmiN_api.c).  The FMU holds those sources and a buildDescription.xml so
that any platform can rebuild it, plus the binary for this platform.  Building
is four steps: sources, descriptions and documentation, binary, archive.
"""
from __future__ import annotations

import html
import io
import platform
import shutil
import zipfile
from pathlib import Path

from ..errors import UserError
from ..fileio import atomic_write, claim_output, output_mode, write_failures
from ..model.plant import Plant
from ..model.symbolic import build_model
from ..runtime import compile_shared, find_compiler, temporary_folder, utc_now
from ..version import __version__
from . import description
from .sources import C_DIR, generate_sources
from .variables import Variable, fmu_variables

__all__ = ["BuildError", "build_fmu", "assemble_fmu", "platform_folder", "DEFAULT_EXPERIMENT", "CORE_FILES", "equations"]

CORE_FILES = ("core_api.h", "core_common.c")  # what every FMU core includes (servo_core.c, sampled_core.c)
DEFAULT_EXPERIMENT = {"startTime": 0.0, "stopTime": 10.0, "tolerance": 1e-10, "stepSize": 1e-3}
EQUATIONS = """u_total = u + excitation_amplitude*sin(2*pi*excitation_frequency*t)
v       = output of G(s) driven by u_total - F(v)        (all states start at 0)
position = integral of v"""
VISCOUS_EQUATIONS = {"fv": "viscous = fv*v", "fv_pos": "viscous = fv_pos*max(v, 0) + fv_neg*min(v, 0)"}
LOAD_EQUATIONS = """load (the terms of the plant's [load] section; G is driven by u_total - F(v) + L(position)):
L = offset - stiffness*(position - x0) + ripple_amplitude*sin(2*pi*position/ripple_period + ripple_phase)"""


def equations(plant: Plant) -> str:
    """The plant's equations in ASCII for the FMU's documentation: G's, its friction law's (servofmu.model.laws)
    with its viscous term, and its load's."""
    friction = plant.friction
    viscous = VISCOUS_EQUATIONS["fv_pos" if "fv_pos" in friction.keys() else "fv"]
    text = f"{EQUATIONS}\n{friction.model}: {friction.law.equations}\n{viscous}"
    return text + ("\n" + LOAD_EQUATIONS if plant.load.keys() else "")


class BuildError(UserError):
    """The FMU could not be built (no compiler, compile failure, unwritable output)."""


def platform_folder(fmi_version: int) -> str:
    """The binaries/ subfolder of this platform in an FMI ``fmi_version`` FMU."""
    machine = {"amd64": "x86_64", "arm64": "aarch64"}.get(platform.machine().lower(), platform.machine().lower())
    system = {"darwin": "darwin", "windows": "windows"}.get(platform.system().lower(), "linux")
    if fmi_version == 2:
        bits = "64" if machine in ("x86_64", "aarch64") else "32"
        return {"linux": "linux", "darwin": "darwin", "windows": "win"}[system] + bits
    return f"{machine}-{system}"


def fmi_header_dir() -> Path:
    """The FMI 2.0/3.0 standard headers; FMPy ships them with its compile support."""
    import fmpy
    path = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (path / "fmi3Functions.h").is_file():
        raise BuildError(f"FMI headers not found in {path} (reinstall fmpy)")
    return path


def build_fmu(plant: Plant, output: str | Path, fmi_version: int = 3, provenance: dict | None = None,
              overwrite: bool = False) -> Path:
    """Write an FMU of ``plant``: Model Exchange and Co-Simulation in one archive.

    Parameters
    ----------
    plant : Plant
        The plant (see :func:`servofmu.load_plant`).
    output : str or Path
        The .fmu file to write.
    fmi_version : {3, 2}
        FMI version of the FMU.
    provenance : dict, optional
        Name/value pairs added to the FMU's description, documentation and annotations (FMI 3.0
        ``<Annotations>``, FMI 2.0 ``<VendorAnnotations>``).
    overwrite : bool
        Replace an existing ``output`` (atomically); without it an existing file is refused.

    Returns
    -------
    Path
        The FMU written.

    Raises
    ------
    BuildError
        (a UserError) when there is no C compiler, compiling fails or ``output`` cannot be written; a UserError
        when ``output`` exists (without ``overwrite``).

    Examples
    --------
    >>> from servofmu import build_fmu, load_plant
    >>> build_fmu(load_plant("g1"), "g1.fmu")  # doctest: +SKIP
    PosixPath('g1.fmu')
    """
    from ..api_checks import check_arguments

    check_arguments(build_fmu, locals())  # a wrong type: UserError naming it
    model = build_model(plant)

    def write_sources(src: Path) -> str:
        token = generate_sources(model, src, plant.name)  # model_eqs.c/.h, model_config.h
        (src / "fmu_core.h").write_text('#include "servo_core.h"\n')
        for name in ("servo_core.c", "servo_core.h", *CORE_FILES):
            shutil.copy(C_DIR / name, src / name)
        return token

    return assemble_fmu(plant.name, output, fmi_version, fmu_variables(model), write_sources,
                        list(description.SOURCE_FILES), _summary(plant, provenance),
                        equations(plant), provenance,
                        title=f"{plant.name} — servo plant with friction (FMI {fmi_version}.0)", overwrite=overwrite)


def assemble_fmu(identifier: str, output: str | Path, fmi_version: int, variables: list[Variable], write_sources,
                 sources: list[str], summary: str, equations: str, provenance: dict | None = None,
                 title: str | None = None, continuous: bool = True, overwrite: bool = False) -> Path:
    """Write an FMU: ``write_sources(folder)`` fills sources/ (and returns the instantiation token); the C files
    ``sources`` plus the FMI wrapper fmiN_api.c are compiled for this platform; the model description, a build
    description and documentation/index.html are written; the archive replaces ``output`` atomically.
    ``continuous=False``: a sampled component, Co-Simulation only.  An existing ``output`` is refused unless
    ``overwrite`` (fileio.claim_output)."""
    if fmi_version not in (2, 3):
        raise BuildError(f"fmi_version must be 2 or 3, not {fmi_version}")
    output = claim_output(output, output_mode(overwrite))
    find_compiler()  # before any work: a missing compiler is the commonest failure
    headers = fmi_header_dir()
    with temporary_folder("build") as tmp:
        with write_failures(f"the FMU's files in {tmp}", BuildError):
            root = Path(tmp) / "fmu"
            src = root / "sources"
            src.mkdir(parents=True)
            token = write_sources(src)
            api = f"fmi{fmi_version}_api.c"
            shutil.copy(C_DIR / api, src / api)
            sources = [*sources, api]
            (src / "buildDescription.xml").write_bytes(description.build_description(identifier, sources))
            info = {"description": summary, "generationTool": f"servofmu {__version__}",
                    "generationDateAndTime": utc_now()}
            if fmi_version == 3:
                md = description.model_description_fmi3(identifier, token, variables, info, DEFAULT_EXPERIMENT,
                                                        provenance, continuous=continuous)
            else:
                md = description.model_description_fmi2(identifier, token, variables, info, DEFAULT_EXPERIMENT,
                                                        sources, provenance, continuous=continuous)
            (root / "modelDescription.xml").write_bytes(md)
            _write_documentation(root, title or identifier, summary, equations, variables, provenance)
            bindir = root / "binaries" / platform_folder(fmi_version)
            bindir.mkdir(parents=True)
            compile_shared([src / s for s in sources], bindir / f"{identifier}{_shared_suffix()}",
                           include=[src, headers], what=f"the FMU {identifier}")
        _pack(root, output)
    return output


def _summary(plant: Plant, provenance: dict | None) -> str:
    zeros = f", zeros {', '.join(map(str, plant.all_zeros()))}" if plant.zeros else ""
    text = (f"Servo plant '{plant.name}': G(s) with poles {', '.join(map(str, plant.all_poles()))}{zeros} "
            f"and {plant.friction.model} friction in the feedback path.")
    if plant.load.keys():
        text += f" Load on the axis, adding to u: {plant.load.describe()}."
    if provenance:
        text += " " + "; ".join(f"{k}: {v}" for k, v in provenance.items())
    return text


def _write_documentation(root: Path, title: str, summary: str, equations: str, variables: list[Variable],
                         provenance: dict | None) -> None:
    docs = root / "documentation"
    docs.mkdir()
    extra = []
    if provenance:
        rows = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>"
                       for k, v in provenance.items())
        extra.append(("Provenance", f"<table>{rows}</table>"))
    (docs / "index.html").write_text(description.documentation_html(title, summary, equations, variables, extra))


def _pack(root: Path, output: Path) -> None:
    """Zip ``root`` into ``output`` atomically."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(root.rglob("*")):
            if path.is_file():
                zf.write(path, path.relative_to(root).as_posix())
    atomic_write(output, buffer.getvalue())


def _shared_suffix() -> str:
    return {"darwin": ".dylib", "windows": ".dll"}.get(platform.system().lower(), ".so")
