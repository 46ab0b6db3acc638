"""Run the whole fault-injection suite (tests/faults, every case, also those marked long) and count its cases per
subcommand and kind of fault.

The table goes between the markers of docs/reliability.md (or is printed with --print).  Exit status 1 when a case
failed.

Usage: python scripts/fault_suite.py [--print] [pytest options...]
"""
from __future__ import annotations

import collections
import os
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "reliability.md"
BEGIN, END = "<!-- fault-suite counts: begin -->", "<!-- fault-suite counts: end -->"
WRITE_KINDS = {"fsize": "file-size limit", "full": "disk full"}


def classify(module: str, name: str) -> tuple[str, str]:
    """(subcommand, fault kind) of a test case from its module and name."""
    params = re.search(r"\[(.*)\]$", name)
    params = params.group(1).split("-") if params else []
    if module.endswith("test_write_faults"):
        return params[0], WRITE_KINDS[params[1]]
    if module.endswith("test_signals"):
        return params[0], params[1]
    if module.endswith("test_read_faults"):
        reader, fault = re.match(r"(.*?)-(truncated|bit-flip|nan|inf|wrong-shape|1e308|-1e308)$",
                                 name[name.index("[") + 1:-1]).groups()
        return reader, f"damaged input: {fault}"
    group = re.match(r"test_(\d)_", name)
    return "(reported groups)", f"group {group.group(1)}" if group else name


def run(extra: list[str]) -> tuple[dict, int]:
    with tempfile.TemporaryDirectory(prefix="fault-suite-") as tmp:
        report = Path(tmp) / "junit.xml"
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/faults",
                               f"--junitxml={report}", *extra], cwd=ROOT, env={**os.environ, "SERVOFMU_FAULTS": "all"})
        counts = collections.defaultdict(collections.Counter)
        for case in ET.parse(report).getroot().iter("testcase"):
            key = classify(case.get("classname", ""), case.get("name", ""))
            outcome = "failed" if case.find("failure") is not None or case.find("error") is not None else \
                "skipped" if case.find("skipped") is not None else "passed"
            counts[key][outcome] += 1
    return counts, proc.returncode


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
    show = "--print" in sys.argv
    counts, rc = run([a for a in sys.argv[1:] if a != "--print"])
    text = table(counts)
    if show or not DOC.exists():
        print(text)
    else:
        doc = DOC.read_text()
        start, end = doc.index(BEGIN) + len(BEGIN), doc.index(END)
        DOC.write_text(doc[:start] + "\n" + text + "\n" + doc[end:])
        print(f"wrote the counts into {DOC.relative_to(ROOT)}")
    return 1 if rc else 0


if __name__ == "__main__":
    sys.exit(main())
