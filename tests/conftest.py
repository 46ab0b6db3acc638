"""Fixtures shared by the test modules, and the temporary-directory check every test passes."""
from __future__ import annotations

import gc
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

# Every test runs with a temporary directory of this session's own (inherited by the commands it starts), so that
# what servofmu leaves there is seen: nothing may be left by any test (no_temporary_leftovers).
SESSION_TMP = Path(tempfile.mkdtemp(prefix="servofmu-tests-"))


def pytest_configure(config):
    import importlib.util

    missing = [m for m in ("servofmu", "h5py", "numpy", "scipy", "casadi", "fmpy")
               if importlib.util.find_spec(m) is None]
    if missing:  # a bare `pytest` outside the environment the test command makes
        raise pytest.UsageError(f"{', '.join(missing)} not importable by {sys.executable}: run the test command, "
                                "`bash scripts/test.sh` (it makes .venv with everything the suite needs)")
    os.environ["TMPDIR"] = str(SESSION_TMP)
    tempfile.tempdir = None


def pytest_unconfigure(config):
    shutil.rmtree(SESSION_TMP, ignore_errors=True)


def _leftovers(before: set) -> set:
    """servofmu's temporary folders (other libraries' are theirs to keep), and the fault driver's; not those this
    process still holds (FMUs of in-process runs, cached for the next run and removed at exit)."""
    from servofmu.runtime import _folders as held

    return {p.name for p in SESSION_TMP.iterdir()
            if p.name.startswith(("servofmu-", "fault-driver-")) and str(p) not in held} - before


@pytest.fixture(autouse=True)
def no_temporary_leftovers():
    """The test leaves nothing in the temporary directory (worker processes of a killed command get a few seconds
    to notice and remove their folders)."""
    before = _leftovers(set())
    yield
    gc.collect()  # FMUs run in this process are removed with their objects
    deadline = time.monotonic() + 10
    while _leftovers(before) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _leftovers(before), f"left in the temporary directory: {sorted(_leftovers(before))}"


@pytest.fixture(scope="session")
def built_fmu(tmp_path_factory):
    """``built_fmu(name, version)``: the plant ``fmu_models/<name>.toml`` as an FMI ``version``.0 FMU.

    Each FMU is built once per session; treat the file as read-only (copy it before changing it).
    """
    from servofmu.fmu import build_fmu
    from servofmu.model.plant import load_plant

    folder = tmp_path_factory.mktemp("built_fmus")
    cache = {}

    def build(name: str, version: int = 3):
        key = (name, int(version))
        if key not in cache:
            cache[key] = build_fmu(load_plant(name), folder / f"{name}_fmi{version}.fmu", fmi_version=int(version))
        return cache[key]

    return build


@dataclass(frozen=True)
class FmuLayout:
    """Value references of a servofmu FMU, from the fixed layout of docs/fmu.md:
    0 time, 1 u, 2 v, 3 position (also the position state), 4 friction_force, 1000+i parameters,
    2000+i states, 3000+i state derivatives."""

    parameters: dict      # name -> value reference
    states: list          # value references of the continuous states, in state-vector order
    derivatives: list     # value references of their derivatives
    state_names: tuple

    TIME, U, V, POSITION, FRICTION_FORCE = 0, 1, 2, 3, 4

    @property
    def nx(self) -> int:
        return len(self.states)


@pytest.fixture(scope="session")
def fmu_layout():
    """``fmu_layout(name)``: the value references of the FMU of plant ``name`` (see FmuLayout)."""
    from servofmu.model.plant import load_plant
    from servofmu.model.symbolic import build_model

    def layout(name: str) -> FmuLayout:
        model = build_model(load_plant(name))
        names = tuple(model.state_names)
        return FmuLayout(parameters={p: 1000 + i for i, p in enumerate(model.parameter_names)},
                         states=[FmuLayout.POSITION if n == "position" else 2000 + i for i, n in enumerate(names)],
                         derivatives=[3000 + i for i in range(len(names))], state_names=names)

    return layout
