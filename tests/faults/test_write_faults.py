"""Every writing subcommand against a full disk (a tmpfs that has a given number of bytes left, the temporary
directory on it or not) and a file-size limit (RLIMIT_FSIZE): one line naming the file and the OS's reason, exit
status 2, no crash, the previous file as it was (or, for a run that continues a file, every experiment it held),
no partial file, nothing left in the temporary directory; and --resume after it finishes identical to a run
without the fault."""
from __future__ import annotations

import numpy as np
import pytest
from harness import PREVIOUS, WRITERS, assert_one_line, no_partial_files, resume_command, run_driver, sample

# Where the write fails: the file-size limit or the free space, as a fraction of the complete output's size.
FRACTIONS = (0.0, 0.3, 0.7, 0.95)
REASONS = ("No space left on device", "File too large")


@pytest.fixture(scope="session")
def reference(inputs, tmp_path_factory):
    """Every writer run once without a fault: its output (kept) and size."""
    folder = tmp_path_factory.mktemp("reference-runs")
    previous = folder / "previous"
    previous.write_bytes(PREVIOUS)
    cases = [{"id": name, "argv": w.command(inputs), "folder": str(folder / "run" / name),
              "files": w.files(inputs, previous), "keep": str(folder / "out" / name)} for name, w in WRITERS.items()]
    out = {}
    for case, report in zip(cases, run_driver(cases, folder)):
        assert report["rc"] == 0, (case["id"], report["stderr"][-2000:])
        path = folder / "out" / case["id"] / WRITERS[case["id"]].output
        out[case["id"]] = {"path": path, "size": path.stat().st_size}
    return out


def cases() -> list[tuple[str, str, float, bool]]:
    """(writer, fault kind, fraction, temporary directory on the full file system)."""
    table = []
    for i, name in enumerate(WRITERS):
        for j, fraction in enumerate(FRACTIONS):
            table.append((name, "fsize", fraction, False))
            table.append((name, "full", fraction, (i + j) % 2 == 0))
    return sample(table, every=8)


def same_measurement(a, b) -> None:
    from servofmu.measurement.datafile import read_data_file

    a, b = read_data_file(a), read_data_file(b)
    assert [e.index for e in a.experiments] == [e.index for e in b.experiments]
    for x, y in zip(a.experiments, b.experiments):
        assert (x.H, x.dc) == (y.H, y.dc)
        np.testing.assert_array_equal(x.window.v, y.window.v)
        np.testing.assert_array_equal(x.transient.v, y.transient.v)


def same_training_set(a, b) -> None:
    from servofmu.identification.training_set import load_training_set

    a, b = load_training_set(a), load_training_set(b)
    for name in ("parameters", "H", "dc", "converged", "done"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize("name, kind, fraction, temp_on_fault", cases(),
                         ids=lambda v: f"{v:g}" if isinstance(v, float) else str(v))
def test_a_failed_write_is_one_line_and_damages_nothing(inputs, reference, tmp_path, name, kind, fraction,
                                                        temp_on_fault):
    writer = WRITERS[name]
    previous = tmp_path / "previous"
    previous.write_bytes(PREVIOUS)
    limit = int(fraction * reference[name]["size"])
    fault = {"kind": kind, "limit": limit} if kind == "fsize" else {"kind": kind, "free": limit}
    case = {"id": name, "argv": writer.command(inputs), "folder": str(tmp_path / "fs"), "fault": fault,
            "temp_on_fault": temp_on_fault, "files": writer.files(inputs, previous), "keep": str(tmp_path / "kept")}
    [report] = run_driver([case], tmp_path, in_namespace=kind == "full")
    assert report["uncaught"] is None, report
    line = assert_one_line(report["stderr"], report["rc"], 2)
    assert any(reason in line for reason in REASONS), line
    assert writer.output in line or "tmp" in line, line  # the culprit: the output, or a temporary file
    assert not report["temp_left"], report["temp_left"]
    no_partial_files(report["after"])
    kept = tmp_path / "kept" / writer.output
    if writer.resumable:
        if writer.previous is not None:  # what the file held before is still there
            same_measurement_prefix(inputs[writer.previous], kept)
        finish = {"id": f"{name}-resume", "argv": resume_command(writer, inputs), "folder": str(tmp_path / "again"),
                  "files": {writer.output: str(kept)} if kept.exists() else {}, "keep": str(tmp_path / "done")}
        [again] = run_driver([finish], tmp_path)
        assert again["rc"] == 0, again["stderr"][-2000:]
        (same_measurement if name == "measure" else same_training_set)(tmp_path / "done" / writer.output,
                                                                         reference[name]["path"])
    else:
        assert report["after"] == report["before"]  # the previous file as it was, nothing else


def same_measurement_prefix(before, after) -> None:
    """Every experiment ``before`` held is in ``after``, unchanged."""
    from servofmu.measurement.datafile import read_data_file

    old, new = read_data_file(before), {e.index: e for e in read_data_file(after).experiments}
    for e in old.experiments:
        assert new[e.index].H == e.H
        np.testing.assert_array_equal(new[e.index].window.v, e.window.v)
