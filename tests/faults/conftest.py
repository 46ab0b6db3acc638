"""Inputs of the fault-injection suite, made once per session: one of every kind of file servofmu reads."""
from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))


def pytest_collection_modifyitems(config, items):
    from harness import FULL

    if not FULL:
        skip = pytest.mark.skip(reason="a long fault case: SERVOFMU_FAULTS=all runs it (scripts/fault_suite.py)")
        for item in items:
            if item.get_closest_marker("long"):
                item.add_marker(skip)


def servofmu(*argv) -> None:
    """Run a command in this process (quicker than a subprocess); it must succeed."""
    from servofmu.cli import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    assert rc == 0, (argv, err.getvalue())


def write_record_csv(path: Path) -> Path:
    """A sinusoidal record of a first-order plant (velocity column v)."""
    t = np.arange(0, 4, 1e-3)
    u = 2.0 * np.sin(2 * np.pi * 2.0 * t)
    v = np.zeros_like(t)
    for i in range(1, t.size):
        v[i] = v[i - 1] + 1e-3 * (-10 * v[i - 1] + 10 * (u[i - 1] - 0.5 * np.tanh(v[i - 1] / 1e-3)))
    np.savetxt(path, np.column_stack([t, u, v]), delimiter=",", header="time,u,v", comments="")
    return path


def write_reference_csv(path: Path) -> Path:
    t = np.arange(0.0, 1.0005, 1e-3)
    x = 0.03 * (1 - np.cos(2 * np.pi * t))
    np.savetxt(path, np.column_stack([t, x]), delimiter=",", header="time,position", comments="")
    return path


@pytest.fixture(scope="session")
def inputs(tmp_path_factory, built_fmu) -> dict[str, Path]:
    """name -> file: the FMUs, data, training set, network, results, records, system and plain-text inputs that
    the subcommands read."""
    from servofmu.identification.prior import identified_mask, identified_names
    from servofmu.identification.results import Result, Stage, write_result
    from servofmu.measurement.datafile import add_experiments, create_measurement, read_data_file
    from servofmu.model.plant import example_files, load_plant

    d = tmp_path_factory.mktemp("fault-inputs")
    f = {"g1_fmu": d / "g1.fmu", "data": d / "data.h5", "data2": d / "data2.h5", "partial": d / "partial.h5", "records_csv": d / "rec.csv",
         "records": d / "rec.h5", "ds": d / "ds.h5", "ann": d / "ann.h5", "result": d / "result.h5",
         "plant2_fmu": d / "plant2.fmu", "ctrl2_fmu": d / "ctrl2.fmu", "reference_csv": d / "ref.csv",
         "axis": d / "axis.ssp", "axis_result": d / "axis-result.h5", "plant_toml": d / "plant.toml",
         "controller_toml": d / "ctrl.toml"}
    f["g1_fmu"].write_bytes(built_fmu("g1", 3).read_bytes())
    servofmu("measure", f["g1_fmu"], "--amplitudes", "2,0.6", "--frequencies", "1,5", "--workers", "0", "-o", f["data"])
    # another measurement of the same axis and plan at other frequencies: what `select` validates on
    servofmu("measure", f["g1_fmu"], "--amplitudes", "2,0.6", "--frequencies", "2,4", "--workers", "0", "-o",
             f["data2"])
    data = read_data_file(f["data"])  # the first half of it, as an interrupted run leaves it
    create_measurement(f["partial"], data.plan, data.provenance, data.parameters)
    add_experiments(f["partial"], data.experiments[:2])
    write_record_csv(f["records_csv"])
    servofmu("import", f["records_csv"], "--time", "time", "--input", "u", "--output-variable", "v", "-o", f["records"])
    servofmu("dataset", "g1", "--like", f["data"], "--samples", "200", "-o", f["ds"])
    servofmu("train", f["ds"], "-o", f["ann"])
    servofmu("identify", f["data"], "--structure", "g1", "--ann", f["ann"], "-o", f["result"])
    servofmu("build", "linear_axis", "--fmi-version", "2", "-o", f["plant2_fmu"])
    servofmu("controller", "axis_controller", "--fmi-version", "2", "-o", f["ctrl2_fmu"])
    servofmu("system", f["plant2_fmu"], f["ctrl2_fmu"], "--reference", write_reference_csv(f["reference_csv"]),
             "-o", f["axis"])
    axis = load_plant("linear_axis")  # a result of the axis's structure, at its true values: for `compensate`
    theta = axis.parameter_vector()[identified_mask(axis)]
    write_result(f["axis_result"], Result(
        method="pso", structure=axis, plant=axis, names=tuple(identified_names(axis)), theta=theta,
        intervals=np.column_stack([theta, theta]), fitness=0.0, seconds=0.0, evaluations=0,
        stages=(Stage("pso", None, 0.0, 0.0, 0),), history=np.zeros(1), provenance={}))
    f["plant_toml"].write_text(example_files()["g1"].read_text())
    f["controller_toml"].write_text(example_files()["axis_controller"].read_text())
    return f
