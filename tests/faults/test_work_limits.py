"""Absurd work refused up front (class 6 of the third probe): a search whose options multiply to days is estimated
— its evaluations times the measured time of one — and refused in one line naming the estimate and the option that
raises the bound; nothing is written."""
from __future__ import annotations

import numpy as np
from clitools import assert_one_line_error, run

from test_controller_log import _drive, _simulated_log
from test_tune import fake_result

import servofmu as sf
from servofmu.identification.results import write_result
from servofmu.model.controller import controller_toml


def _closed_loop_log(folder):
    """A short closed-loop log of linear_axis in the docs/control.md drive, as a records file."""
    controller = _drive()
    r, x, command, d = _simulated_log(controller, seconds=0.5)
    t = np.arange(r.size) * controller.sample_time
    np.savetxt(folder / "log.csv", np.column_stack([t, r, x, command, d]), delimiter=",",
               header="t,ref,enc,out,pulse", comments="", fmt="%.17g")
    assert run("import", folder / "log.csv", "--time", "t", "--reference", "ref", "--output-variable", "enc",
               "--kind", "position", "--input", "out", "--disturbance", "pulse",
               "-o", folder / "log.h5").returncode == 0
    (folder / "drive.toml").write_text(controller_toml(controller))
    return folder / "log.h5"


def test_searches_estimated_at_years_are_refused_and_the_limit_can_be_raised(tmp_path):
    log = _closed_loop_log(tmp_path)
    DRIVE = tmp_path / "drive.toml"  # noqa: N806 (the drive of the log, as a file)
    out = tmp_path / "out.h5"
    proc = run("identify", log, "--structure", "linear_axis", "--closed-loop", DRIVE, "--iterations",
               "1000000000", "-o", out)
    assert_one_line_error(proc, "the search (10 particles × 1000000000 iterations", "years on this machine",
                          "--work-limit 8 h", "fewer --iterations")
    proc = run("select", log, "--validate", log, "--closed-loop", DRIVE, "--budget", "1e9", "-o", out)
    assert_one_line_error(proc, "candidates' swarms of up to --budget 1e+09 s each", "--work-limit")
    assert_one_line_error(run("identify", log, "--structure", "linear_axis", "--closed-loop", DRIVE,
                              "--work-limit", "0", "-o", out), "--work-limit must be a positive number of hours")
    assert not out.exists()
    write_result(tmp_path / "r.h5", fake_result(sf.load_plant("linear_axis")))
    proc = run("tune", tmp_path / "r.h5", "axis_controller", "--stroke", "0.02", "--speed", "0.05", "--particles",
               "10000", "--iterations", "100000", "-o", tmp_path / "t.toml")
    assert_one_line_error(proc, "the tuning's swarm (10000 particles × 100000 iterations on 7 plants)",
                          "fewer --particles or --iterations")
    assert not (tmp_path / "t.toml").exists()
    # the estimate is a bound the user may raise: a search just past a tiny limit runs once it is raised
    proc = run("identify", log, "--structure", "linear_axis", "--closed-loop", DRIVE, "--iterations",
               "3000", "--work-limit", "1e-6", "-o", out)
    assert_one_line_error(proc, "the search (10 particles × 3000 iterations")
