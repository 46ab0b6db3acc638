"""Claims between processes: an output a run is writing, a temporary folder a run is using.

A claim is an advisory lock (``flock``) on a small file beside what it guards, held through an open file
descriptor.  The system releases it when its process ends in any way (SIGKILL included, in any PID namespace that
shares the file system), so a claim never outlives its owner, and any process can tell a live claim from an
abandoned one by trying to take it — which a process ID cannot tell across containers.
"""
from __future__ import annotations

import fcntl
import hashlib
import os
from pathlib import Path

__all__ = ["sibling", "take", "release", "is_abandoned", "NAME_MAX"]

NAME_MAX = 255  # bytes in a file name on the file systems servofmu writes to (Linux, macOS)


def sibling(path: Path, suffix: str) -> Path:
    """``.NAME.SUFFIX`` beside ``path``: a hidden file of servofmu's own.  A name too long to carry the dot and the
    suffix (a legal name of up to NAME_MAX bytes) gets ``.servofmu-HASH.SUFFIX`` instead, HASH from its name."""
    name = f".{path.name}.{suffix}"
    if len(os.fsencode(name)) > NAME_MAX:
        name = f".servofmu-{hashlib.sha256(os.fsencode(path.name)).hexdigest()[:32]}.{suffix}"
    return path.with_name(name)


def take(lock: Path) -> int | None:
    """Take the claim whose lock file is ``lock`` (made if missing): its file descriptor, or None when another
    process holds it.  OSError when the lock file cannot be made."""
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        # its previous holder may have removed the file between our open and our lock: then we hold a lock on a
        # file nobody else can find, and must take the one now at that name
        try:
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)


def release(fd: int, lock: Path) -> None:
    """Give up a claim taken with :func:`take`: the lock file removed first (while still held, so that nobody
    takes a claim on a file about to vanish), then the lock."""
    try:
        lock.unlink(missing_ok=True)
    finally:
        os.close(fd)


def is_abandoned(lock: Path) -> bool:
    """Whether the claim of ``lock`` is held by nobody (its process ended): checked by taking it for an instant.
    A missing lock file is no proof: its owner may be about to make it."""
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)
