"""Integrity of servofmu's files: random single-bit flips in the arrays of a data file and a result file, and what
the checksums cost.

1. A data file (`measure` of g1: 2 amplitudes × 3 frequencies) and a result file (`identify --method pso` of it)
   are made once.  For each, N times: one bit, drawn with a seeded generator, is flipped anywhere in the stored
   bytes of its arrays (every chunk of every numeric dataset, located with h5py's get_chunk_info / get_offset),
   and the file is read with servofmu's own reader (read_data_file, read_result).  A flip counts as detected
   when the reader raises a UserError that calls the file damaged; the rest are listed.
2. The cost of Fletcher-32: the same data file rewritten through write_hdf5 with and without the filter on its
   datasets (everything else equal), and read with read_data_file: median times of both, and their ratio, in
   one run.

Usage: python scripts/bench_integrity.py [--flips 1000] [--seed 0] [--out docs/bench-integrity.md]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import statistics
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

DAMAGE_WORDS = ("damaged", "checksum", "NaN or Inf", "beyond", "not a readable")


def servofmu(*argv) -> None:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main([str(a) for a in argv]) == 0, argv


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

            f.attrs.update(src.attrs)
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


def main_bench() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flips", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--out", default="docs/bench-integrity.md")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory(prefix="bench-integrity-") as tmp:
        tmp = Path(tmp)
        servofmu("build", "g1", "-o", tmp / "g1.fmu")
        servofmu("measure", tmp / "g1.fmu", "--amplitudes", "2,0.6", "--frequencies", "1,3,10", "--workers", "0",
                 "-o", tmp / "data.h5")
        servofmu("identify", tmp / "data.h5", "--structure", "g1", "--method", "pso", "-o", tmp / "result.h5")
        scratch = tmp / "scratch"
        scratch.mkdir()
        rows = []
        for name, reader in (("data.h5", read_data_file), ("result.h5", read_result)):
            path = tmp / name
            ranges = stored_ranges(path)
            outcome = flips(path, reader, args.flips, rng, scratch)
            rows.append((name, path.stat().st_size, len(ranges), sum(n for *_, n in ranges), outcome))
        rewrite(tmp / "data.h5", tmp / "with.h5", True)
        rewrite(tmp / "data.h5", tmp / "without.h5", False)
        write = timed([lambda k=k: rewrite(tmp / "data.h5", tmp / f"{k}.h5", k == "with") for k in ("with", "without")],
                      args.repeats)
        read = timed([lambda k=k: read_data_file(tmp / f"{k}.h5") for k in ("with", "without")], args.repeats)
        sizes = [(tmp / f"{k}.h5").stat().st_size for k in ("with", "without")]

    total = sum(r[4]["detected"] for r in rows)
    flipped = args.flips * len(rows)
    lines = ["# Integrity of data and result files", "",
             "Made by `python scripts/bench_integrity.py` "
             f"(--flips {args.flips} --seed {args.seed}); see [reliability.md](reliability.md).", "",
             "## Single-bit flips in the stored arrays", "",
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
    lines += ["", "## What Fletcher-32 costs (the data file, median of "
              f"{args.repeats} runs each, in one run)", "",
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
