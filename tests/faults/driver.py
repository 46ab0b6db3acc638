"""Run servofmu commands in this one process, each under an injected fault, and report each outcome as a JSON line.

    python driver.py CASES.json

Every case of CASES.json (a list) is a dict:

- ``argv``: the command line after ``servofmu``;
- ``folder``: where the command runs and writes (made empty first); ``files``: name -> a file copied there first
  (a previous output, say);
- ``fault``: null, ``{"kind": "fsize", "limit": BYTES}`` (RLIMIT_FSIZE while the command runs) or
  ``{"kind": "full", "free": BYTES}`` (``folder`` on a tmpfs of its own that has BYTES left; this process must run
  in a mount namespace where it may mount one, e.g. under ``unshare -m``); ``temp_on_fault``: the command's
  temporary directory on that tmpfs too (a full disk is full for every file);
- ``keep``: a folder the contents of ``folder`` are copied to afterwards (a tmpfs is gone when the case ends).

The report of a case: ``rc`` (main()'s return or SystemExit code), ``stderr`` (everything written to file
descriptors 1 and 2, C libraries included), ``uncaught`` (an exception main() let through: a bug), ``before`` and
``after`` (name -> SHA-256 of the files in ``folder``) and ``temp_left`` (what the command left in its temporary
directory).  A crash ends this process: the test sees its exit status.
"""
import hashlib
import json
import os
import resource
import select
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path


def digests(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def fill(folder: Path, free: int) -> Path:
    """A file that leaves ``free`` bytes on the file system of ``folder``."""
    filler = folder / "filler"
    st = os.statvfs(folder)
    size = max(0, st.f_bavail * st.f_frsize - free)
    with open(filler, "wb") as fh:
        while size:
            size -= fh.write(b"\0" * min(size, 1 << 20))
    return filler


def run_case(case: dict, scratch: Path) -> dict:
    from servofmu.cli import main

    folder = Path(case["folder"])
    fault = case.get("fault") or {}
    mounted = fault.get("kind") == "full"
    folder.mkdir(parents=True, exist_ok=True)
    if mounted:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256m", "tmpfs", str(folder)], check=True)
    temp = (folder if mounted and case.get("temp_on_fault") else scratch) / "tmp"
    work = folder / "work"
    for d in (temp, work):
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir()
    for name, source in case.get("files", {}).items():
        shutil.copyfile(source, work / name)
    before = digests(work)
    filler = fill(folder, int(fault["free"])) if mounted else None
    os.environ["TMPDIR"] = str(temp)
    tempfile.tempdir = None
    # stdout and stderr into a pipe (a pipe has no file-size limit), drained by a thread until the command is
    # over: not until end of file, since a helper process (multiprocessing's resource tracker) keeps the pipe open
    read_end, write_end = os.pipe()
    captured, over = [], threading.Event()

    def drain():
        while True:
            # ``over`` read before the poll: set once the command has written all it will, so a poll that then
            # finds nothing has read everything (checked after an empty poll, a busy machine could let the
            # command write its line and finish between the two, and the line was lost)
            finished = over.is_set()
            if select.select([read_end], [], [], 0 if finished else 0.1)[0]:
                chunk = os.read(read_end, 65536)
                if not chunk:  # every writer closed it
                    return
                captured.append(chunk)
            elif finished:
                return

    reader = threading.Thread(target=drain)
    reader.start()
    saved = os.dup(2), os.dup(1)
    limits = resource.getrlimit(resource.RLIMIT_FSIZE)
    report = {"id": case.get("id"), "uncaught": None}
    try:
        os.dup2(write_end, 2)
        os.dup2(write_end, 1)
        os.chdir(work)
        if fault.get("kind") == "fsize":
            resource.setrlimit(resource.RLIMIT_FSIZE, (int(fault["limit"]), limits[1]))
        try:
            report["rc"] = main(case["argv"])
        except SystemExit as exc:
            report["rc"] = exc.code if isinstance(exc.code, int) else 2
        except BaseException as exc:  # a bug of servofmu: main() lets nothing through
            report["rc"], report["uncaught"] = None, f"{type(exc).__name__}: {exc}"
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, limits)
            sys.stdout.flush()
            sys.stderr.flush()
    finally:
        os.dup2(saved[0], 2)
        os.dup2(saved[1], 1)
        for fd in (*saved, write_end):
            os.close(fd)
        over.set()
        reader.join()
        os.close(read_end)
        os.chdir(scratch)
    if filler is not None:
        filler.unlink()
    report.update(stderr=b"".join(captured).decode(errors="replace"), before=before, after=digests(work),
                  temp_left=sorted(p.name for p in temp.iterdir()))
    if case.get("keep"):
        shutil.copytree(work, case["keep"], dirs_exist_ok=True)
    if mounted:
        subprocess.run(["umount", "-l", str(folder)], check=True)  # lazily: a helper may still be in there
    return report


def main_driver() -> None:
    cases = json.loads(Path(sys.argv[1]).read_text())
    scratch = Path(tempfile.mkdtemp(prefix="fault-driver-"))
    for case in cases:
        print(json.dumps(run_case(case, scratch)), flush=True)
    shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main_driver()
