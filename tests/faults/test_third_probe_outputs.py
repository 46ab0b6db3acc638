"""Faults of a third probe about outputs, each reproduced: a test named ``test_tN_...`` is the probe's class N.
Class 2: an output that is another output, an input named by an example's name, or a file servofmu ships; class 3:
values beyond the readers' bounds written (or an appended-to file rewritten) before they are refused; class 5: a run
stopped between its outputs' writes leaving some new and some old.  Every test here failed before servofmu handled
the fault (scripts/fault_suite.py --against shows it)."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from harness import AGAINST, PREVIOUS, assert_one_line, command_env, run_here, run_servofmu

ROOT = Path(__file__).resolve().parents[2]
SELECT = ["select", "{data}", "--validate", "{data2}", "--candidates", "coulomb/1", "--iterations", "5", "--workers",
          "0"]


def argv_of(template: list[str], inputs: dict) -> list[str]:
    return [a.format(**{k: str(v) for k, v in inputs.items()}) for a in template]


# ---- 2. an output destroys another output, an input, or a file servofmu ships ---------------------------------------
@pytest.mark.parametrize("argv, culprit, options", [
    (["tune", "{axis_result}", "{controller_toml}", "--particles", "4", "--iterations", "2", "-o", "T.toml",
      "--report", "T.toml"], "T.toml", ("-o", "--report")),
    ([*SELECT, "-o", "S.h5", "--report", "S.h5"], "S.h5", ("-o", "--report")),
    ([*SELECT, "-o", "S.h5", "--report", "S.toml"], "S.toml", ("--plant", "--report")),  # SELECT.toml, by default
    ([*SELECT, "-o", "S.h5", "--plant", "P.toml", "--report", "P.toml"], "P.toml", ("--plant", "--report")),
    ([*SELECT, "-o", "S.h5", "--result", "R.h5", "--report", "R.h5"], "R.h5", ("--result", "--report")),
], ids=["tune-o-report", "select-o-report", "select-default-plant-report", "select-plant-report",
        "select-result-report"])
def test_t2_two_outputs_of_one_run_that_are_one_file_are_refused_before_any_work(inputs, tmp_path, argv, culprit,
                                                                               options):
    rc, err = run_here(argv_of(argv, inputs), tmp_path)
    assert_one_line(err, rc, 2, culprit, *options)
    assert list(tmp_path.iterdir()) == []


def test_t2_an_output_under_another_name_of_an_existing_output_is_refused(inputs, tmp_path):
    """A hard link: one file under two names; with --force the run would write the page over the controller."""
    (tmp_path / "T.toml").write_bytes(PREVIOUS)
    os.link(tmp_path / "T.toml", tmp_path / "T.html")
    rc, err = run_here(argv_of(["tune", "{axis_result}", "{controller_toml}", "--particles", "4", "--iterations",
                                "2", "-o", "T.toml", "--report", "T.html", "--force"], inputs), tmp_path)
    assert_one_line(err, rc, 2, "T.html", "-o", "--report")
    assert (tmp_path / "T.toml").read_bytes() == PREVIOUS


def test_t2_a_result_of_many_files_is_never_one_of_the_inputs(inputs, tmp_path):
    """`identify A.h5 A-result.h5 --output-dir .`: A's result would go over the second data file."""
    for name in ("a.h5", "a-result.h5"):
        (tmp_path / name).write_bytes(Path(inputs["data"]).read_bytes())
    rc, err = run_here(["identify", "a.h5", "a-result.h5", "--structure", "g1", "--method", "pso", "--iterations",
                        "2", "--workers", "0", "--output-dir", ".", "--force"], tmp_path)
    assert (tmp_path / "a-result.h5").read_bytes() == Path(inputs["data"]).read_bytes()
    assert_one_line(err, rc, 2, "a-result.h5", "is also an input")


@pytest.fixture
def installed(tmp_path) -> Path:
    """A copy of servofmu installed in ``tmp_path/site`` with its examples inside the package, as a wheel installs
    it (the sources under test, so that a run that writes over an example spoils only this copy)."""
    site = tmp_path / "site"
    shutil.copytree(Path(AGAINST or ROOT) / "servofmu", site / "servofmu",
                    ignore=shutil.ignore_patterns("__pycache__", "fmu_models"))
    shutil.copytree(ROOT / "fmu_models", site / "servofmu" / "fmu_models",
                    ignore=shutil.ignore_patterns("__pycache__"))
    return site


@pytest.mark.parametrize("option", ["--plant", "--result"])
def test_t2_a_file_servofmu_ships_is_never_an_output(inputs, tmp_path, installed, option):
    """The example's path given as an output (with --force): refused in one line, the example as it was."""
    example = installed / "servofmu" / "fmu_models" / "axis_controller.toml"
    before = example.read_bytes()
    work = tmp_path / "work"
    work.mkdir()
    proc = subprocess.run([sys.executable, "-m", "servofmu", *argv_of(SELECT, inputs), "-o", "S.h5", option,
                           str(example), "--force"], cwd=work, capture_output=True, text=True,
                          env={**command_env(), "PYTHONPATH": str(installed)}, timeout=600)
    assert_one_line(proc.stderr, proc.returncode, 2, "axis_controller.toml", "servofmu's own package")
    assert example.read_bytes() == before
    assert list(work.iterdir()) == []


def test_t2_an_input_given_by_an_example_name_is_that_file(inputs, tmp_path, monkeypatch):
    """`tune RESULT axis_controller -o PATH` where PATH is the example's file (here a copy the examples are read
    from): the input is that file, so the output is refused as an input."""
    if AGAINST:
        pytest.skip("replaces the examples' folder in this process")
    from servofmu.model import plant

    examples = tmp_path / "examples"
    examples.mkdir()
    (examples / "axis_controller.toml").write_bytes(Path(inputs["controller_toml"]).read_bytes())
    monkeypatch.setattr(plant, "example_files", lambda: {"axis_controller": examples / "axis_controller.toml"})
    rc, err = run_here(["tune", inputs["axis_result"], "axis_controller", "--particles", "4", "--iterations", "2",
                        "-o", examples / "axis_controller.toml", "--force"], tmp_path)
    assert_one_line(err, rc, 2, "axis_controller.toml", "is also an input")
    assert (examples / "axis_controller.toml").read_bytes() == Path(inputs["controller_toml"]).read_bytes()


# ---- 3. a write that a reader would refuse -------------------------------------------------------------------------
@pytest.fixture
def beyond_bounds(inputs, tmp_path) -> Path:
    """The records' CSV with two disturbance columns: d, one of whose values is 1e99 (beyond ±1e100 once scaled by
    35), and e, a pulse of 1 (beyond it scaled by 1e200)."""
    table = np.loadtxt(inputs["records_csv"], delimiter=",", skiprows=1)
    d, e = np.zeros(len(table)), np.zeros(len(table))
    d[len(d) // 2], e[len(e) // 2] = 1e99, 1.0
    path = tmp_path / "bad.csv"
    np.savetxt(path, np.column_stack([table, d, e]), delimiter=",", header="time,u,v,d,e", comments="",
               fmt="%.17g")
    return path


IMPORT = ["--time", "time", "--input", "u", "--output-variable", "v", "--disturbance", "d", "--disturbance-scale",
          "35"]


def test_t3_a_failed_append_leaves_the_target_byte_identical(inputs, tmp_path, beyond_bounds):
    target = tmp_path / "out.h5"
    target.write_bytes(Path(inputs["records"]).read_bytes())
    rc, err = run_here(["import", beyond_bounds, *IMPORT, "--append", "-o", target], tmp_path)
    assert target.read_bytes() == Path(inputs["records"]).read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "out.h5"]
    assert_one_line(err, rc, 2, "bad.csv", "disturbance")


@pytest.mark.parametrize("column, scale", [("d", "35"), ("e", "1e200")])
def test_t3_values_beyond_the_bounds_are_refused_before_the_first_byte(tmp_path, beyond_bounds, column, scale):
    argv = ["import", beyond_bounds, "--time", "time", "--input", "u", "--output-variable", "v", "--disturbance",
            column, "--disturbance-scale", scale, "-o", "out.h5"]
    rc, err = run_here(argv, tmp_path)
    assert not (tmp_path / "out.h5").exists()
    assert_one_line(err, rc, 2, "bad.csv", "disturbance")


def size(path: Path) -> int:
    try:
        return path.stat().st_size
    except FileNotFoundError:  # (the claim's probe, made and removed at once)
        return 0


def entries(folder: Path) -> list[Path]:
    try:
        return list(folder.iterdir())
    except OSError:  # (gone meanwhile, or a file)
        return []


# ---- 5. all outputs of a run, or none ------------------------------------------------------------------------------
STOPPED = {"select": ([*SELECT, "-o", "S.h5", "--report", "S.html", "--force"],
                      ["S.h5", "S.toml", "S-result.h5", "S.html"]),
           "tune": (["tune", "{axis_result}", "{controller_toml}", "--particles", "4", "--iterations", "2", "-o",
                     "T.toml", "--report", "T.html", "--force"], ["T.toml", "T.html"])}


@pytest.mark.parametrize("command", STOPPED)
def test_t5_a_run_stopped_while_it_writes_leaves_every_old_output(inputs, tmp_path, command):
    """`select --force --report` (four outputs) and `tune --force --report` (two) sent SIGTERM as soon as their
    first output is being written (its hidden .part, or the file itself): every output is the old one, or (a
    signal that came after the last rename) every one new — never some of each."""
    work, temp = tmp_path / "work", tmp_path / "tmp"
    work.mkdir()
    temp.mkdir()
    argv, names = STOPPED[command]
    for name in names:
        (work / name).write_bytes(PREVIOUS)
    proc = run_servofmu(argv_of(argv, inputs), work, temp)
    deadline = time.monotonic() + 600
    while proc.poll() is None and time.monotonic() < deadline:
        if any(p.name.endswith(".part") and size(p) > 0 for p in work.iterdir()) or \
                any((work / n).read_bytes() != PREVIOUS for n in names):
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.001)
    out, err = proc.communicate(timeout=120)
    new = {n for n in names if (work / n).read_bytes() != PREVIOUS}
    assert new in (set(), set(names)), (new, err[-2000:])
    if not new:
        assert_one_line(err, proc.returncode, 143, "terminated (SIGTERM)")
    assert sorted(p.name for p in work.iterdir()) == sorted(names)


def test_t5_a_stopped_demo_leaves_its_old_folder(tmp_path):
    """`demo --out D --force` sent SIGTERM as soon as its first file is made (in D, or in its staging folder
    beside it): D holds its old files, as they were, and nothing else; no staging folder is left."""
    work, temp = tmp_path / "work", tmp_path / "tmp"
    (work / "D").mkdir(parents=True)
    temp.mkdir()
    old = {"g1.fmu": PREVIOUS, "g1.h5": PREVIOUS, "notes.txt": b"mine\n"}
    for name, data in old.items():
        (work / "D" / name).write_bytes(data)
    proc = run_servofmu(["demo", "-o", "D", "--force"], work, temp)
    deadline = time.monotonic() + 600
    while proc.poll() is None and time.monotonic() < deadline:
        staging = [p for p in work.iterdir() if p.name.endswith(".part")]
        if any(size(f) > 0 for p in staging for f in entries(p)) or \
                {p.name: p.read_bytes() for p in entries(work / "D") if not p.name.startswith(".")} != old:
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.005)
    out, err = proc.communicate(timeout=120)
    assert {p.name: p.read_bytes() for p in (work / "D").iterdir()} == old
    assert_one_line(err, proc.returncode, 143, "terminated (SIGTERM)")
    assert sorted(p.name for p in work.iterdir()) == ["D"]


@pytest.mark.parametrize("kind", ["tuned controller", "chosen plant"])
def test_t3_every_flipped_bit_of_a_written_toml_file_is_reported_or_harmless(tmp_path, kind):
    """The TOML files select and tune write end with a digest line: one bit flipped anywhere in them is refused
    in one line naming the file, or — in the digest line's own words — leaves the settings read exactly as
    written; never another valid number read silently."""
    from servofmu.errors import UserError
    from servofmu.model.controller import controller_toml, load_controller
    from servofmu.model.plant import load_plant
    from servofmu.text_digest import with_digest

    if kind == "tuned controller":
        text, read = with_digest(controller_toml(load_controller("axis_controller"), "tuned by servofmu tune")), \
            lambda p: load_controller(p).values
    else:
        text, read = with_digest("# chosen by servofmu select\n" + load_plant("g1").to_toml()), \
            lambda p: load_plant(p).parameter_vector().tolist()
    good = tmp_path / "good.toml"
    good.write_text(text)
    expected = read(good)
    data, path = text.encode(), tmp_path / "flipped.toml"
    outcomes = {"reported": 0, "harmless": 0}
    for i in range(len(data)):
        for bit in range(8):
            flipped = bytearray(data)
            flipped[i] ^= 1 << bit
            path.write_bytes(bytes(flipped))
            try:
                got = read(path)
            except UserError as exc:
                assert str(path) in str(exc) and "\n" not in str(exc)
                outcomes["reported"] += 1
                continue
            assert got == expected, (i, bit, bytes(flipped[max(i - 20, 0):i + 20]))
            outcomes["harmless"] += 1
    assert outcomes["reported"] > 0.9 * 8 * len(data), outcomes
