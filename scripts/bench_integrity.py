"""Integrity of servofmu's files: single-bit flips through the readers, and what the checks cost.

1. Random flips in the arrays: a data file (`measure` of g1: 2 amplitudes × 3 frequencies) and a result file
   (`identify --method pso` of it); N times one bit, drawn with a seeded generator, is flipped in the stored bytes
   of the arrays (every chunk of every numeric dataset) and the file read with servofmu's reader.
2. Every byte: a small data file (`measure` of g1 at one frequency, 2 amplitudes, 64 samples per period) and its
   result file are damaged at every byte in turn, one bit per byte (the bit drawn for each byte with a seeded
   generator, so every bit position occurs), and each copy is read by the reader the command line uses —
   read_data_file (identify, validate, report) and read_result (export, validate, report) — in worker processes
   watched for hangs.  Each outcome is classified: reported (a one-line error calling the file damaged or not
   readable), refused (a one-line error of another kind: not a servofmu file, a newer schema), harmless (the reader
   returned exactly what it returns for the undamaged file), and the three that must never happen: a wrong answer
   (something else returned), a hang (no answer within the timeout) and a traceback (any other exception).
   Then the commands themselves run on copies: every flip not reported by the reader, and every K-th reported one
   (--cli-every), through `identify` and `validate` (data file) or `export`, `validate` and `report` (result file),
   each classified the same way (exit status 2 with one line naming the file; or status 0 with the same output as
   for the undamaged file, dates and the file's own hash aside).
3. The cost: Fletcher-32 (the data file of 1. rewritten with and without it), and the reader's first pass — the
   bytes read once and hashed, then walked in a forked, watched child that checks the digest — on the files of
   the demo's g1 (its plan: 2 amplitudes × 6 frequencies; the result of it).

Usage: python scripts/bench_integrity.py [--flips 1000] [--seed 0] [--every 1] [--cli-every 50]
       [--workers 2] [--out docs/bench-integrity.md]
"""
from __future__ import annotations

import argparse
import base64
import contextlib
import dataclasses
import hashlib
import io
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "faults"))
from harness import flip_bit, stored_ranges  # noqa: E402  (the fault suite's own helpers)

from servofmu.cli import main  # noqa: E402
from servofmu.errors import UserError  # noqa: E402
from servofmu.fileio import write_hdf5  # noqa: E402
from servofmu.identification.results import read_result  # noqa: E402
from servofmu.measurement.datafile import read_data_file  # noqa: E402

DAMAGE_WORDS = ("damaged", "checksum", "NaN or Inf", "beyond", "not a readable", "not numeric", "has shape",
                "does not match", "not a plant", "not supported")
OUTCOMES = ("reported", "refused", "harmless", "wrong answer", "hang", "traceback")
READERS = {"data.h5": read_data_file, "result.h5": read_result}
# the commands run on a damaged copy (its name in the folder: data.h5 or result.h5; the other file undamaged)
COMMANDS = {"data.h5": {"identify": ["identify", "data.h5", "--structure", "g1", "--method", "pso", "-o", "out.h5"],
                        "validate": ["validate", "result.h5", "data.h5", "--json"]},
            "result.h5": {"export": ["export", "result.h5", "--format", "json", "-o", "out.json"],
                          "validate": ["validate", "result.h5", "data.h5", "--json"],
                          "report": ["report", "result.h5", "-o", "out.html"]}}


def servofmu(*argv) -> None:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main([str(a) for a in argv]) == 0, argv


# ---------------------------------------------------------------------------------------------------------------
# What a reader or a command gave, comparably
# ---------------------------------------------------------------------------------------------------------------
def fingerprint(value) -> str:
    """SHA-256 of everything a reader returned, but the file's path and the hash of its bytes (a copy's own)."""
    h = hashlib.sha256()

    def feed(x):
        if hasattr(x, "to_toml"):
            h.update(b"plant" + x.to_toml().encode())
        elif dataclasses.is_dataclass(x):
            h.update(type(x).__name__.encode())
            for f in dataclasses.fields(x):
                if f.name not in ("path", "sha256"):
                    h.update(f.name.encode())
                    feed(getattr(x, f.name))
        elif isinstance(x, np.ndarray):
            h.update(repr((x.dtype.str, x.shape)).encode() + np.ascontiguousarray(x).tobytes())
        elif isinstance(x, dict):
            for k in sorted(x, key=str):
                feed(str(k))
                feed(x[k])
        elif isinstance(x, (list, tuple)):
            h.update(b"[%d" % len(x))
            for item in x:
                feed(item)
        else:
            h.update(repr(x).encode() + b";")

    feed(value)
    return h.hexdigest()


_VOLATILE = re.compile(r"\d{4}-\d\d-\d\d[T ]\d\d:\d\d:\d\d(\.\d+)?(Z|[+-]\d\d:?\d\d)?|[0-9a-f]{64}|"
                       r"\d+(\.\d+)? ?(ms|s)\b")
_EMBEDDED = re.compile(r"base64,([A-Za-z0-9+/=]+)")


def command_output(name: str, folder: Path, stdout: str) -> str:
    """What a command produced, its dates, wall times and hashes aside (they differ between any two runs)."""
    if name == "identify":
        r = read_result(folder / "out.h5")
        return fingerprint((r.method, r.names, r.theta, r.intervals, r.fitness, r.history, r.plant,
                            {k: v for k, v in r.provenance.items() if k not in ("data_sha256", "date")}))
    if name == "export":
        d = json.loads((folder / "out.json").read_text())
        d["provenance"] = {k: v for k, v in d.get("provenance", {}).items()
                           if k not in ("result_sha256", "export_date")}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()
    if name == "report":  # its figures are embedded (base64), each with the date it was drawn
        def figure(match):
            try:
                return _VOLATILE.sub("", base64.b64decode(match.group(1)).decode())
            except ValueError:
                return match.group(1)

        page = _EMBEDDED.sub(figure, (folder / "out.html").read_text())
        return hashlib.sha256(_VOLATILE.sub("", page).encode()).hexdigest()
    # validate: whether the data is the identification's own is decided by the hash of its bytes, which a flipped
    # bit changes wherever it falls (a damaged copy is not the data identified from): that verdict aside
    d = json.loads(stdout)
    d.pop("own_data", None)
    d["warnings"] = [w for w in d.get("warnings", []) if "identified from" not in w]
    return hashlib.sha256(_VOLATILE.sub("", json.dumps(d, sort_keys=True)).encode()).hexdigest()


def classify_error(text: str, name: str) -> str:
    one_line = "\n" not in text.strip() and name in text
    if not one_line:
        return "traceback"
    return "reported" if any(w in text for w in DAMAGE_WORDS) else "refused"


def read_outcome(path: Path, reader, baseline: str) -> tuple[str, str]:
    try:
        value = reader(path)
    except UserError as exc:
        return classify_error(str(exc), path.name), str(exc)
    except Exception as exc:  # noqa: BLE001  (what the sweep exists to find)
        return "traceback", f"{type(exc).__name__}: {exc}"
    return ("harmless", "") if fingerprint(value) == baseline else ("wrong answer", "")


def run_command(name: str, argv: list[str], folder: Path) -> tuple[int, str, str]:
    for p in folder.glob("out.*"):
        p.unlink()
    out, err, here = io.StringIO(), io.StringIO(), os.getcwd()
    os.chdir(folder)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(argv)
            except SystemExit as exc:
                rc = exc.code
            except Exception as exc:  # noqa: BLE001
                return -1, "", f"Traceback: {type(exc).__name__}: {exc}"
    finally:
        os.chdir(here)
    return rc, out.getvalue(), err.getvalue()


def command_outcome(name: str, argv: list[str], folder: Path, damaged: str, baseline: str) -> tuple[str, str]:
    rc, out, err = run_command(name, argv, folder)
    if rc == 0:
        same = command_output(name, folder, out) == baseline
        return ("harmless", "") if same else ("wrong answer", "")
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("warning:")]
    if rc != 2 or len(lines) != 1 or "Traceback" in err:
        return "traceback", err[-300:]
    return classify_error(lines[0], damaged), lines[0]


# ---------------------------------------------------------------------------------------------------------------
# The sweep's worker: python bench_integrity.py --worker SPEC.json (one JSON line per flip on stdout)
# ---------------------------------------------------------------------------------------------------------------
def worker(spec_path: str) -> None:
    spec = json.loads(Path(spec_path).read_text())
    source = Path(spec["source"])  # the folder of the undamaged data.h5 and result.h5
    name, reader = spec["file"], READERS[spec["file"]]
    folder = Path(spec["scratch"])
    folder.mkdir(parents=True, exist_ok=True)
    for other in READERS:
        shutil.copyfile(source / other, folder / other)
    image = (source / name).read_bytes()
    baseline = fingerprint(reader(source / name))
    commands = COMMANDS[name]
    cli_baseline = {c: command_output(c, folder, run_command(c, argv, folder)[1]) for c, argv in commands.items()} \
        if spec["cli"] else {}
    for offset, bit, cli in spec["flips"]:
        damaged = bytearray(image)
        damaged[offset] ^= 1 << bit
        (folder / name).write_bytes(damaged)
        outcome, text = read_outcome(folder / name, reader, baseline)
        report = {"offset": offset, "bit": bit, "reader": outcome, "text": text[:300]}
        if cli or outcome not in ("reported", "harmless") and spec["cli"]:
            report["commands"] = {c: command_outcome(c, argv, folder, name, cli_baseline[c])
                                  for c, argv in commands.items()}
        print(json.dumps(report), flush=True)
    (folder / name).write_bytes(image)


def sweep(source: Path, name: str, flips: list, scratch: Path, timeout: float, cli: bool, workers: int) -> list:
    """Run ``flips`` ([offset, bit, through the commands too]) of ``source/name`` in ``workers`` watched
    processes; a worker silent for ``timeout`` seconds is killed and its flip counted a hang."""
    script = Path(__file__).resolve()
    results, queue = [], [flips[i::workers] for i in range(workers)]
    procs = {}

    def start(k, todo):
        spec = scratch / f"spec-{name}-{k}.json"
        spec.write_text(json.dumps({"source": str(source), "file": name, "scratch": str(scratch / f"w{k}"),
                                    "flips": todo, "cli": cli}))
        proc = subprocess.Popen([sys.executable, str(script), "--worker", str(spec)], stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        os.set_blocking(proc.stdout.fileno(), False)
        procs[k] = [proc, list(todo), time.monotonic(), ""]

    for k, todo in enumerate(queue):
        if todo:
            start(k, todo)
    while procs:
        time.sleep(0.05)
        for k in list(procs):
            proc, todo, last, buffer = procs[k]
            try:
                chunk = os.read(proc.stdout.fileno(), 1 << 16).decode()
            except BlockingIOError:
                chunk = None
            buffer += chunk or ""
            *lines, buffer = buffer.split("\n")
            for line in lines:
                results.append(json.loads(line))
                todo.pop(0)
                last = time.monotonic()
            procs[k][1:] = [todo, last, buffer]
            if not todo:
                proc.wait()
                del procs[k]
            elif time.monotonic() - last > timeout:  # the flip in hand hangs: record it, go on after it
                os.killpg(proc.pid, 9)
                proc.wait()
                offset, bit, _ = todo.pop(0)
                results.append({"offset": offset, "bit": bit, "reader": "hang", "text": ""})
                del procs[k]
                if todo:
                    start(k, todo)
            elif chunk == "" and proc.poll() is not None:  # end of its output: it died on the flip in hand
                offset, bit, _ = todo.pop(0)
                results.append({"offset": offset, "bit": bit, "reader": "traceback",
                                "text": f"worker died (status {proc.returncode})"})
                del procs[k]
                if todo:
                    start(k, todo)
    return sorted(results, key=lambda r: r["offset"])


# ---------------------------------------------------------------------------------------------------------------
# Parts 1 and 3
# ---------------------------------------------------------------------------------------------------------------
def flips(path: Path, reader, n: int, rng, scratch: Path) -> dict:
    """Flip one bit n times (each in a fresh copy of ``path``); how the reader took it."""
    image = path.read_bytes()
    copy = scratch / path.name
    out = {"detected": 0, "missed": [], "other": []}
    for _ in range(n):
        copy.write_bytes(image)
        where = flip_bit(copy, rng)
        try:
            reader(copy)
        except UserError as exc:
            if any(w in str(exc) for w in DAMAGE_WORDS):
                out["detected"] += 1
            else:
                out["other"].append(f"{where}: {exc}")
        else:
            out["missed"].append(where)
    return out


def rewrite(source: Path, target: Path, fletcher32: bool) -> None:
    """``source`` rewritten through write_hdf5: the same groups, attributes and datasets (chunks, compression),
    with or without Fletcher-32 on every dataset that has filters."""
    import h5py

    def fill(f):
        with h5py.File(source, "r") as src:
            def copy(name, obj):
                if isinstance(obj, h5py.Group):
                    g = f.require_group(name)
                    g.attrs.update(obj.attrs)
                    return
                options = {}
                if obj.chunks is not None:
                    options = {"chunks": obj.chunks, "compression": obj.compression, "shuffle": obj.shuffle,
                               "fletcher32": fletcher32}
                f.create_dataset(name, data=obj[()], **options).attrs.update(obj.attrs)

            f.attrs.update({k: v for k, v in src.attrs.items() if k != "content_sha256"})
            src.visititems(copy)

    write_hdf5(target, fill)


def timed(functions, repeats: int) -> list[float]:
    """Median seconds of each function, the runs interleaved (a busy machine slows both alike)."""
    times = [[] for _ in functions]
    for _ in range(repeats):
        for function, t in zip(functions, times):
            start = time.perf_counter()
            function()
            t.append(time.perf_counter() - start)
    return [statistics.median(t) for t in times]


def read_costs(files: dict, repeats: int) -> list[tuple]:
    """Per file: its size and the median times of the reader, of the reader without the first pass, and of
    hashing its bytes."""
    import servofmu.fileio as fileio

    rows = []
    for label, (path, reader) in files.items():
        inspect = fileio.inspect_image

        def without_pass():
            fileio.inspect_image = lambda image: None
            try:
                reader(path)
            finally:
                fileio.inspect_image = inspect

        full, bare, digest = timed([lambda: reader(path), without_pass,
                                    lambda: hashlib.sha256(path.read_bytes()).hexdigest()], repeats)
        rows.append((label, path.stat().st_size, full, bare, digest))
    return rows


# ---------------------------------------------------------------------------------------------------------------
def sweep_table(name: str, size: int, results: list) -> list[str]:
    counts = {o: 0 for o in OUTCOMES}
    for r in results:
        counts[r["reader"]] += 1
    lines = [f"| {name} ({size} bytes) | reader | {len(results)} | " + " | ".join(str(counts[o]) for o in OUTCOMES)
             + " |"]
    commands = sorted({c for r in results for c in r.get("commands", {})})
    for c in commands:
        counts = {o: 0 for o in OUTCOMES}
        ran = [r for r in results if c in r.get("commands", {})]
        for r in ran:
            counts[r["commands"][c][0]] += 1
        lines.append(f"| | `{c}` | {len(ran)} | " + " | ".join(str(counts[o]) for o in OUTCOMES) + " |")
    return lines


def make_files(tmp: Path, demo: bool) -> None:
    servofmu("build", "g1", "-o", tmp / "g1.fmu")
    servofmu("measure", tmp / "g1.fmu", "--amplitudes", "2,0.6", "--frequencies", "1,3,10", "--workers", "0",
             "-o", tmp / "data.h5")
    servofmu("identify", tmp / "data.h5", "--structure", "g1", "--method", "pso", "-o", tmp / "result.h5")
    small = tmp / "small"
    small.mkdir()
    servofmu("measure", tmp / "g1.fmu", "--amplitudes", "2,0.6", "--frequencies", "5", "--samples-per-period", "64",
             "--workers", "0", "-o", small / "data.h5")
    servofmu("identify", small / "data.h5", "--structure", "g1", "--method", "pso", "-o", small / "result.h5")
    if demo:
        from servofmu.commands.demo import DEMO_PLANS

        amplitudes, frequencies = DEMO_PLANS["g1"]
        servofmu("measure", tmp / "g1.fmu", "--amplitudes", ",".join(map(str, amplitudes)), "--frequencies",
                 ",".join(map(str, frequencies)), "-o", tmp / "demo-g1.h5")
        servofmu("identify", tmp / "demo-g1.h5", "--structure", "g1", "--method", "pso", "-o",
                 tmp / "demo-g1-result.h5")


def main_bench() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flips", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--every", type=int, default=1, help="sweep every N-th byte (1: every byte)")
    ap.add_argument("--cli-every", type=int, default=50,
                    help="every N-th reported flip also through the commands (0: none)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds a flip may take before it is a hang")
    ap.add_argument("--out", default="docs/bench-integrity.md")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args.worker)
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory(prefix="bench-integrity-") as tmp:
        tmp = Path(tmp)
        make_files(tmp, demo=True)
        scratch = tmp / "scratch"
        scratch.mkdir()
        rows = []
        for name, reader in READERS.items():
            path = tmp / name
            ranges = stored_ranges(path)
            outcome = flips(path, reader, args.flips, rng, scratch)
            rows.append((name, path.stat().st_size, len(ranges), sum(n for *_, n in ranges), outcome))
        swept = {}
        for name in READERS:
            size = (tmp / "small" / name).stat().st_size
            bits = np.random.default_rng([args.seed, size]).integers(8, size=size)
            picked = [[k, int(bits[k]), bool(args.cli_every) and (k // args.every) % args.cli_every == 0]
                      for k in range(0, size, args.every)]
            started = time.monotonic()
            swept[name] = (size, sweep(tmp / "small", name, picked, scratch, args.timeout, args.cli_every > 0,
                                       args.workers), time.monotonic() - started)
        rewrite(tmp / "data.h5", tmp / "with.h5", True)
        rewrite(tmp / "data.h5", tmp / "without.h5", False)
        write = timed([lambda k=k: rewrite(tmp / "data.h5", tmp / f"{k}.h5", k == "with") for k in ("with", "without")],
                      args.repeats)
        read = timed([lambda k=k: read_data_file(tmp / f"{k}.h5") for k in ("with", "without")], args.repeats)
        sizes = [(tmp / f"{k}.h5").stat().st_size for k in ("with", "without")]
        costs = read_costs({"the demo's g1 data file (2 × 6 experiments)": (tmp / "demo-g1.h5", read_data_file),
                            "its result file": (tmp / "demo-g1-result.h5", read_result)}, args.repeats)
    write_doc(args, rows, swept, write, read, sizes, costs)


def write_doc(args, rows, swept, write, read, sizes, costs) -> None:
    total = sum(r[4]["detected"] for r in rows)
    flipped = args.flips * len(rows)
    lines = ["# Integrity of data and result files", "",
             "Made by `python scripts/bench_integrity.py` "
             f"(--flips {args.flips} --seed {args.seed} --every {args.every} --cli-every {args.cli_every}); "
             "see [reliability.md](reliability.md) and [hdf5.md](hdf5.md#integrity).", "",
             "## Every byte of a small data file and its result file", "",
             f"One bit flipped per byte{'' if args.every == 1 else f' (every {args.every}th byte)'}, the bit drawn "
             "for each byte with a seeded generator (all eight positions occur about equally), each flip in a fresh "
             "copy read by the reader the commands use (`read_data_file`: identify, validate, report; "
             "`read_result`: export, validate, report). The commands then ran on every copy the reader did not "
             f"report{f' and on every {args.cli_every}th byte' if args.cli_every else ''}: `identify --method pso` "
             "and `validate --json` on a damaged data file, `export --format json`, `validate --json` and `report` "
             "on a damaged result file. *reported*: one line, exit status 2, calling the file damaged or not "
             "readable; *refused*: one line of another refusal (not a servofmu file, an unsupported schema "
             "version); *harmless*: the same answer as for the undamaged file (dates, wall times and the file's "
             f"own hash aside, and validate's verdict on whether the data is the identification's own, which is "
             f"decided by that hash); *hang*: no answer within {args.timeout:g} s.", "",
             "| file | through | flips | " + " | ".join(OUTCOMES) + " |",
             "|---|---|---:|" + "---:|" * len(OUTCOMES)]
    for name, (size, results, seconds) in swept.items():
        lines += sweep_table(name, size, results)
    bad = [(name, r) for name, (_, results, _) in swept.items() for r in results
           if r["reader"] in OUTCOMES[3:] or any(o in OUTCOMES[3:] for o, _ in r.get("commands", {}).values())]
    lines += ["", f"**{len(bad)} wrong answers, hangs or tracebacks** in "
              f"{sum(len(r) for _, r, _ in swept.values())} flips "
              f"({', '.join(f'{name}: {s:.0f} s' for name, (_, _, s) in swept.items())} of sweeping)."]
    for name, r in bad[:20]:
        lines.append(f"- {name} byte {r['offset']} bit {r['bit']}: reader {r['reader']} {r['text'][:120]} "
                     f"{r.get('commands', '')}")
    messages = {}
    for _, (_, results, _) in swept.items():
        for r in results:
            if r["reader"] in ("reported", "refused"):
                key = re.sub(r"^\S+: ", "", r["text"])
                key = re.sub(r"\(.*", "(…)", key) if "not a readable" in key else key
                messages[key] = messages.get(key, 0) + 1
    lines += ["", "The commonest messages (the file's name first, left out here):", ""]
    for text, n in sorted(messages.items(), key=lambda kv: -kv[1])[:8]:
        lines.append(f"- {n} × `{text[:160]}`")
    lines += ["", "## Random flips in the stored arrays (a larger data file, 2 amplitudes × 3 frequencies)", "",
              "| file | size (bytes) | stored array pieces | bytes in arrays | flips | reported as damage | missed | "
              "other error |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, size, pieces, nbytes, o in rows:
        lines.append(f"| {name} | {size} | {pieces} | {nbytes} | {args.flips} | {o['detected']} "
                     f"({100 * o['detected'] / args.flips:.1f} %) | {len(o['missed'])} | {len(o['other'])} |")
    lines += ["", f"**{total} of {flipped} flips ({100 * total / flipped:.2f} %) reported as a damaged file**, "
              "naming it.", ""]
    for name, *_, o in rows:
        for where in o["missed"][:5]:
            lines.append(f"- missed in {name}: a bit of `{where}`")
        for text in o["other"][:5]:
            lines.append(f"- other error in {name}: {text}")
    lines += ["## What reading safely costs (median of "
              f"{args.repeats} runs each, in one run)", "",
              "The reader reads the file's bytes once, hashes them (the hash provenance records), walks them in a "
              "forked child with a limit on its processor time (opening, every object, every value, the digest), "
              "then parses the same bytes in memory. The machine was shared with other work while this ran: the "
              "times are of one run, not a quiet machine's.", "",
              "| file | size | read | without the first pass | of which hashing the bytes |",
              "|---|---:|---:|---:|---:|"]
    for label, size, full, bare, digest in costs:
        lines.append(f"| {label} | {size} B | {1e3 * full:.1f} ms | {1e3 * bare:.1f} ms | {1e3 * digest:.2f} ms |")
    lines += ["", f"## What Fletcher-32 costs (the data file of the random flips, median of {args.repeats} runs "
              "each, in one run)", "",
              "| | with Fletcher-32 | without | ratio |", "|---|---:|---:|---:|",
              f"| write (write_hdf5 of the whole file) | {1e3 * write[0]:.2f} ms | {1e3 * write[1]:.2f} ms | "
              f"{write[0] / write[1]:.3f} |",
              f"| read (read_data_file, every array checked) | {1e3 * read[0]:.2f} ms | {1e3 * read[1]:.2f} ms | "
              f"{read[0] / read[1]:.3f} |",
              f"| size | {sizes[0]} B | {sizes[1]} B | {sizes[0] / sizes[1]:.4f} |", ""]
    text = "\n".join(lines)
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main_bench()
