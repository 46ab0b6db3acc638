"""The FMUs carry everything needed to rebuild them elsewhere: FMPy's `compile` rebuilds the binary from the
sources and buildDescription.xml alone, and FMPy's validator finds nothing to complain about."""
from __future__ import annotations

import platform
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

OUTPUTS = ["v", "position", "friction_force"]
STARTS = {"excitation_amplitude": 0.6, "excitation_frequency": 0.5}


def without_binaries(source, target):
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            if not item.filename.startswith("binaries/"):
                zout.writestr(item, zin.read(item.filename))
    return target


def run(path, interface):
    return simulate_fmu(str(path), fmi_type=interface, stop_time=1.0, output_interval=0.01, start_values=STARTS,
                        output=OUTPUTS)


@pytest.mark.skipif(shutil.which("cmake") is None, reason="fmpy compile needs cmake, which is not installed")
@pytest.mark.parametrize("version", [3, 2])
def test_fmpy_compile_rebuilds_an_identical_binary_from_the_sources(built_fmu, tmp_path, version):
    original = built_fmu("g2", version)
    stripped = without_binaries(original, tmp_path / "g2.fmu")
    with pytest.raises(Exception, match="cannot be simulated on the current platform"):
        run(stripped, "CoSimulation")  # no binary left: nothing can run it before the rebuild

    proc = subprocess.run([sys.executable, "-m", "fmpy.cli", "compile", str(stripped)], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    identifier = read_model_description(str(stripped)).coSimulation.modelIdentifier
    suffix = {"Darwin": ".dylib", "Windows": ".dll"}.get(platform.system(), ".so")
    with zipfile.ZipFile(stripped) as zf:
        binaries = [n for n in zf.namelist() if n.startswith("binaries/") and n.endswith(identifier + suffix)]
    assert len(binaries) == 1, binaries

    for interface in ("ModelExchange", "CoSimulation"):
        before, after = run(original, interface), run(stripped, interface)
        assert np.array_equal(before["time"], after["time"])
        for name in OUTPUTS:
            assert np.abs(after[name] - before[name]).max() <= 1e-12, (interface, name)
        assert np.abs(before["v"]).max() > 0.1


@pytest.mark.parametrize("name", ["g1", "g2", "stribeck_servo", "lugre_servo"])
@pytest.mark.parametrize("version", [3, 2])
def test_fmpy_validate_finds_no_problems(built_fmu, name, version):
    assert validate_fmu(str(built_fmu(name, version))) == []
