"""Run the whole fault-injection suite (tests/faults, every case, also those marked long) and count its cases per
subcommand and kind of fault.

The table goes between the markers of docs/reliability.md (or is printed with --print).  Exit status 1 when a case
failed.

With ``--against REV`` it runs instead the tests of one probe's reported faults twice in one run: against the sources
of the earlier revision REV (from git; the inputs still made by this checkout) and against this checkout, and writes
their outcomes side by side into docs/reliability.md: each test should fail before its fix and pass after.
``--probe first`` (default: tests/faults/test_reported_faults.py), ``--probe second``
(tests/faults/test_second_probe.py), ``--probe inputs``, ``--probe outputs`` or ``--probe controller``
(tests/faults/test_third_probe_*.py: the third probe's inputs and messages, outputs and writes, and closed-loop
controller checks and work limits) chooses the probe.

Usage: python scripts/fault_suite.py [--print] [--against REV [--probe first|second|inputs|outputs|controller]]
       [pytest options...]
"""
from __future__ import annotations

import collections
import io
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "reliability.md"
BEGIN, END = "<!-- fault-suite counts: begin -->", "<!-- fault-suite counts: end -->"
BEFORE_BEGIN = "<!-- reported groups before and after: begin -->"
BEFORE_END = "<!-- reported groups before and after: end -->"
SECOND_BEGIN = "<!-- second probe before and after: begin -->"
SECOND_END = "<!-- second probe before and after: end -->"
# probe -> (its tests, the markers of its before-and-after table)
PROBES = {"first": ("tests/faults/test_reported_faults.py", BEFORE_BEGIN, BEFORE_END),
          "second": ("tests/faults/test_second_probe.py", SECOND_BEGIN, SECOND_END),
          **{name: (f"tests/faults/test_third_probe_{name}.py", f"<!-- third probe, {name}, before and after: begin -->",
                    f"<!-- third probe, {name}, before and after: end -->")
             for name in ("inputs", "outputs", "controller")}}
WRITE_KINDS = {"fsize": "file-size limit", "full": "disk full"}


def classify(module: str, name: str) -> tuple[str, str]:
    """(subcommand, fault kind) of a test case from its module and name."""
    params = re.search(r"\[(.*)\]$", name)
    params = params.group(1).split("-") if params else []
    if module.endswith("test_write_faults"):
        return params[0], WRITE_KINDS[params[1]]
    if module.endswith("test_signals"):
        if name.startswith("test_a_stop_at_any_moment"):  # [SIGNAL-k]: measure with workers, start-up included
            return "measure", f"{params[0]} at any moment"
        if name.startswith("test_a_selection_stopped"):  # [SIGNAL-k]: select with workers
            return "select", f"{params[0]} at any moment"
        return (params[0], params[1]) if params else ("(signal handling)", name.removeprefix("test_"))
    if module.endswith("test_read_faults"):
        reader, fault = re.match(r"(.*?)-(truncated|bit-flip|nan|inf|wrong-shape|1e308|-1e308)$",
                                 name[name.index("[") + 1:-1]).groups()
        return reader, f"damaged input: {fault}"
    if "third_probe" in module:  # test_cN_... or test_tN_...: the third probe's class N
        kind = re.match(r"test_[ct](\d+)_", name)
        return "(third probe)", f"class {kind.group(1)}" if kind else name
    if module.endswith("test_second_probe"):
        item = re.match(r"test_p0?(\d+b?)_", name)
        return "(second probe)", f"item {item.group(1)}" if item else name
    group = re.match(r"test_(\d)_", name)
    return "(reported groups)", f"group {group.group(1)}" if group else name


def pytest_outcomes(where: str, extra: list[str], env: dict) -> tuple[dict[tuple[str, str], str], int]:
    """(classname, name) -> passed | skipped | failed of every case, and pytest's exit status."""
    with tempfile.TemporaryDirectory(prefix="fault-suite-") as tmp:
        report = Path(tmp) / "junit.xml"
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", where,
                               f"--junitxml={report}", *extra], cwd=ROOT,
                              env={**os.environ, "SERVOFMU_FAULTS": "all", **env})
        if not report.exists():  # pytest could not run (its own message above): no table to make
            raise SystemExit(f"fault_suite: pytest ended with status {proc.returncode} before running any case")
        outcomes = {}
        for case in ET.parse(report).getroot().iter("testcase"):
            key = case.get("classname", ""), case.get("name", "")
            failed = case.find("failure") is not None or case.find("error") is not None
            if outcomes.get(key) != "failed":  # an error in the teardown is a second entry of the same case
                outcomes[key] = "failed" if failed else "skipped" if case.find("skipped") is not None else "passed"
    return outcomes, proc.returncode


def run(extra: list[str]) -> tuple[dict, int]:
    outcomes, rc = pytest_outcomes("tests/faults", extra, {})
    counts = collections.defaultdict(collections.Counter)
    for (module, name), outcome in outcomes.items():
        counts[classify(module, name)][outcome] += 1
    return counts, rc


def before_and_after(rev: str, tests: str, extra: list[str]) -> str:
    """A probe's ``tests`` against revision ``rev`` and against this checkout, as a table."""
    with tempfile.TemporaryDirectory(prefix="fault-suite-src-") as src:
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, capture_output=True, check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(src, filter="data")
        before, _ = pytest_outcomes(tests, extra, {"SERVOFMU_FAULTS_AGAINST": src})
    after, _ = pytest_outcomes(tests, extra, {})
    lines = [f"| test | before ({rev}) | now |", "|---|---|---|"]
    for key in sorted(after, key=lambda k: k[1]):
        lines.append(f"| `{key[1]}` | {before.get(key, 'not run')} | {after[key]} |")
    return "\n".join(lines)


def write_between(begin: str, end: str, text: str) -> None:
    doc = DOC.read_text()
    start, stop = doc.index(begin) + len(begin), doc.index(end)
    DOC.write_text(doc[:start] + "\n" + text + "\n" + doc[stop:])
    print(f"wrote the table into {DOC.relative_to(ROOT)}")


def table(counts: dict) -> str:
    lines = ["| subcommand | fault | cases | passed | skipped | failed |", "|---|---|---:|---:|---:|---:|"]
    totals = collections.Counter()
    for (command, kind), c in sorted(counts.items()):
        lines.append(f"| {command} | {kind} | {sum(c.values())} | {c['passed']} | {c['skipped']} | {c['failed']} |")
        totals.update(c)
    lines.append(f"| **all** | | **{sum(totals.values())}** | **{totals['passed']}** | **{totals['skipped']}** | "
                 f"**{totals['failed']}** |")
    return "\n".join(lines)


def main() -> int:
    args = sys.argv[1:]
    show = "--print" in args
    rev = None
    if "--against" in args:
        i = args.index("--against")
        rev = args[i + 1]
        del args[i:i + 2]
    probe = "first"
    if "--probe" in args:
        i = args.index("--probe")
        probe = args[i + 1]
        del args[i:i + 2]
    extra = [a for a in args if a != "--print"]
    if rev is not None:
        tests, *markers = PROBES[probe]
        text, rc = before_and_after(rev, tests, extra), 0
    else:
        counts, rc = run(extra)
        text, markers = table(counts), (BEGIN, END)
    if show or not DOC.exists():
        print(text)
    else:
        write_between(*markers, text)
    return 1 if rc else 0


if __name__ == "__main__":
    sys.exit(main())
