"""What a real machine's log brings that generated records do not: a reference that never moves, a drive that
saturates, an encoder counter that wraps, a clock with a gap — each one line (or a stated warning), never a
traceback, nothing written; and the EMPS drive's controller file (docs/examples) as its documentation states the
loop."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from clitools import assert_one_line_error, run

from servofmu.errors import ServofmuWarning, UserError
from servofmu.identification.closed_loop import MOSTLY_SATURATED, check_log
from servofmu.model.controller import load_controller

from test_drive_logs import CONTROLLER, IMPORT, STRUCTURE, drive_log, reference_and_pulses, write_log

EMPS = Path(__file__).resolve().parent.parent / "docs" / "examples" / "emps_drive.toml"


def _loop(n=400, limit=350.0):
    t = np.arange(n) * 1e-3
    reference = 0.01 * np.sin(2 * np.pi * t)
    position = reference - 1e-4 * np.cos(2 * np.pi * t)
    command = 0.5 * limit * np.sin(2 * np.pi * 3 * t)
    return reference, position, command


@pytest.mark.parametrize("change, fragment", [
    (lambda r, x, u: (np.full_like(r, 0.2), x, u), "the reference is constant (0.2 m)"),
    (lambda r, x, u: (r, np.full_like(x, 0.1), u), "the encoder position never changes (0.1 m)"),
    (lambda r, x, u: (r, x, np.zeros_like(u)), "the force command never changes (0 N)"),
    (lambda r, x, u: (r, x, 3 * u), "the logged command reaches 525 N, beyond the output limit"),
    (lambda r, x, u: (r, x, np.clip(u, -100, 100)), "held at ±100 N, its largest magnitude, in 5"),
])
def test_logs_a_closed_loop_fit_cannot_use_are_refused_naming_why(change, fragment):
    controller = load_controller(EMPS).with_values(force_limit=350.0)
    with pytest.raises(UserError) as info:
        check_log("log.h5: record r", *change(*_loop()), None, controller)
    assert fragment in str(info.value) and str(info.value).startswith("log.h5: record r: ")


def test_a_constant_reference_with_an_injected_signal_is_a_log_like_any_other():
    reference, position, command = _loop()
    check_log("w", np.zeros_like(reference), position, command, np.sign(np.sin(np.arange(400))),
              load_controller(EMPS).with_values(force_limit=350.0))


def test_a_drive_at_its_limit_most_of_the_time_is_said_in_a_warning():
    reference, position, command = _loop()
    saturated = np.clip(command, -30.0, 30.0)
    assert np.mean(np.abs(saturated) == 30.0) > MOSTLY_SATURATED
    with pytest.warns(ServofmuWarning, match=r"at the output limit ±30 N in [\d.]+ % of the samples"):
        check_log("w", reference, position, saturated, None, load_controller(EMPS).with_values(force_limit=30.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_log("w", reference, position, command, None, load_controller(EMPS).with_values(force_limit=350.0))


def test_the_emps_drive_file_is_the_loop_its_documentation_states():
    """kv·gtau and ±10 V·gtau in newtons, the velocity from the two-sample difference (a window-2 moving average),
    one sample of delay, no integrator."""
    c = load_controller(EMPS)
    gtau, kv = 35.15065188, 243.45
    assert c["kp_velocity"] == pytest.approx(kv * gtau, rel=1e-12) and c["kp_position"] == 160.18
    assert c["force_limit"] == pytest.approx(10 * gtau, rel=1e-12) and c["ki_velocity"] == 0
    assert (c["delay"], c["velocity_filter"], c["filter_window"]) == (1, 1, 2)


def _write(tmp_path, edit, seconds=0.3):
    (tmp_path / "drive.toml").write_text(CONTROLLER)
    (tmp_path / "structure.toml").write_text(STRUCTURE)
    log = drive_log(*reference_and_pulses(seconds, 5), seed=5)
    edit(log)
    write_log(tmp_path / "log.csv", log)
    return tmp_path / "log.csv"


def test_an_encoder_that_wraps_is_refused_at_import(tmp_path):
    def wrap(log):  # a 16-bit counter of 1 µm counts overflows at sample 151
        log["enc"][150:] -= 2 ** 16 * 1e-6
    proc = run("import", _write(tmp_path, wrap), *IMPORT, "-o", tmp_path / "log.h5")
    assert_one_line_error(proc, "column 'enc' jumps by -0.065", "from sample 150 to 151", "an encoder counter's overflow?")
    assert not (tmp_path / "log.h5").exists()


def test_a_log_with_a_one_second_gap_in_its_clock_is_refused_at_import(tmp_path):
    def gap(log):
        log["stamp"][150:] += 1.0
    proc = run("import", _write(tmp_path, gap), *IMPORT, "-o", tmp_path / "log.h5")
    assert_one_line_error(proc, "sample 151", "a missing sample?")
    assert not (tmp_path / "log.h5").exists()


def test_a_log_whose_reference_never_moves_is_refused_by_identify_and_select(tmp_path):
    def still(log):
        log["ref"][:] = log["ref"][0]
        log["pulse"][:] = 0.0
    path = _write(tmp_path, still)
    assert run("import", path, *IMPORT, "-o", tmp_path / "log.h5").returncode == 0
    proc = run("identify", tmp_path / "log.h5", "--structure", tmp_path / "structure.toml", "--closed-loop",
               tmp_path / "drive.toml", "-o", tmp_path / "r.h5")
    assert_one_line_error(proc, "the reference is constant", "nothing excites the loop")
    assert not (tmp_path / "r.h5").exists()
    proc = run("select", tmp_path / "log.h5", "--validate", tmp_path / "log.h5", "--closed-loop",
               tmp_path / "drive.toml", "--candidates", "coulomb/1", "-o", tmp_path / "s.h5")
    assert_one_line_error(proc)
    assert not (tmp_path / "s.h5").exists()
