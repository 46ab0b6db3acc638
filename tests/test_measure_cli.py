"""`servofmu measure | import | plot` on the command line: normal use, a run killed with -9 and resumed,
and bad input — one line on stderr, exit status 2, no traceback, existing files untouched."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import h5py
import numpy as np
import psutil
import pytest

from servofmu.cli import main
from servofmu.measurement.datafile import read_data_file
from servofmu.output.plots import bode_points


def run_cli(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse rejects a malformed command line this way
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_measure_then_plot(built_fmu, tmp_path, capsys):
    data = tmp_path / "d.h5"
    code, out, err = run_cli(capsys, "measure", built_fmu("g1"), "--amplitudes", "2.0,0.6", "--frequencies", "1,5",
                             "--workers", "0", "-o", data)
    assert code == 0, err
    assert "4 experiments" in out and "all reached steady state" in out
    ds = read_data_file(data)
    assert ds.complete and ds.provenance["command"].startswith("servofmu measure ")
    assert ds.provenance["tolerance"] == 1e-12 and ds.provenance["excitation"] == "builtin"
    curves = bode_points(ds)  # what the Bode figure draws: one curve per amplitude
    assert list(curves) == ["amplitude 2 N", "amplitude 0.6 N"]
    (f2, h2, ok2), (f06, h06, ok06) = curves.values()
    assert list(f2) == list(f06) == [1.0, 5.0] and ok2.all() and ok06.all()
    assert np.all(np.abs(h06) < 0.5 * np.abs(h2))  # the friction's effect at the lower magnitude
    for what in ("bode", "time"):
        fig = tmp_path / f"{what}.png"
        code, out, err = run_cli(capsys, "plot", data, "--what", what, "-o", fig)
        assert code == 0, err
        assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"wrote {fig}" in out


def test_import_then_plot_records(tmp_path, capsys):
    t = np.arange(3000) / 1000.0
    u = 1.5 * np.sin(2 * np.pi * 2.0 * t)
    v = 0.5 * np.sin(2 * np.pi * 2.0 * t - 0.3)
    csv = tmp_path / "rec.csv"
    np.savetxt(csv, np.column_stack([t, u, v]), delimiter=",", header="time,force,speed", comments="")
    code, out, err = run_cli(capsys, "import", csv, "--time", "time", "--input", "force", "--output-variable", "speed",
                             "-o", tmp_path / "r.h5")
    assert code == 0, err
    assert "sine 2 Hz" in out and "H = 0.3333" in out and "-17.19 deg" in out
    code, out, err = run_cli(capsys, "plot", tmp_path / "r.h5", "-o", tmp_path / "r.png")
    assert code == 0 and (tmp_path / "r.png").stat().st_size > 1000


def stored(path) -> int:
    try:
        with h5py.File(path, "r") as f:
            return len(f["experiments"])
    except (OSError, KeyError):
        return -1


def test_a_killed_run_resumes_without_loss_or_duplication(built_fmu, tmp_path):
    fmu = built_fmu("g2")
    args = ["measure", str(fmu), "--frequencies", "1,2,5,10", "--max-time", "20"]
    data = tmp_path / "killed.h5"
    proc = subprocess.Popen([sys.executable, "-m", "servofmu", *args, "-o", str(data)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    children = []
    try:
        while stored(data) < 1 and proc.poll() is None:
            children = children or psutil.Process(proc.pid).children(recursive=True)
            time.sleep(0.02)
        children = psutil.Process(proc.pid).children(recursive=True) or children
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run ended before it could be killed"
    # the local worker processes notice and end
    gone, alive = psutil.wait_procs(children, timeout=10)
    assert not alive

    partial = read_data_file(data)  # the file opens: it is the last complete version
    assert not partial.complete and 1 <= len(partial.experiments) < 8
    before = {e.index: e.H for e in partial.experiments}

    resumed = subprocess.run([sys.executable, "-m", "servofmu", *args, "--resume", "-o", str(data)],
                             capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    final = read_data_file(data)
    assert final.complete and [e.index for e in final.experiments] == list(range(8))
    assert all(final.experiments[i].H == h for i, h in before.items())

    whole = subprocess.run([sys.executable, "-m", "servofmu", *args, "--workers", "0", "-o",
                            str(tmp_path / "whole.h5")], capture_output=True, text=True)
    assert whole.returncode == 0, whole.stderr
    for a, b in zip(final.experiments, read_data_file(tmp_path / "whole.h5").experiments):
        assert (a.index, a.H, a.dc, a.distortion, a.converged, a.settling_time) == \
               (b.index, b.H, b.dc, b.distortion, b.converged, b.settling_time)
        np.testing.assert_array_equal(a.window.v, b.window.v)
        np.testing.assert_array_equal(a.transient.v, b.transient.v)


@pytest.fixture
def files(built_fmu, tmp_path):
    """An existing measurement, a corrupt and a foreign HDF5 file, a good and a bad CSV."""
    good = tmp_path / "good.h5"
    assert main(["measure", str(built_fmu("g1")), "--amplitudes", "2", "--frequencies", "5", "--workers", "0",
                 "-o", str(good)]) == 0
    corrupt = tmp_path / "corrupt.h5"
    corrupt.write_bytes(good.read_bytes()[:2000])
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["data"] = np.arange(3.0)
    csv = tmp_path / "rec.csv"
    csv.write_text("time,force,speed\n" + "".join(f"{i / 100},{np.sin(i)},{np.cos(i)}\n" for i in range(50)))
    return {"fmu": built_fmu("g1"), "good": good, "corrupt": corrupt, "foreign": foreign, "csv": csv,
            "new": tmp_path / "new.h5", "tmp": tmp_path}


def bad_csv(files, line: str, at: int = 5) -> str:
    rows = files["csv"].read_text().splitlines()
    rows[at] = line
    path = files["tmp"] / f"bad{abs(hash(line))}.csv"
    path.write_text("\n".join(rows) + "\n")
    return str(path)


BAD = [
    (["measure", "{fmu}", "--amplitudes", "2,nan", "-o", "{new}"], "amplitude must be a positive finite number"),
    (["measure", "{fmu}", "--amplitudes", "inf", "-o", "{new}"], "amplitude must be a positive finite number"),
    (["measure", "{fmu}", "--amplitudes", "0", "-o", "{new}"], "amplitude must be a positive finite number, not 0"),
    (["measure", "{fmu}", "--amplitudes", "-2", "-o", "{new}"], "amplitude must be a positive finite number, not -2"),
    (["measure", "{fmu}", "--frequencies", "1,0", "-o", "{new}"], "frequency must be a positive finite number"),
    (["measure", "{fmu}", "--frequencies", "-5", "-o", "{new}"], "frequency must be a positive finite number"),
    (["measure", "{fmu}", "--amplitudes", "two", "-o", "{new}"], "not a comma-separated list of numbers"),
    (["measure", "{fmu}", "--output-variable", "speed", "--frequencies", "1", "-o", "{new}"], "no variable named 'speed'"),
    (["measure", "{fmu}", "--input", "force", "--frequencies", "1", "-o", "{new}"], "no variable named 'force'"),
    (["measure", "{csv}", "--frequencies", "1", "-o", "{new}"], "not an FMU"),
    (["measure", "{fmu}", "--frequencies", "5", "--amplitudes", "2", "-o", "{good}"], "exists already"),
    (["measure", "{fmu}", "--resume", "-o", "{corrupt}"], "not a readable data file"),
    (["measure", "{fmu}", "--resume", "-o", "{foreign}"], "not a servofmu data file"),
    (["measure", "{fmu}", "--frequencies", "5", "--amplitudes", "3", "--resume", "-o", "{good}"], "cannot resume"),
    (["measure", "{fmu}", "--frequencies", "1", "--tolerance", "2", "-o", "{new}"], "tolerance must be in"),
    (["measure", "{fmu}", "--frequencies", "1", "--scheduler", "nowhere", "-o", "{new}"], "is not a scheduler"),
    (["plot", "{corrupt}", "-o", "{tmp}/x.png"], "not a readable data file"),
    (["plot", "{foreign}", "-o", "{tmp}/x.png"], "not a servofmu data file"),
    (["plot", "{tmp}/missing.h5", "-o", "{tmp}/x.png"], "no such data file"),
    (["plot", "{good}", "-o", "{tmp}/nofolder/x.png"], "does not exist"),
    (["import", "{csv}", "--time", "time", "--input", "force", "--output-variable", "velocity", "-o", "{new}"],
     "no column 'velocity'"),
    (["import", "{csv}", "--time", "t", "--input", "force", "--output-variable", "speed", "-o", "{new}"], "no column 't'"),
    (["import", "NAN", "--time", "time", "--input", "force", "--output-variable", "speed", "-o", "{new}"], "line 6: .* nan"),
    (["import", "INF", "--time", "time", "--input", "force", "--output-variable", "speed", "-o", "{new}"], "line 6: .* -inf"),
    (["import", "BACK", "--time", "time", "--input", "force", "--output-variable", "speed", "-o", "{new}"],
     "line 6: time is not strictly increasing"),
    (["import", "{csv}", "--time", "time", "--input", "force", "--output-variable", "speed", "-o", "{good}"], "exists already"),
    (["import", "{csv}", "--time", "time", "--input", "force", "--output-variable", "speed", "--append", "-o", "{corrupt}"],
     "not a readable data file"),
    (["import", "{csv}", "--time", "time", "--input", "force", "--output-variable", "speed", "--append", "-o", "{good}"],
     "records can only be appended to a records file"),
]


@pytest.mark.parametrize("argv, message", BAD, ids=[" ".join(a[:1] + [m[:30]]) for a, m in BAD])
def test_bad_input_is_one_line_exit_2_and_leaves_files_alone(files, capsys, argv, message):
    special = {"NAN": "0.04,nan,1", "INF": "0.04,1,-inf", "BACK": "0.01,1,1"}
    argv = [bad_csv(files, special[a]) if a in special else a.format(**files) for a in argv]
    before = {k: files[k].read_bytes() for k in ("good", "corrupt", "foreign", "csv")}
    code, out, err = run_cli(capsys, *argv)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"servofmu {argv[0]}: error: ") or lines[0].startswith("servofmu ")
    import re
    assert re.search(message, lines[0]), lines[0]
    assert {k: files[k].read_bytes() for k in before} == before
    assert not files["new"].exists()


def test_bad_input_in_a_fresh_process_prints_no_traceback(files):
    proc = subprocess.run([sys.executable, "-m", "servofmu", "measure", str(files["fmu"]), "--amplitudes", "0",
                           "-o", str(files["new"])], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "amplitude must be a positive finite number, not 0" in proc.stderr
