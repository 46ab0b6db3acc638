"""The README's tour, command by command, in an empty folder: every documented command works as written."""
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def tour_commands() -> list[list[str]]:
    text = README.read_text()
    tour = text.split("## A five-minute tour", 1)[1].split("```console", 1)[1].split("```", 1)[0]
    lines = [line[2:] for line in tour.splitlines() if line.startswith("$ servofmu ")]
    return [shlex.split(line) for line in lines]


def test_readme_tour_runs(tmp_path):
    commands = tour_commands()
    assert len(commands) >= 8
    for argv in commands:
        proc = subprocess.run([sys.executable, "-m", "servofmu", *argv[1:]], cwd=tmp_path, capture_output=True,
                              text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
        assert proc.returncode == 0, f"{' '.join(argv)}: {proc.stderr}"
    for name in ("g1.fmu", "g1.csv", "g1.h5", "g1-bode.png", "g1-ann.h5", "g1-result.h5", "g1-validation.html",
                 "g1-report.html",
                 "g1-compare.md", "g1-identified.fmu", "g1-identified.toml"):
        assert (tmp_path / name).stat().st_size > 0, name
    # the identified plant file rebuilds and is close to g1 (a 500-plant ANN, but PSO and polish finish the job)
    text = (tmp_path / "g1-identified.toml").read_text()
    pole = float(re.search(r"poles = \[\[(-?[0-9.e+-]+),", text).group(1))
    assert abs(pole / -10.0 - 1) < 1e-6


# ---------------------------------------------------------------------------
# docs/api.md and the public API
# ---------------------------------------------------------------------------
API_DOC = README.parent / "docs" / "api.md"


def python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_api_example_runs(tmp_path):
    """The docs' Python example, as a script in an empty folder, twice (a script or a notebook is run again): the
    files it names appear, and the plant it prints is the paper's G1."""
    (script,) = python_blocks(API_DOC)
    (tmp_path / "example.py").write_text(script)
    for _ in range(2):
        proc = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
    for name in ("g1.fmu", "g1.h5", "g1-result.h5", "g1-identified.fmu"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert proc.stdout.strip() == "pole -10.000000, Fc+ 0.500000, Fc- 0.400000"


def numpydoc_sections(doc: str) -> set[str]:
    """Section titles of a numpydoc docstring (a title line followed by a line of dashes)."""
    lines = [line.strip() for line in (doc or "").splitlines()]
    return {a for a, b in zip(lines, lines[1:]) if b and set(b) == {"-"} and len(b) == len(a)}


def test_every_public_name_has_a_numpydoc_docstring():
    """Functions document Parameters and Returns; classes their Parameters (a class's call returns the
    instance, its methods document their own Returns)."""
    import inspect

    import servofmu

    assert len(servofmu.__all__) >= 15
    for name in servofmu.__all__:
        obj = getattr(servofmu, name)
        sections = numpydoc_sections(inspect.getdoc(obj))
        needed = {"Parameters"} if inspect.isclass(obj) else {"Parameters", "Returns"}
        assert needed <= sections, f"servofmu.{name}: docstring lacks {', '.join(sorted(needed - sections))}"
        if inspect.isclass(obj):
            for method in ("fit", "result"):
                if hasattr(obj, method):
                    assert {"Parameters", "Returns"} <= numpydoc_sections(inspect.getdoc(getattr(obj, method))), \
                        f"servofmu.{name}.{method}"


def test_numpydoc_check_fails_on_a_bare_docstring():
    assert numpydoc_sections("Do it.\n\nParameters\n----------\nx : int\n") == {"Parameters"}
    assert numpydoc_sections("Do it.") == set()


def test_importing_the_package_loads_no_numerical_code():
    """`import servofmu` is cheap: the API is loaded on first use."""
    code = ("import sys, servofmu; "
            "print(sorted(m for m in ('numpy', 'casadi', 'torch', 'h5py', 'fmpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_closed_loop_commands_of_docs_control_run(tmp_path):
    """docs/control.md's console block, in order, in an empty folder with a reference from rest."""
    text = (README.parent / "docs" / "control.md").read_text()
    block = text.split("```console", 1)[1].split("```", 1)[0]
    commands = [shlex.split(line[2:]) for line in block.splitlines() if line.startswith("$ servofmu ")]
    assert len(commands) == 7
    t = np.arange(0.0, 2.0005, 1e-3)
    x = 0.03 * (1 - np.cos(np.pi * t)) + 0.01 * (1 - np.cos(2 * np.pi * 2.3 * t))
    np.savetxt(tmp_path / "reference.csv", np.column_stack([t, x]), delimiter=",", header="time,position",
               comments="")
    for argv in commands:
        proc = subprocess.run([sys.executable, "-m", "servofmu", *argv[1:]], cwd=tmp_path, capture_output=True,
                              text=True)
        assert proc.returncode == 0, f"{' '.join(argv)}: {proc.stderr}"
    assert "lowers the RMS tracking error" in proc.stdout
    assert (tmp_path / "axis-compensation.html").stat().st_size > 0


def test_drive_log_example_of_docs_control_runs(tmp_path):
    """docs/control.md's "A drive's logs" example as written, in an empty folder: its Python and console blocks in
    document order; the log in volts imports with its clock measured and identifies close to linear_axis."""
    text = (README.parent / "docs" / "control.md").read_text()
    section = text.split("## A drive's logs", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```(python|console)\n(.*?)```", section, flags=re.S)
    assert [kind for kind, _ in blocks] == ["python", "console", "python", "console"]
    outputs = []
    for i, (kind, body) in enumerate(blocks):
        if kind == "python":
            (tmp_path / f"block{i}.py").write_text(body)
            runs = [[sys.executable, f"block{i}.py"]]
        else:
            runs = [[sys.executable, "-m", "servofmu", *shlex.split(line[2:])[1:]] for line in body.splitlines()
                    if line.startswith("$ servofmu ")]
        for argv in runs:
            proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True)
            assert proc.returncode == 0, f"{' '.join(argv)}: {proc.stderr}"
            outputs.append(proc.stdout)
    assert "time stamps every 0.001000008 s" in outputs[-2] and "closed loop (reference, disturbance)" in outputs[-2]
    assert "+8e-06 off the controller's clock" in outputs[-1]
    import servofmu
    from servofmu.identification.prior import identified_mask

    result, plant = servofmu.read_result(tmp_path / "drive-result.h5"), servofmu.load_plant("linear_axis")
    truth = plant.parameter_vector()[identified_mask(plant)]
    assert np.max(np.abs(result.theta / truth - 1)) < 0.01


def test_export_doc_python_control_example_runs(tmp_path):
    """docs/export.md's python-control section as written, in an empty folder: its console block in order, then
    each Python block as a script; the model read back is g1's (pole −10, DC gain 1, Coulomb friction)."""
    text = (README.parent / "docs" / "export.md").read_text()
    section = text.split("### python-control", 1)[1].split("### MATLAB", 1)[0]
    block = section.split("```console", 1)[1].split("```", 1)[0]
    commands = [shlex.split(line[2:]) for line in block.splitlines() if line.startswith("$ servofmu ")]
    assert [c[1] for c in commands] == ["build", "measure", "identify", "export"]
    for argv in commands:
        proc = subprocess.run([sys.executable, "-m", "servofmu", *argv[1:]], cwd=tmp_path, capture_output=True,
                              text=True)
        assert proc.returncode == 0, f"{' '.join(argv)}: {proc.stderr}"
    scripts = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(scripts) == 2
    outputs = []
    for i, script in enumerate(scripts):
        (tmp_path / f"example{i}.py").write_text(script)
        proc = subprocess.run([sys.executable, f"example{i}.py"], cwd=tmp_path, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        outputs.append(proc.stdout.split())
    num, states, model = outputs[0][0], outputs[0][-2], outputs[0][-1]
    assert float(num.strip("[]")) == pytest.approx(10, rel=1e-5) and states == "1" and model == "coulomb"
    dc, fc_pos = map(float, outputs[1])
    assert dc == pytest.approx(1, rel=1e-5) and fc_pos == pytest.approx(0.5, rel=1e-4)
