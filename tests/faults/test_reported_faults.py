"""The eight groups of faults found by probing servofmu as a user would (disk full, a broken FMU, unbounded work,
FMU parameters, silent corruption, tracebacks, SIGTERM, overwrite rules), each reproduced: every test here failed
before servofmu handled the fault.  (FMU parameters through the FMI API, Model Exchange with v_smooth = 0 among
them: tests/test_fmi_api.py::test_values_the_plant_file_refuses_are_refused_through_the_api.)"""
from __future__ import annotations

import os
import resource
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from harness import AGAINST, assert_one_line, command_env, edit_hdf5, run_here, run_servofmu


def copy(source: Path, folder: Path, name: str | None = None) -> Path:
    target = folder / (name or source.name)
    shutil.copyfile(source, target)
    return target


# ---- 1. a write that fails (disk full, file-size limit) -----------------------------------------------------------
@pytest.mark.parametrize("name, limit", [("measure", 150_000), ("train", 4096)])
def test_1_a_file_size_limit_is_one_line_naming_the_file(inputs, tmp_path, name, limit):
    """``measure`` stores experiments as they finish (a file --resume continues): the limit, above the FMU's
    extracted files, stops it at its second experiment.  ``train`` replaces a previous file only when complete."""
    argv = {"measure": ["measure", inputs["g1_fmu"], "--amplitudes", "2,0.6", "--frequencies", "5", "--workers",
                        "0", "-o", "out.h5"],
            "train": ["train", inputs["ds"], "-o", "out.h5", "--force"]}[name]
    if name == "train":
        (tmp_path / "out.h5").write_bytes(b"previous")

    def at_most():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.RLIM_INFINITY))

    proc = subprocess.run([sys.executable, "-m", "servofmu", *map(str, argv)], cwd=tmp_path, capture_output=True,
                          text=True, preexec_fn=at_most, env=command_env())
    assert_one_line(proc.stderr, proc.returncode, 2, f"servofmu {name}: error: cannot write out.h5: File too large")
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]
    if name == "train":
        assert (tmp_path / "out.h5").read_bytes() == b"previous"
    else:
        rc, err = run_here([*argv, "--resume"], tmp_path)
        assert rc == 0, err


# ---- 2. an FMU whose binary cannot be loaded --------------------------------------------------------------------
def test_2_an_fmu_without_binaries_leaves_no_file_and_a_rerun_works(inputs, tmp_path):
    broken = tmp_path / "g1.fmu"
    with zipfile.ZipFile(inputs["g1_fmu"]) as good, zipfile.ZipFile(broken, "w") as bad:
        for item in good.infolist():
            if not item.filename.startswith("binaries/"):
                bad.writestr(item, good.read(item))
    argv = ["measure", broken, "--amplitudes", "2", "--frequencies", "5", "--workers", "0", "-o", "out.h5"]
    rc, err = run_here(argv, tmp_path)
    assert_one_line(err, rc, 2, "g1.fmu", "cannot load the FMU's binary")
    assert not (tmp_path / "out.h5").exists()
    copy(inputs["g1_fmu"], tmp_path)
    rc, err = run_here(argv, tmp_path)
    assert rc == 0, err


# ---- 3. bounded work ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("frequency, fragment", [("1e9", "FMU steps"), ("1e-9", "more than --max-time 60 s")])
def test_3_a_plan_beyond_the_bounds_is_refused_up_front_with_the_estimate(inputs, tmp_path, frequency, fragment):
    rc, err = run_here(["measure", inputs["g1_fmu"], "--amplitudes", "2", "--frequencies", frequency,
                        "--workers", "0", "-o", "out.h5"], tmp_path)
    assert_one_line(err, rc, 2, f"frequency {float(frequency):g} Hz", fragment)
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.skipif(bool(AGAINST), reason="calls the library in this process")
def test_3_a_running_experiment_reports_its_progress(inputs, tmp_path, monkeypatch):
    """Not only finished experiments: a long one (a high-order plant's) shows how far it is."""
    import servofmu.measurement.measure as measure_module
    from servofmu.runtime import RunOptions

    monkeypatch.setattr(measure_module, "REPORT_EVERY", 0.0)  # report at every period
    seen = []
    run = RunOptions(workers=0, progress=lambda done, total: seen.append((done, total)))
    measure_module.measure(inputs["g1_fmu"], tmp_path / "out.h5", amplitudes=[2.0], frequencies=[5.0], run=run)
    scale = measure_module.PROGRESS_SCALE
    assert all(total == scale for _, total in seen)
    within = [done for done, _ in seen if 0 < done < scale]
    assert within and within == sorted(within)
    assert seen[-1] == (scale, scale)


# ---- 5. silent corruption -----------------------------------------------------------------------------------------
def test_5_a_flipped_bit_in_a_stored_first_harmonic_is_damage(inputs, tmp_path):
    from servofmu.measurement.datafile import read_data_file

    data = copy(inputs["data"], tmp_path)
    image = bytearray(data.read_bytes())
    where = image.find(np.complex128(read_data_file(data).experiments[0].H).tobytes())
    assert where > 0
    image[where + 3] ^= 0x10
    data.write_bytes(bytes(image))
    rc, err = run_here(["identify", data, "--structure", "g1", "--ann", inputs["ann"], "-o", "r.h5"], tmp_path)
    assert_one_line(err, rc, 2, str(data), "checksum")


def edited(source: Path, folder: Path, edit) -> Path:
    return edit_hdf5(copy(source, folder), edit)  # with the digest of what it holds: the readers' checks meet it


def test_5_plot_refuses_nan_and_inf_harmonics(inputs, tmp_path):
    for value in (np.nan, np.inf):
        def edit(f):
            f["experiments/exp_0001"].attrs["H"] = np.complex128(complex(value, 0))
        data = edited(inputs["data"], tmp_path, edit)
        rc, err = run_here(["plot", data, "-o", "bode.png", "--force"], tmp_path)
        assert_one_line(err, rc, 2, str(data), "exp_0001/H", "NaN or Inf")
        assert not (tmp_path / "bode.png").exists()


@pytest.mark.parametrize("command", ["plot", "identify", "dataset"])
def test_5_a_plan_of_the_wrong_length_is_refused(inputs, tmp_path, command):
    def edit(f):
        frequencies = f["plan/frequency"][()]
        del f["plan/frequency"]
        f["plan"].create_dataset("frequency", data=frequencies[:-1])
    data = edited(inputs["data"], tmp_path, edit)
    argv = {"plot": ["plot", data, "-o", "out.png"],
            "identify": ["identify", data, "--structure", "g1", "--ann", inputs["ann"], "-o", "out.h5"],
            "dataset": ["dataset", "g1", "--like", data, "--samples", "10", "-o", "out.h5"]}[command]
    rc, err = run_here(argv, tmp_path)
    assert_one_line(err, rc, 2, str(data), "plan/frequency")


# ---- 6. one line instead of a traceback ----------------------------------------------------------------------------
def test_6_impossible_options_are_one_line(inputs, tmp_path):
    cases = [
        (["dataset", "g1", "--like", inputs["data"], "--samples", "10", "--seed", "-1", "-o", "a.h5"], "seed"),
        (["identify", inputs["data"], "--structure", "g1", "--ann", inputs["ann"], "--seed", "-1", "-o", "b.h5"],
         "seed"),
        (["dataset", "g1", "--like", inputs["data"], "--samples", "1000000000", "-o", "c.h5"], "of memory"),
        (["train", inputs["ds"], "--hidden", "1000000", "-o", "d.h5"], "of memory"),
        (["measure", inputs["g1_fmu"], "--amplitudes", "2", "--frequencies", "5", "--samples-per-period",
          "1000000000", "--workers", "0", "-o", "e.h5"], "samples-per-period"),
    ]
    for argv, fragment in cases:
        rc, err = run_here(argv, tmp_path)
        assert_one_line(err, rc, 2, fragment)
    assert not list(tmp_path.iterdir())


def test_6_a_result_with_nan_parameters_is_refused_by_report_and_export(inputs, tmp_path):
    def edit(f):
        theta = f["theta"][()]
        theta[0] = np.nan
        del f["theta"]
        f.create_dataset("theta", data=theta)
    result = edited(inputs["result"], tmp_path, edit)
    for argv in (["report", result, "-o", "r.html"], ["export", result, "-o", "r.fmu"]):
        rc, err = run_here(argv, tmp_path)
        line = assert_one_line(err, rc, 2, str(result), "theta", "NaN")
        assert "--name" not in line and "compiler" not in line


def test_6_a_very_long_model_name_is_refused_before_the_compiler(tmp_path):
    from servofmu.model.plant import example_files

    text = example_files()["g1"].read_text().replace('name = "g1"', f'name = "{"g" * 300}"')
    (tmp_path / "long.toml").write_text(text)
    rc, err = run_here(["build", "long.toml", "-o", "long.fmu"], tmp_path)
    assert_one_line(err, rc, 2, "long.toml", "at most 64 characters")


# ---- 7. SIGTERM ---------------------------------------------------------------------------------------------------
def wait_for(condition, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "the command never got that far"
        time.sleep(0.05)


def test_7_sigterm_is_one_line_exit_143_and_leaves_no_temporary_folder(inputs, tmp_path):
    temp = tmp_path / "tmp"
    temp.mkdir()
    # long enough (36 experiments, down to 0.2 Hz) to be stopped while its workers hold extracted FMUs
    proc = run_servofmu(["measure", inputs["g1_fmu"], "--amplitudes", "2,1,0.6", "--frequencies",
                         "0.2,0.3,0.5,0.7,1,1.5,2,3,5,7,10,15", "--workers", "2", "-o", "out.h5"], tmp_path, temp)
    wait_for(lambda: any(p.name.startswith("servofmu-") for p in temp.iterdir()))
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert_one_line(err, proc.returncode, 143, "servofmu measure: terminated (SIGTERM)")
    wait_for(lambda: not list(temp.iterdir()), timeout=10)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]


# ---- 8. one overwrite rule, checked before the work ---------------------------------------------------------------
def test_8_every_output_is_refused_if_it_exists_unless_force(inputs, tmp_path):
    cases = {"identify": ["identify", inputs["data"], "--structure", "g1", "--ann", inputs["ann"], "-o", "out"],
             "train": ["train", inputs["ds"], "-o", "out"],
             "export": ["export", inputs["result"], "--format", "toml", "-o", "out"]}
    for name, argv in cases.items():
        (tmp_path / "out").write_text("previous")
        rc, err = run_here(argv, tmp_path)
        assert_one_line(err, rc, 2, "out: exists already", "--force")
        assert (tmp_path / "out").read_text() == "previous"
    rc, err = run_here([*cases["export"], "--force"], tmp_path)
    assert rc == 0, err
    assert (tmp_path / "out").read_text() != "previous"


def test_8_the_fleet_follows_the_same_rule(inputs, tmp_path):
    data = copy(inputs["data"], tmp_path, "A.h5")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "A-result.h5").write_text("previous")
    argv = ["identify", data, "--structure", "g1", "--ann", inputs["ann"], "--output-dir", "out", "--workers", "0"]
    rc, err = run_here(argv, tmp_path)
    assert_one_line(err, rc, 2, "A-result.h5: exists already", "--force")
    rc, err = run_here([*argv, "--force"], tmp_path)
    assert rc == 0, err
    from servofmu.identification.results import read_result
    assert read_result(tmp_path / "out" / "A-result.h5").method == "pso-ann"


@pytest.mark.parametrize("argv", [["train", "{ds}", "-o", "missing/out.h5"],
                                  ["identify", "{data}", "--structure", "g1", "--ann", "{ann}", "-o",
                                   "missing/out.h5"]])
@pytest.mark.skipif(bool(AGAINST), reason="sees the work start in this process")
def test_8_an_unwritable_output_is_refused_before_the_work(inputs, tmp_path, argv, monkeypatch):
    import servofmu.identification.identifier as identifier
    import servofmu.identification.train as train

    def no_work(*args, **kwargs):
        raise AssertionError("the work started")
    monkeypatch.setattr(identifier.PSOANNIdentifier, "fit", no_work)
    monkeypatch.setattr(train, "train_network", no_work)
    rc, err = run_here([a.format(**{k: str(v) for k, v in inputs.items()}) for a in argv], tmp_path)
    assert_one_line(err, rc, 2, "missing/out.h5", "does not exist")
    assert os.listdir(tmp_path) == []
