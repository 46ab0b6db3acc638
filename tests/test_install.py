"""What a default install promises, checked in this environment: the command line loads neither torch nor the
extras' packages to parse its options; a feature of an extra that is missing says which extra in one line; the
library's warnings go through ``warnings.warn`` and the command line shows each as one line; a script that starts
worker processes outside ``if __name__ == "__main__":`` is told so, by file and line, before any worker starts.

The wheel itself, installed with no extras in a fresh environment, runs the demo and the README's tour in
scripts/check_install.sh (CI, after the suite).
"""
import os
import subprocess
import sys
import tomllib
import warnings
from pathlib import Path

import pytest

from servofmu.errors import ServofmuWarning, UserError
from servofmu.runtime import optional_import, show_warnings

ROOT = Path(__file__).resolve().parent.parent
HEAVY = ("torch", "dask", "distributed", "control", "libcosimpy")


def python(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd,
                          env={**os.environ, **(env or {})})


@pytest.mark.parametrize("argv", [["--help"], ["identify", "--help"], ["validate", "--help"], ["report", "--help"],
                                  ["export", "--help"], ["cosim", "--help"]])
def test_the_command_line_parses_without_torch_or_the_extras(argv):
    code = ("import runpy, sys\nsys.argv = ['servofmu', *sys.argv[1:]]\ntry:\n"
            "    runpy.run_module('servofmu', run_name='__main__')\nexcept SystemExit:\n    pass\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))")
    proc = python("-c", code, *argv)
    assert proc.stdout.strip().splitlines()[-1] == "[]", proc.stdout[-500:] + proc.stderr[-2000:]


def test_the_dependencies_leave_the_extras_out():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = [d.split(";")[0].split("[")[0].split(">")[0].split("=")[0].split("<")[0].strip()
             for d in project["dependencies"]]
    assert "dask" not in names and "control" not in names and "torch" in names and "libcosimpy" in names
    extras = project["optional-dependencies"]
    assert extras["dask"][0].startswith("dask[distributed]") and extras["control"][0].startswith("control")
    assert extras["notebook"][0].startswith("pandas")
    assert "servofmu[dask,control,notebook]" in extras["test"]  # scripts/setup.sh installs [test]: the suite needs all
    package_data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "py.typed" in package_data["servofmu"] and (ROOT / "servofmu" / "py.typed").is_file()


def test_a_missing_extra_is_named_in_one_line():
    with pytest.raises(UserError) as caught:
        optional_import("servofmu_no_such_module", "a Dask scheduler", "dask")
    assert str(caught.value) == "a Dask scheduler needs dask: pip install 'servofmu[dask]'"
    with pytest.raises(UserError, match=r"load_control needs python-control: pip install 'servofmu\[control\]'"):
        optional_import("servofmu_no_such_module", "load_control", "control", package="python-control")


def test_a_scheduler_without_dask_names_the_extra():
    """distributed made unimportable (None in sys.modules), as where dask is not installed."""
    code = ("import sys\nsys.modules['distributed'] = None\nfrom servofmu.simulation.parallel import Workers\n"
            "from servofmu.errors import UserError\ntry:\n    Workers(scheduler='tcp://127.0.0.1:9').__enter__()\n"
            "except UserError as exc:\n    print(exc)\n")
    proc = python("-c", code)
    assert proc.stdout.strip() == "a Dask scheduler needs dask: pip install 'servofmu[dask]'", proc.stderr


def test_load_control_without_python_control_names_the_extra(tmp_path):
    code = ("import sys\nsys.modules['control'] = None\nfrom servofmu.output.export import load_control\n"
            "from servofmu.errors import UserError\ntry:\n    load_control('nothing.json')\n"
            "except UserError as exc:\n    print(exc)\n")
    proc = python("-c", code, cwd=tmp_path)
    assert proc.stdout.strip() == "load_control needs python-control: pip install 'servofmu[control]'", proc.stderr


def test_cosim_without_libcosimpy_runs_on_fmpy_and_says_so(tmp_path):
    """The default engine falls back to FMPy with one warning where libcosimpy is missing (no wheel for the
    platform); the engine in the result is the one that ran."""
    from servofmu.control import cosim

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        original = cosim.importlib.util.find_spec
        try:
            cosim.importlib.util.find_spec = lambda name, *a: None if name == "libcosimpy" else original(name, *a)
            with pytest.raises(UserError):  # no such archive: the fallback is decided before the archive is read
                cosim.cosimulate(tmp_path / "none.ssp", engine="libcosim")
        finally:
            cosim.importlib.util.find_spec = original
    assert [str(w.message) for w in caught if w.category is ServofmuWarning] == [
        "libcosimpy is not installed (its wheels are for Linux x86_64 and Windows): co-simulating on FMPy instead"]


def test_an_unsettled_experiment_is_a_warning_of_the_callers_line(tmp_path):
    """Without a warn callback, measure's warning reaches ``warnings`` (it was lost), attributed to the caller."""
    import servofmu as sf
    from servofmu.runtime import RunOptions

    sf.build_fmu(sf.load_plant("g1"), tmp_path / "g1.fmu")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        data = sf.measure(tmp_path / "g1.fmu", tmp_path / "g1.h5", amplitudes=[0.6], frequencies=[5.0],
                          options=sf.MeasureOptions(max_time=0.6, tolerance=1e-14), run=RunOptions(workers=0))
    assert [e.converged for e in data.experiments] == [False]
    (warning,) = [w for w in caught if w.category is ServofmuWarning]
    assert str(warning.message).startswith("experiment 0 (amplitude 0.6, frequency 5 Hz) reached no steady state")
    assert warning.filename == __file__


def test_warnings_show_as_one_line_each(capsys):
    def library_call():
        warnings.warn("experiment 3 reached no steady state\nsecond line", ServofmuWarning, stacklevel=2)

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        with show_warnings():
            library_call()
        lines = []
        with show_warnings(lines.append):  # a progress bar's writer
            library_call()
    assert capsys.readouterr().err == "warning: experiment 3 reached no steady state\n"
    assert lines == ["experiment 3 reached no steady state"]
    assert warnings.showwarning is not None and warnings.showwarning.__module__ == "warnings"


# ---------------------------------------------------------------------------
# worker processes and the __main__ guard
# ---------------------------------------------------------------------------
SCRIPT = """\
import operator
from servofmu.simulation.parallel import Workers


def run():
    with Workers(workers=1) as pool:
        print(list(pool.imap(operator.is_not, [1, 2])))

{call}
"""


@pytest.mark.parametrize("guarded", [True, False])
def test_a_script_that_starts_workers_must_guard_its_main(tmp_path, guarded):
    call = 'if __name__ == "__main__":\n    run()' if guarded else "run()"
    (tmp_path / "work.py").write_text(SCRIPT.format(call=call))
    proc = python("work.py", cwd=tmp_path)
    if guarded:
        assert proc.returncode == 0 and sorted(eval(proc.stdout.strip())) == [(0, True), (1, True)], proc.stderr
    else:
        assert proc.returncode != 0
        last = proc.stderr.strip().splitlines()[-1]
        assert last == (f"servofmu.errors.UserError: {tmp_path / 'work.py'}, line 9: starts worker processes outside "
                        '`if __name__ == "__main__":`; each worker imports the script again and would run it too: '
                        "put the script's work under that guard (or pass workers=0 to run in this process)")
        assert "bootstrapping" not in proc.stderr  # refused before a worker started


WARNING_SCRIPT = """\
import warnings
from servofmu.errors import ServofmuWarning
from servofmu.runtime import show_warnings
from servofmu.simulation.parallel import Workers


def task(_, k):
    warnings.warn(f"item {{k % 2}} is odd", ServofmuWarning)
    return k


if __name__ == "__main__":
    with show_warnings(), Workers(workers={workers}) as pool:
        print(sorted(r for _, r in pool.imap(task, [1, 2, 3])))
"""


@pytest.mark.parametrize("workers", [0, 2])
def test_warnings_of_worker_processes_show_as_in_the_main_process(tmp_path, workers):
    """A warning a task issues in a worker process reaches the main process and shows there as it would had the
    task run there: one line each, repeated ones once — not Python's file, line and source, printed by the worker."""
    (tmp_path / "work.py").write_text(WARNING_SCRIPT.format(workers=workers))
    proc = python("work.py", cwd=tmp_path)
    assert proc.returncode == 0 and proc.stdout.strip() == "[1, 2, 3]", proc.stderr
    assert sorted(proc.stderr.splitlines()) == ["warning: item 0 is odd", "warning: item 1 is odd"], proc.stderr


def test_a_package_main_needs_no_guard(tmp_path):
    """python -m package: multiprocessing does not run a package's __main__ again in the workers."""
    package = tmp_path / "job"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "__main__.py").write_text(SCRIPT.format(call="run()"))
    proc = python("-m", "job", cwd=tmp_path)
    assert proc.returncode == 0 and sorted(eval(proc.stdout.strip())) == [(0, True), (1, True)], proc.stderr


def test_the_public_api_is_annotated():
    """py.typed promises annotations: every parameter and return of the names in servofmu.__all__ (and of their
    classes' public methods) has one."""
    import inspect

    import servofmu

    missing = []
    for name in servofmu.__all__:
        obj = getattr(servofmu, name)
        functions = [(name, obj)] if inspect.isfunction(obj) else [
            (f"{name}.{m}", f) for m, f in vars(obj).items()
            if inspect.isfunction(f) and (not m.startswith("_") or m == "__init__")] if inspect.isclass(obj) else []
        for qual, function in functions:
            signature = inspect.signature(function)
            missing += [f"{qual}({p})" for p, v in signature.parameters.items()
                        if v.annotation is inspect.Parameter.empty and p not in ("self", "cls")]
            if signature.return_annotation is inspect.Signature.empty and not qual.endswith("__init__"):
                missing.append(f"{qual} -> ?")
    assert not missing, missing


def test_identify_validate_report_export_run_without_torch_or_the_extras(tmp_path):
    """The commands of a fitted model's life after the measurement, run with torch, dask and python-control made
    unimportable: none of them needs one (identify without --ann)."""
    import servofmu as sf
    from servofmu.runtime import RunOptions

    sf.build_fmu(sf.load_plant("g1"), tmp_path / "g1.fmu")
    sf.measure(tmp_path / "g1.fmu", tmp_path / "g1.h5", amplitudes=[2.0, 0.6], frequencies=[0.5, 2.0, 10.0],
               run=RunOptions(workers=0))
    blocked = ("import runpy, sys\nfor m in ('torch', 'dask', 'distributed', 'control'):\n    sys.modules[m] = None\n"
               "sys.argv = ['servofmu', *sys.argv[1:]]\nrunpy.run_module('servofmu', run_name='__main__')\n")
    for argv in (["identify", "g1.h5", "--structure", "g1", "--method", "pso", "-o", "g1-result.h5"],
                 ["validate", "g1-result.h5", "g1.h5", "-o", "g1-validation.html"],
                 ["report", "g1-result.h5", "-o", "g1-report.html"],
                 ["export", "g1-result.h5", "-o", "g1-identified.fmu"]):
        proc = python("-c", blocked, *argv, cwd=tmp_path)
        assert proc.returncode == 0, f"{argv[0]}: {proc.stderr}"
