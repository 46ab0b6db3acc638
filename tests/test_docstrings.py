"""Every public name has a docstring, found by introspection (as python-control's docstrings_test does).

Public: the package's API (``servofmu.__all__``), and in every module the functions and classes of its
``__all__`` with the public methods and properties its classes define.  A docstring says what the thing does, in
which units and what it returns; a dataclass's generated signature (``Name(field: type, ...)``) is not one.  The
docstrings' cross references to ``servofmu.NAME`` must name the API.
"""
from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest

import servofmu

MODULES = sorted(m.name for m in pkgutil.walk_packages(servofmu.__path__, "servofmu.")
                 if not m.name.startswith("servofmu.fmu_models") and m.name != "servofmu.__main__")


def own_doc(obj) -> str:
    """The object's own docstring ('' when it has none: not inherited, not a dataclass's generated one)."""
    if inspect.isclass(obj):
        doc = obj.__dict__.get("__doc__") or ""
        if doc.startswith(f"{obj.__name__}("):  # made by @dataclass from the fields
            return ""
        return doc.strip()
    return (obj.__doc__ or "").strip()


def methods(cls):
    """(name, function) of the public methods and properties ``cls`` defines itself."""
    for name, value in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(value, property):
            yield name, value.fget
        elif isinstance(value, (staticmethod, classmethod)):
            yield name, value.__func__
        elif inspect.isfunction(value):
            yield name, value


def undocumented(module_name: str) -> list[str]:
    module = importlib.import_module(module_name)
    missing = [] if own_doc(module) else ["(module)"]
    for name in getattr(module, "__all__", ()):
        obj = getattr(module, name)
        if not (inspect.isfunction(obj) or inspect.isclass(obj)):
            continue  # constants
        if not own_doc(obj):
            missing.append(name)
        if inspect.isclass(obj) and obj.__module__ == module_name:
            for method, function in methods(obj):
                # an override of a documented method of a base class (argparse's error, ...) keeps its meaning
                inherited = any(inspect.getdoc(getattr(base, method, None)) for base in obj.__mro__[1:]
                                if base is not object and hasattr(base, method))
                if not (function.__doc__ or "").strip() and not inherited:
                    missing.append(f"{name}.{method}")
    return missing


@pytest.mark.parametrize("module_name", MODULES)
def test_public_names_have_docstrings(module_name):
    assert undocumented(module_name) == []


@pytest.mark.parametrize("module_name", [m for m in MODULES if m != "servofmu.version"])
def test_every_module_declares_its_public_names(module_name):
    assert isinstance(getattr(importlib.import_module(module_name), "__all__", None), (list, tuple))


def test_the_api_is_documented():
    missing = [name for name in servofmu.__all__ if not own_doc(getattr(servofmu, name))]
    assert missing == []


def test_cross_references_name_the_api():
    """``:func:`servofmu.X``` and friends in docstrings point at names of the API (or subpackages)."""
    root = Path(servofmu.__file__).parent
    wrong = []
    for path in sorted(root.rglob("*.py")):
        for name in re.findall(r"`servofmu\.([A-Za-z_]\w*)`", path.read_text()):
            is_module = (root / name).is_dir() or (root / f"{name}.py").exists() or name == "fmu_models"  # (shipped)
            if name not in servofmu.__all__ and not is_module:
                wrong.append(f"{path.relative_to(root)}: servofmu.{name}")
    assert wrong == []
