"""The batch simulator's compiled library: C generated from the plant's CasADi model, compiled with a driver
(``batch_c/batch_driver.c``; its header comment says what the driver adds to the FMU's integrator), and kept in a
cache on disk so that a process which finds it there generates and compiles nothing.

The driver's interface for its callers in this stage: :func:`compiled_driver` (a loaded library),
:class:`SineResult` (the slots of a sine task's results), :data:`H_START`, :data:`HOLD_CODES`, and the ctypes
helpers :func:`c_doubles` and :func:`c_mask`.  Only servofmu.simulation uses this module; the other stages go
through servofmu.simulation.batch.
"""
from __future__ import annotations

import ctypes
import enum
import functools
import hashlib
import importlib.util
import os
import platform
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UserError
from ..model.plant import Plant, state_nominals, state_scale
from ..runtime import cache_dir, compile_shared, compiler_signature, temporary_folder
from ..version import __version__

if TYPE_CHECKING:  # CasADi is loaded only to generate code, which a cached library spares
    import casadi as ca

    from ..model.symbolic import SymbolicModel

__all__ = ["ModelStructureError", "SineResult", "HOLD_CODES", "H_START", "DRIVER_DIR", "DRIVER", "batch_functions",
           "write_batch_sources", "compiled_driver", "batch_library", "driver_cflags", "library_key", "c_doubles",
           "c_mask"]

PACKAGE = Path(__file__).resolve().parent.parent
DRIVER_DIR = PACKAGE / "simulation" / "batch_c"  # the C drivers of the batch and loop simulators
DRIVER = DRIVER_DIR / "batch_driver.c"
FMU_C_DIR = PACKAGE / "fmu" / "c"  # servo_core.c: the FMU's integrator, which the driver includes
# The Python modules whose code writes the generated C sources (with the C files, part of a library's cache key).
# (a friction law's module writes its part of the equations: changing one changes the code of its plants)
GENERATORS = ("model/plant.py", "model/symbolic.py", "model/signals.py", "fmu/sources.py", "fmu/variables.py",
              "simulation/compiled.py") + tuple(f"model/laws/{p.name}"
                                                for p in sorted(PACKAGE.glob("model/laws/*.py")))
EXTRA_CFLAGS = ("-pthread", "-O3")
# On x86-64 the library is built for this machine's processor: about 10 % faster steady states.  No contraction
# into fused multiply-adds, so that results stay bit for bit those of a portable build; the processor is part of
# the cache key, so that a cache shared by several machines never hands one a library it cannot run.
NATIVE_CFLAGS = ("-march=native", "-ffp-contract=off")
HOLD_CODES = {"zoh": 0, "foh": 1, "sine": 2}  # the driver's HOLD_* values
H_START = 1e-4  # first step of every period, as a fraction of the period (the same each period: see the driver)


class SineResult(enum.IntEnum):
    """The slots of a sine task's results, in the order of the driver's ``enum SineResult`` (a test parses the C
    file and compares): the first harmonic S1 of v (real and imaginary part, m/s), the mean of v (m/s) and of v²
    ((m/s)²) over the last period, whether it converged (1.0 or 0.0), the simulated time (s), and the accepted and
    rejected integrator steps."""

    RE_S1 = 0
    IM_S1 = 1
    DC = 2
    MEAN_SQUARE = 3
    CONVERGED = 4
    SETTLE_TIME = 5
    STEPS = 6
    REJECTED = 7


class ModelStructureError(UserError):
    """The plant's equations are not of the form the batch simulator integrates."""


def batch_functions(model: SymbolicModel) -> tuple[ca.Function, ca.Function]:
    """The right-hand side the driver integrates, from the plant's symbolic model.

    ``sb_ode(x, u, p) -> xdot`` and ``sb_jac(x, u, p) -> (dxdot/dx, dxdot/du)`` (dense) for the states without
    the position — unless the load's force depends on it (a spring, a ripple), when the position is a state like
    the others (the driver's position quadrature then integrates the same v beside it) — the plant's parameters
    ``p`` and the model's own excitation removed (the driver puts the sine into u).  Checks what the driver
    relies on: v is the first state, and nothing depends on a position it drops.
    """
    import casadi as ca

    names = model.parameter_names
    pos = model.state_names.index("position")
    keep = [i for i in range(model.nx) if i != pos or model.plant.load.depends_on_position()]
    x = ca.vertcat(*[model.x[i] for i in keep])
    n_plant = len(model.plant.parameter_names())
    p = model.p[:n_plant]
    xdot = ca.substitute(model.xdot, model.p[names.index("excitation_amplitude")], ca.SX(0))
    xdot = ca.vertcat(*[xdot[i] for i in keep])
    if not ca.is_equal(model.y[0], model.x[0]) or pos == 0:
        raise ModelStructureError(f"{model.plant.name}: the batch simulator needs v as the first state")
    if (pos not in keep and ca.jacobian(model.xdot, model.x[pos]).nnz() != 0) or ca.depends_on(xdot, model.t):
        raise ModelStructureError(f"{model.plant.name}: the batch simulator needs equations that depend neither on the "
                                  "position nor, apart from the excitation, on time")
    ode = ca.Function("sb_ode", [x, model.u, p], [ca.densify(xdot)], ["x", "u", "p"], ["xdot"])
    jacobians = [ca.densify(ca.jacobian(xdot, x)), ca.densify(ca.jacobian(xdot, model.u))]
    jac = ca.Function("sb_jac", [x, model.u, p], jacobians, ["x", "u", "p"], ["J", "B"])
    return ode, jac


def write_batch_sources(model: SymbolicModel, src: Path) -> None:
    """batch_eqs.c (CasADi) and batch_config.h (sizes) for the driver; the FMU's sources via generate_sources."""
    import casadi as ca

    from ..fmu.sources import generate_sources
    from ..fmu.variables import state_nominals

    generate_sources(model, src, model.plant.name)  # model_eqs.c, model_config.h: what servo_core.c needs
    functions = batch_functions(model)
    cg = ca.CodeGenerator("batch_eqs.c", {"with_header": False})
    for fn in functions:
        cg.add(fn)
    cg.generate(str(src) + os.sep)
    sizes = {k: max(getattr(f, k)() for f in functions) for k in ("sz_arg", "sz_res", "sz_iw", "sz_w")}
    keep_position = model.plant.load.depends_on_position()
    nominal = [n for i, n in enumerate(state_nominals(model)) if keep_position or model.state_names[i] != "position"]
    (src / "batch_config.h").write_text(
        f"/* Sizes of the batch simulator of plant {model.plant.name}. */\n"
        f"#define SB_NS {functions[0].size1_in(0)}\n#define SB_NP {functions[0].size1_in(2)}\n"
        f"#define SB_SZ_ARG {max(sizes['sz_arg'], 3)}\n#define SB_SZ_RES {max(sizes['sz_res'], 2)}\n"
        f"#define SB_SZ_IW {sizes['sz_iw']}\n#define SB_SZ_W {sizes['sz_w']}\n"
        f"#define SB_X_NOMINAL {{{', '.join(repr(float(v)) for v in nominal)}}}\n")


def compiled_driver(plant: Plant, driver: Path, extra: dict[str, str] | None = None) -> ctypes.CDLL:
    """The shared library of a driver C file compiled with the plant's batch sources (write_batch_sources) and
    ``extra`` generated files (name -> text).

    Libraries are kept in cache_dir() under a key of everything that determines them (:func:`library_key`), so
    that a process which finds its library there loads it without generating or compiling anything.  A new
    library is compiled in a temporary folder and renamed into the cache: processes building the same library
    at once all end with one complete file.  Deleting the folder is safe; libraries are rebuilt on demand.
    """
    extra = extra or {}
    name = f"{driver.stem}-{plant.name}-{library_key(plant, driver, extra)[:24]}.so"
    target = cache_dir() / name
    with temporary_folder("batch") as tmp:
        if not target.is_file():
            target = _build(plant, driver, extra, Path(tmp), target)
        lib = ctypes.CDLL(str(target))  # inside: a library left in the temporary folder is mapped before it goes
    _declare(lib)
    ns, n_p, nf = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
    lib.sb_sizes(ctypes.byref(ns), ctypes.byref(n_p), ctypes.byref(nf))
    if (n_p.value, nf.value) != (len(plant.parameter_names()), len(SineResult)):
        raise ModelStructureError(f"{target}: compiled library does not match plant {plant.name}")
    return lib


@functools.lru_cache(maxsize=None)
def driver_cflags() -> tuple[str, ...]:
    """The compiler flags of the batch drivers, beyond runtime.CFLAGS (see NATIVE_CFLAGS)."""
    if platform.machine().lower() in ("x86_64", "amd64"):
        return (*EXTRA_CFLAGS, *NATIVE_CFLAGS)
    return EXTRA_CFLAGS


@functools.lru_cache(maxsize=None)
def _processor() -> str:
    """What identifies this machine's processor for code built for it: its model and features (Linux), else
    what the platform module says."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return f"{platform.machine()} {platform.processor()}"
    first = {}
    for line in lines:
        key, _, value = line.partition(":")
        first.setdefault(key.strip(), value.strip())
    return " ".join(first.get(k, "") for k in ("vendor_id", "model name", "flags"))


def library_key(plant: Plant, driver: Path, extra: dict[str, str]) -> str:
    """The cache key (SHA-256, hex) of a compiled driver: the plant's structure (its file text with every value
    1: the parameters are the library's arguments) and the two constants its code holds (plant.state_scale and
    plant.state_nominals, powers of two: plants of one structure and similar values share a library; a selection
    fits candidates from starts of their own, which each compiled a library of their own when the key held the
    values), servofmu's version, the Python code that generates the C sources (GENERATORS), every C file of the
    driver's, the batch driver's and the FMU core's folders, the ``extra`` texts, the CasADi installation, the
    compiler with its flags, and the processor when built for it."""
    digest = hashlib.sha256()
    native = driver_cflags() != EXTRA_CFLAGS
    shape = plant.with_parameters(np.ones(len(plant.parameter_names()))).to_toml()
    constants = f"{state_scale(plant)!r} " + " ".join(repr(n) for n in state_nominals(plant.friction) or (1.0,))
    for text in (shape, constants, __version__, compiler_signature(driver_cflags()), _casadi_stamp(),
                 _processor() if native else ""):
        digest.update(text.encode() + b"\0")
    folders = {FMU_C_DIR, DRIVER.parent, driver.parent}
    files = [PACKAGE / g for g in GENERATORS] + sorted(f for d in folders for f in d.iterdir()
                                                     if f.suffix in (".c", ".h"))
    for path in [*files, driver]:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    for name, text in sorted(extra.items()):
        digest.update(name.encode() + b"\0" + text.encode())
    return digest.hexdigest()


def _casadi_stamp() -> str:
    """Which CasADi generates the code, without importing it: its location, size and modification time."""
    spec = importlib.util.find_spec("casadi")
    if spec is None or spec.origin is None:
        return "no casadi"
    stat = os.stat(spec.origin)
    return f"{spec.origin} {stat.st_size} {stat.st_mtime_ns}"


def _build(plant: Plant, driver: Path, extra: dict[str, str], src: Path, target: Path) -> Path:
    """Generate the sources into ``src``, compile, and move the library to ``target`` (the library's path in the
    temporary folder ``src`` when the cache is not writable)."""
    from ..model.symbolic import build_model

    write_batch_sources(build_model(plant), src)
    for name, text in extra.items():
        (src / name).write_text(text)
    built = src / target.name
    # the driver's unit includes batch_eqs.c and servo_core.c; model_eqs.c serves servo_core.c
    compile_shared([driver, src / "model_eqs.c"], built, include=[src, FMU_C_DIR, DRIVER.parent, driver.parent],
                   extra_flags=driver_cflags(), what=f"the {driver.stem} of {plant.name}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(f".{target.name}.{os.getpid()}.part")
        partial.write_bytes(built.read_bytes())
        os.replace(partial, target)  # atomic: concurrent builders all end with a complete file
    except OSError:
        return built  # no writable cache
    return target


@functools.lru_cache(maxsize=None)
def batch_library(plant: Plant) -> ctypes.CDLL:
    """The batch driver's library for the structure of ``plant`` (loaded once per process)."""
    return compiled_driver(plant, DRIVER)


def _declare(lib: ctypes.CDLL) -> None:
    d, pd, lng, i = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_long, ctypes.c_int
    pu = ctypes.POINTER(ctypes.c_ubyte)
    lib.sb_sizes.argtypes = [ctypes.POINTER(i)] * 3
    lib.sb_sine.argtypes = [lng, i, pd, pu, i, pd, pd, d, d, d, lng, d, lng, lng, lng, lng, i, pd, pd, pd]
    lib.sb_sine.restype = i
    lib.sb_record.argtypes = [lng, i, pd, pu, lng, pd, pd, i, d, d, d, d, lng, i, pd]
    lib.sb_record.restype = i


def c_doubles(a: np.ndarray):
    """A pointer to the doubles of a C-contiguous float64 array, for the driver's entry points."""
    assert a.flags.c_contiguous and a.dtype == np.float64  # internal invariant, not input validation
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def c_mask(mask: np.ndarray):
    """A pointer to the bytes of a C-contiguous uint8 array (a mask of valid parameter sets), for the driver."""
    assert mask.flags.c_contiguous and mask.dtype == np.uint8
    return mask.ctypes.data_as(ctypes.POINTER(ctypes.c_ubyte))
