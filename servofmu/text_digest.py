"""A digest line at the end of the text files servofmu writes for a machine (a tuned controller file, a selection's
chosen plant file), checked by their readers: a flipped bit in a TOML file is otherwise another valid number — a
velocity gain of 18850 read as 18851 — that no reader could tell from the one written.

The line is a TOML comment, ``# servofmu digest: sha256 HEX`` over every byte before it; a file without it (one
written by hand) is read as it is, and one edited by hand after servofmu wrote it is refused until its digest
line is deleted (the message says so).
"""
from __future__ import annotations

import hashlib
import re

from .errors import UserError

__all__ = ["with_digest", "checked_text", "DIGEST_PREFIX"]

DIGEST_PREFIX = "# servofmu digest: sha256 "
_LINE = re.compile(r"(?:\A|\n)# servofmu digest: sha256 ([0-9a-f]{64})\n?\Z")


def with_digest(text: str) -> str:
    """``text`` (ending with a newline) followed by its digest line."""
    text = text if text.endswith("\n") else text + "\n"
    return f"{text}{DIGEST_PREFIX}{hashlib.sha256(text.encode()).hexdigest()}\n"


def checked_text(path, text: str) -> str:
    """``text`` (read from ``path``) after checking its digest line, if it ends with one; anything that looks
    like a damaged digest line (its prefix in the last line) is checked as one."""
    last = text.rstrip("\n").rsplit("\n", 1)[-1]
    if not last.startswith("# servofmu digest"):
        return text
    match = _LINE.search(text)
    body = text[:match.start() + (1 if match.start() else 0)] if match else None
    if match is None or hashlib.sha256(body.encode()).hexdigest() != match.group(1):
        raise UserError(f"{path}: damaged, or edited since servofmu wrote it: its content does not match the digest "
                        "in its last line (if you edited it, delete that line)")
    return text
