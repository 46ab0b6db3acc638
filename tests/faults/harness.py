"""What every case of the fault-injection suite shares: the subcommands under test, running them (in the driver
process or as a user does), and the checks of a clean failure.

SERVOFMU_FAULTS=all runs every case (scripts/fault_suite.py); by default the cases marked ``long`` are skipped and a
sample remains that still covers every subcommand and every kind of fault.
"""
from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/
from hdf5edit import edit_hdf5  # noqa: E402,F401  (for the suites here)

FULL = os.environ.get("SERVOFMU_FAULTS") == "all"
# SERVOFMU_FAULTS_AGAINST=SRC: the commands under test run from the servofmu sources in SRC (an earlier revision,
# scripts/fault_suite.py --against REV), in subprocesses, while the inputs are still made by this checkout — the way
# to see a test fail on the code before its fix.
AGAINST = os.environ.get("SERVOFMU_FAULTS_AGAINST")
DRIVER = Path(__file__).resolve().parent / "driver.py"
PREVIOUS = b"the previous output, which a failed run must leave as it was\n"


@dataclass(frozen=True)
class Writer:
    """A subcommand that writes ``output`` (in the folder it runs in); ``argv`` names inputs as ``{key}`` of the
    ``inputs`` fixture.  ``previous``: what is at ``output`` before the run — PREVIOUS (replaced with --force),
    None (nothing), or an input key (a partial file the run continues with --resume)."""

    argv: tuple[str, ...]
    output: str
    previous: str | None = "PREVIOUS"
    resumable: bool = False

    def command(self, inputs: dict) -> list[str]:
        return [a.format(**{k: str(v) for k, v in inputs.items()}) for a in self.argv]

    def files(self, inputs: dict, previous: Path) -> dict:
        """name -> source of the files in the folder before the run (``previous``: a file holding PREVIOUS)."""
        if self.previous is None:
            return {}
        return {self.output: str(previous if self.previous == "PREVIOUS" else inputs[self.previous])}


WRITERS = {
    "build": Writer(("build", "g1", "-o", "out.fmu", "--force"), "out.fmu"),
    "simulate": Writer(("simulate", "{g1_fmu}", "--amplitude", "1", "--frequency", "2", "--stop-time", "1", "-o",
                        "out.csv", "--force"), "out.csv"),
    "measure": Writer(("measure", "{g1_fmu}", "--amplitudes", "2,0.6", "--frequencies", "1,5", "--resume", "-o",
                       "out.h5"), "out.h5", previous="partial", resumable=True),
    "import": Writer(("import", "{records_csv}", "--time", "time", "--input", "u", "--output-variable", "v", "-o", "out.h5",
                      "--force"), "out.h5"),
    "plot": Writer(("plot", "{data}", "-o", "out.png", "--force"), "out.png"),
    "dataset": Writer(("dataset", "g1", "--like", "{data}", "--samples", "600", "-o", "out.h5"), "out.h5",
                      previous=None, resumable=True),
    "train": Writer(("train", "{ds}", "-o", "out.h5", "--force"), "out.h5"),
    "identify": Writer(("identify", "{data}", "--structure", "g1", "--ann", "{ann}", "-o", "out.h5", "--force"),
                       "out.h5"),
    "export": Writer(("export", "{result}", "-o", "out.fmu", "--force"), "out.fmu"),
    "compare": Writer(("compare", "{data}", "--structure", "g1", "--methods", "chen2002", "-o", "out.h5",
                       "--force"), "out.h5"),
    "validate": Writer(("validate", "{result}", "{data}", "-o", "out.html", "--force"), "out.html"),
    "report": Writer(("report", "{result}", "--data", "{data}", "-o", "out.html", "--force"), "out.html"),
    "controller": Writer(("controller", "axis_controller", "-o", "out.fmu", "--force"), "out.fmu"),
    "system": Writer(("system", "{plant2_fmu}", "{ctrl2_fmu}", "--reference", "{reference_csv}", "-o", "out.ssp",
                      "--force"), "out.ssp"),
    "cosim": Writer(("cosim", "{axis}", "--engine", "fmpy", "-o", "out.h5", "--force"), "out.h5"),
    "select": Writer(("select", "{data}", "--validate", "{data2}", "--candidates", "coulomb/1", "--iterations", "5",
                      "--workers", "0", "-o", "out.h5", "--force"), "out.h5"),
    "tune": Writer(("tune", "{axis_result}", "{controller_toml}", "--particles", "4", "--iterations", "2", "-o",
                    "out.toml", "--force"), "out.toml"),
    "compensate": Writer(("compensate", "{axis_result}", "--axis", "{axis}", "--engine", "fmpy", "-o", "out.html",
                          "--force"), "out.html"),
}


def resume_command(writer: Writer, inputs: dict) -> list[str]:
    """The command that continues an interrupted run of ``writer``."""
    argv = writer.command(inputs)
    return argv if "--resume" in argv else [*argv, "--resume"]


# ---------------------------------------------------------------------------
# Running
# ---------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def mount_namespace() -> tuple[str, ...] | None:
    """The prefix that runs a command where it may mount a tmpfs (a mount namespace of its own), or None."""
    for prefix in (("unshare", "-m"), ("unshare", "-rm")):
        try:
            probe = subprocess.run([*prefix, "sh", "-c", "mount -t tmpfs -o size=1m tmpfs /mnt && umount /mnt"],
                                   capture_output=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            continue
        if probe.returncode == 0:
            return prefix
    return None


def run_driver(cases: list[dict], folder: Path, in_namespace: bool = False) -> list[dict]:
    """Run ``cases`` (see driver.py) in one driver process; its reports, one per case."""
    prefix = ()
    if in_namespace:
        prefix = mount_namespace()
        if prefix is None:
            pytest.skip("no tmpfs can be mounted here (no mount namespace); the file-size limit cases cover "
                        "write failures")
    spec = folder / "cases.json"
    spec.write_text(json.dumps(cases))
    proc = subprocess.run([*prefix, sys.executable, str(DRIVER), str(spec)], capture_output=True, text=True,
                          cwd=folder)
    reports = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    assert proc.returncode == 0, (f"the driver died (status {proc.returncode}) in case "
                                  f"{cases[len(reports)]['id'] if len(reports) < len(cases) else '?'}: "
                                  f"{proc.stderr[-2000:]}")
    assert len(reports) == len(cases)
    return reports


def command_env(**extra: str) -> dict:
    """The environment of a servofmu process under test."""
    return {**os.environ, **extra, **({"PYTHONPATH": AGAINST} if AGAINST else {})}


def run_here(argv, cwd: Path) -> tuple[int, str]:
    """``servofmu ARGV`` in this process (quicker than a subprocess), run in ``cwd``: (exit status, stderr)."""
    if AGAINST:
        proc = subprocess.run([sys.executable, "-m", "servofmu", *map(str, argv)], cwd=cwd, env=command_env(),
                              capture_output=True, text=True)
        return proc.returncode, proc.stderr
    from servofmu.cli import main

    err, here = io.StringIO(), os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            try:
                rc = main([str(a) for a in argv])
            except SystemExit as exc:  # argparse
                rc = exc.code
    finally:
        os.chdir(here)
    return rc, err.getvalue()


def ctrl_c_as_in_a_terminal(then=None):
    """A ``preexec_fn``: Ctrl-C's default restored first (a test run started in the background — ``nohup``,
    ``cmd &`` — ignores SIGINT, and servofmu, like any command, keeps an ignored Ctrl-C ignored), then ``then``."""
    def preexec():
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if then is not None:
            then()
    return preexec


def run_servofmu(argv, cwd: Path, tmpdir: Path, preexec_fn=None, **kwargs) -> subprocess.Popen:
    """``python -m servofmu ARGV`` as a user starts it from a terminal, in a session of its own (Ctrl-C goes to
    its group)."""
    return subprocess.Popen([sys.executable, "-m", "servofmu", *map(str, argv)], cwd=cwd,
                            env=command_env(TMPDIR=str(tmpdir)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=ctrl_c_as_in_a_terminal(preexec_fn), **kwargs)


# ---------------------------------------------------------------------------
# Checks
# ---------------------------------------------------------------------------
_BAR = re.compile(r"^(?:[^|\r\n]*: )?\s*\d+%\|")  # a bar, after its label ("measure: ")
_PROGRESS = re.compile(r"^running \S+ \.\.\.$")  # compare's progress: one line per method


def error_lines(stderr: str) -> list[str]:
    """The lines of stderr other than progress (bar refreshes, which end in carriage returns; compare's
    lines)."""
    return [line for line in re.split(r"[\r\n]", stderr)
            if line.strip() and not _BAR.match(line) and not _PROGRESS.match(line)]


def assert_one_line(stderr: str, rc, expected_rc: int, *fragments: str) -> str:
    """The command ended as a failure should: status ``expected_rc`` (no crash signal), one line on stderr that
    holds every fragment, no traceback.  Returns the line."""
    lines = error_lines(stderr)
    assert rc == expected_rc, (rc, stderr[-3000:])
    assert "Traceback" not in stderr and len(lines) == 1, stderr[-3000:]
    assert lines[0].startswith("servofmu "), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def no_partial_files(names) -> None:
    names = list(names)
    assert not [n for n in names if n.endswith(".part")], names


def sample(cases: list, every: int) -> list:
    """Every case; all but every ``every``-th (deterministic, spread over the table) marked ``long``: skipped
    unless SERVOFMU_FAULTS=all (scripts/fault_suite.py)."""
    return [case if i % every == 0 else pytest.param(*case, marks=pytest.mark.long) for i, case in enumerate(cases)]


# ---------------------------------------------------------------------------
# Damage
# ---------------------------------------------------------------------------
def stored_ranges(path: Path, names=None) -> list[tuple[str, int, int]]:
    """(dataset, first byte, byte count) of every stored piece (chunk, or contiguous block) of the file's numeric
    datasets (or of ``names``): where a flipped bit damages an array."""
    import h5py

    ranges = []
    with h5py.File(path, "r") as f:
        found = []
        f.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset)
                     and obj.dtype.kind in "biufc" and obj.size else None)
        for name in names or found:
            ds = f[name]
            if ds.chunks is None:
                if ds.id.get_offset() is not None:
                    ranges.append((name, ds.id.get_offset(), ds.id.get_storage_size()))
                continue
            for k in range(ds.id.get_num_chunks()):
                info = ds.id.get_chunk_info(k)
                ranges.append((name, info.byte_offset, info.size))
    return ranges


def flip_bit(path: Path, rng, names=None) -> str:
    """Flip one bit, drawn with ``rng``, in the stored arrays of ``path``; the dataset it fell in."""
    ranges = stored_ranges(path, names)
    sizes = [n for _, _, n in ranges]
    k = int(rng.integers(sum(sizes)))
    for name, offset, n in ranges:
        if k < n:
            with open(path, "r+b") as fh:
                fh.seek(offset + k)
                byte = fh.read(1)[0]
                fh.seek(offset + k)
                fh.write(bytes([byte ^ (1 << int(rng.integers(8)))]))
            return name
        k -= n
    raise AssertionError("unreachable")
