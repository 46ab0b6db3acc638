"""The package as a user gets it: a wheel built from the repository, installed in a fresh virtual environment
outside the checkout, finds the example plants (package data) and runs the README's first command and the
docs' Python example.

The fresh environment gets the wheel only (pip, no index); its dependencies are borrowed from the test environment
through a path entry (not its .pth files, so the editable install of the checkout stays out of sight).
"""
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    wheels = base / "dist"
    # built from a copy: setuptools writes build/ and the egg-info into the tree it builds, and the test workers
    # that each hold this module's fixture would race there in one checkout
    source = base / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".venv", ".git", "build", "*.egg-info", "__pycache__",
                                                                  ".pytest_cache", "demo-output"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
                    "-w", str(wheels), str(source)], check=True, capture_output=True, cwd=base)
    (wheel,) = wheels.glob("servofmu-*.whl")
    env_dir = base / "fresh"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", str(wheel)],
                   check=True, capture_output=True)
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True).stdout.strip()
    (Path(purelib) / "borrowed-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return wheel, env_dir / "bin", base


def run(program, *args, cwd):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(program), *args], cwd=cwd, capture_output=True, text=True, env=env)


def test_the_wheel_ships_the_example_plants(installed):
    wheel, _, _ = installed
    names = zipfile.ZipFile(wheel).namelist()
    for plant in ("g1", "g2", "stribeck_servo", "lugre_servo"):
        assert f"servofmu/fmu_models/{plant}.toml" in names
    assert "servofmu/fmu/c/servo_core.c" in names and "servofmu/simulation/batch_c/batch_driver.c" in names


def test_the_wheel_ships_every_module_and_c_source_of_the_package(installed):
    wheel, _, _ = installed
    names = set(zipfile.ZipFile(wheel).namelist())
    sources = [p.relative_to(ROOT).as_posix() for p in (ROOT / "servofmu").rglob("*")
               if p.suffix in (".py", ".c", ".h") and "__pycache__" not in p.parts]
    assert sources and not [s for s in sources if s not in names]


def test_the_wheel_is_typed(installed):
    wheel, _, _ = installed
    assert "servofmu/py.typed" in zipfile.ZipFile(wheel).namelist()


def long_description(wheel) -> str:
    with zipfile.ZipFile(wheel) as z:
        (metadata,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        return z.read(metadata).decode().split("\n\n", 1)[1]


def test_the_long_description_points_to_nothing_the_wheel_lacks(installed):
    """The text an index shows: no links to files of the checkout (they break there), no scripts to run."""
    wheel, _, _ = installed
    text = long_description(wheel)
    assert "pip install" in text and "servofmu demo" in text
    links = re.findall(r"\]\(([^)]+)\)", text)
    assert all(re.match(r"https?://", link) for link in links), links
    assert not re.search(r"\b(scripts|docs|tests)/[\w.-]+", text)
    assert ".venv" not in text and "make " not in text


def test_the_long_description_shows_commands_the_tour_runs(installed):
    """Its commands are a subset of the README's tour (run by tests/test_docs.py) and its Python example is the
    one docs/api.md runs, without the print."""
    wheel, _, _ = installed
    text = long_description(wheel)
    readme = (ROOT / "README.md").read_text()
    tour = readme.split("## A five-minute tour", 1)[1].split("```console", 1)[1].split("```", 1)[0]
    shown = [line for line in text.splitlines() if line.startswith("$ servofmu ")]
    assert shown and all(line in tour.splitlines() for line in shown), shown
    (example,) = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    (api,) = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), flags=re.S)
    calls = [line.split("#")[0].strip() for line in example.splitlines()[3:]]
    assert calls and all(call in api for call in calls), calls


def test_installed_wheel_builds_a_named_plant_outside_the_checkout(installed):
    _, bindir, base = installed
    work = base / "build"
    work.mkdir()
    where = run(bindir / "python", "-c", "import servofmu; print(servofmu.__file__)", cwd=work)
    assert where.returncode == 0 and not where.stdout.startswith(str(ROOT)), where.stdout + where.stderr
    proc = run(bindir / "servofmu", "build", "g1", "-o", "g1.fmu", cwd=work)
    assert proc.returncode == 0, proc.stderr
    assert zipfile.is_zipfile(work / "g1.fmu")


def test_installed_wheel_runs_the_api_example(installed):
    _, bindir, base = installed
    work = base / "api"
    work.mkdir()
    (script,) = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), flags=re.S)
    (work / "example.py").write_text(script)
    proc = run(bindir / "python", "example.py", cwd=work)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "pole -10.000000, Fc+ 0.500000, Fc- 0.400000"
