"""Integrity of the HDF5 files servofmu writes: one digest over everything a file holds, and an inspection of an
input that always ends.

The digest (root attribute ``content_sha256``, docs/hdf5.md) is the SHA-256 of a canonical listing of the file's
content — every group and dataset by path, every dataset's type, shape and values, every attribute's name, type,
shape and value — so that a flipped bit anywhere it could change what a reader gets (attributes in a heap no HDF5
checksum covers, such as variable-length strings, included) is found.  :func:`fileio.write_hdf5` writes it;
:func:`fileio.read_hdf5` checks it through :func:`inspect_image`.

A damaged file can make the HDF5 library itself loop for ever (a flipped size in a global heap), deaf to signals,
since the loop never returns to Python.  So the first pass over an input — opening it, walking every object,
reading every value, checking the digest — runs in a forked child process with a limit on its processor time;
only a file that pass has walked completely is then read by the process itself, from the same bytes.
"""
from __future__ import annotations

import hashlib
import json
import os
import select
import signal
import time

__all__ = ["DIGEST_ATTRIBUTE", "content_digest", "inspect_image", "InspectionFailed", "inspection_deadline",
           "READ_ERRORS", "read_error_reason"]

DIGEST_ATTRIBUTE = "content_sha256"
_LISTING_HEADER = b"servofmu-content-1\0"  # the listing's own version: a later change of it names itself
MAX_DEPTH = 16  # servofmu's files are 4 levels deep; a cycle of links (a damaged address) ends here

# How much processor time the first pass over an input may take: BASE_DEADLINE seconds, plus one per
# DEADLINE_BYTES_PER_S bytes (the pass reads and inflates every array: tens of MB/s on a slow machine).  Processor
# time, not wall time, so that a busy machine cannot make a sound file look like a looping one; the kernel ends the
# child when it is spent (RLIMIT_CPU).  A child that neither ends nor computes (a stall) is given STALL_FACTOR times
# as long in wall time.
BASE_DEADLINE = 10.0
DEADLINE_BYTES_PER_S = 5e6
STALL_FACTOR = 10


# What reading a damaged HDF5 file raises: h5py's OSError and RuntimeError (a failed checksum of an object
# header), and the KeyError ... of a missing or malformed item.
READ_ERRORS = (OSError, RuntimeError, KeyError, ValueError, TypeError, IndexError)


def read_error_reason(exc: BaseException) -> str:
    """What went wrong reading an HDF5 file, in a few words: a failed checksum says so."""
    text = (str(exc).strip("'\"").splitlines() or [type(exc).__name__])[0]
    if "checksum" in text or "filter returned failure" in text:
        return "checksum mismatch: the file was changed or damaged after it was written"
    if isinstance(exc, KeyError):
        return f"missing or bad {text}"
    return text.split("(")[-1].rstrip(")") if "(" in text else text


class InspectionFailed(Exception):
    """The first pass over an HDF5 image failed; ``kind`` is "open" (not an HDF5 file, or its superblock is
    damaged), "damaged" (an object unreadable or the content not what its digest says) or "hang" (the pass did not
    end), ``reason`` the few words of why."""

    def __init__(self, kind: str, reason: str):
        super().__init__(reason)
        self.kind, self.reason = kind, reason


def _value_bytes(value) -> bytes:
    """One attribute's or dataset's value, canonically: its type, shape and bytes (text as UTF-8)."""
    import h5py
    import numpy as np

    if isinstance(value, h5py.Empty):
        return b"E" + str(value.dtype).encode()
    a = np.asarray(value)
    shape = repr(a.shape).encode()
    if a.dtype.kind in "OUS":
        parts = [x if isinstance(x, bytes) else str(x).encode() for x in a.ravel()]
        return b"T" + shape + b"".join(len(p).to_bytes(8, "little") + p for p in parts)
    return repr(a.dtype.descr).encode() + shape + np.ascontiguousarray(a).tobytes()


def _attribute_bytes(obj, skip: str | None = None) -> bytes:
    out = []
    for name in sorted(obj.attrs):
        if name != skip:
            out.append(name.encode() + b"\0" + _value_bytes(obj.attrs[name]) + b"\0")
    return b"".join(out)


def content_digest(f) -> str:
    """The digest of the open HDF5 file ``f``: SHA-256, in hex, of its canonical listing (the module's docstring),
    without the root's own ``content_sha256``.  Raises KeyError for a link that leads to no readable object or a
    tree deeper than MAX_DEPTH (both only in a damaged file), and h5py's errors for what it cannot read."""
    import h5py

    digest = hashlib.sha256(_LISTING_HEADER)
    digest.update(b"G/\0" + _attribute_bytes(f, DIGEST_ATTRIBUTE))

    def walk(group, prefix: str, depth: int) -> None:
        if depth > MAX_DEPTH:
            raise KeyError(f"{prefix}: objects nested deeper than {MAX_DEPTH} levels")
        for name in sorted(group):
            obj = group.get(name)
            path = f"{prefix}/{name}"
            if isinstance(obj, h5py.Dataset):
                digest.update(b"D" + path.encode() + b"\0" + _value_bytes(obj[()] if obj.shape is not None
                                                                         else h5py.Empty(obj.dtype)))
            elif isinstance(obj, h5py.Group):
                digest.update(b"G" + path.encode() + b"\0")
            else:
                raise KeyError(f"{path}: a link to no readable object")
            digest.update(_attribute_bytes(obj))
            if isinstance(obj, h5py.Group):
                walk(obj, path, depth + 1)

    walk(f, "", 1)
    return digest.hexdigest()


def _inspect(image: bytes) -> tuple[str, str]:
    """The first pass, in this process: ("ok", "") or (kind, reason) as for InspectionFailed."""
    import h5py

    try:
        f = h5py.File.in_memory(image)
    except (OSError, ValueError) as exc:
        return "open", read_error_reason(exc)
    try:
        with f:
            actual = content_digest(f)
            if DIGEST_ATTRIBUTE not in f.attrs:
                return "ok", ""  # written by an older servofmu: the arrays' checksums and the readers' checks remain
            stored = f.attrs[DIGEST_ATTRIBUTE]
            stored = stored.decode() if isinstance(stored, bytes) else str(stored)
            if stored != actual:
                return "damaged", "its content does not match the digest it was written with: the file was changed " \
                                  "or damaged after it was written"
            return "ok", ""
    except (*READ_ERRORS, AttributeError, UnicodeDecodeError, OverflowError, MemoryError) as exc:
        return "damaged", read_error_reason(exc)


def inspection_deadline(size: int) -> int:
    """Seconds of processor time the first pass over an image of ``size`` bytes may take."""
    return int(BASE_DEADLINE + size / DEADLINE_BYTES_PER_S)


def inspect_image(image: bytes) -> None:
    """Open ``image`` (an HDF5 file's bytes), walk every object, read every value and check the digest, in a forked
    child that has :func:`inspection_deadline` seconds of processor time (and STALL_FACTOR times as long in wall
    time); a stop signal of this process ends it too.  Raises :class:`InspectionFailed`.  Where processes cannot be
    forked the pass runs here, unbounded."""
    if not hasattr(os, "fork"):
        kind, reason = _inspect(image)
        if kind != "ok":
            raise InspectionFailed(kind, reason)
        return
    deadline = inspection_deadline(len(image))
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns, never runs the parent's exit handlers
        _child(image, write_end, read_end, deadline)
    os.close(write_end)
    try:
        report = _wait_for(pid, read_end, deadline)
    finally:
        os.close(read_end)
    if report is None:
        raise InspectionFailed("hang", f"reading it did not end within {deadline} s of processor time: a damaged "
                                       "file that makes the HDF5 library loop")
    kind, reason = report
    if kind != "ok":
        raise InspectionFailed(kind, reason)


def _child(image: bytes, write_end: int, read_end: int, deadline: int) -> None:
    code = 1
    try:
        os.close(read_end)
        for s in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGXCPU):  # a stop ends the child at once
            signal.signal(s, signal.SIG_DFL)
        try:
            import resource

            limit = deadline + 1  # (a forked child's processor time starts at zero)
            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
            resource.setrlimit(resource.RLIMIT_CPU, (limit, limit))  # SIGKILL when spent, even with the parent gone
        except (ImportError, ValueError, OSError):
            pass
        message = json.dumps(_inspect(image)).encode()
        while message:
            message = message[os.write(write_end, message):]
        code = 0
    except BaseException:  # noqa: BLE001  (nothing may escape into the parent's code)
        code = 1
    finally:
        os._exit(code)


def _wait_for(pid: int, read_end: int, deadline: int) -> tuple[str, str] | None:
    """The child's report, or None when it spent its processor time (killed by the kernel) or did not report
    within STALL_FACTOR × ``deadline`` seconds (then killed here).  A stop signal of this process (an exception from
    its handler) kills the child too."""
    chunks, end = [], time.monotonic() + STALL_FACTOR * deadline
    reaped = False
    try:
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([read_end], [], [], left)
            if not ready:
                continue
            chunk = os.read(read_end, 1 << 16)
            if not chunk:
                break
            chunks.append(chunk)
        _, status = os.waitpid(pid, 0)
        reaped = True
        try:
            kind, reason = json.loads(b"".join(chunks))
        except ValueError:  # the child died without a report
            if os.WIFSIGNALED(status) and os.WTERMSIG(status) in (signal.SIGKILL, signal.SIGXCPU):
                return None  # its processor time spent
            return "damaged", "reading it failed in the HDF5 library"
        return str(kind), str(reason)
    finally:
        if not reaped:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)
