"""What decides whether a task must run again: a key hashed from its inputs' fingerprints and
its settings, recorded with what it made.

A file's fingerprint is SHA-256 over its size, its modification time (ns) and its first and
last 64 KiB: a constant cost (two small reads) whatever the file's size, so a rerun over a
campaign of 20 GB logs does not read them again. What it misses: a change inside the file that
keeps its size and its modification time (only a deliberate `touch -d` or a clock set back
does that); a copy of the same bytes elsewhere (a new mtime) counts as a change and reruns.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Final

EDGE_BYTES: Final = 64 << 10


def file_fingerprint(path: Path) -> str:
    """SHA-256 (hex) of the file's size, mtime and first and last EDGE_BYTES; "missing" for a
    path that is not a readable file."""
    try:
        with path.open("rb") as fh:
            st = os.fstat(fh.fileno())
            h = hashlib.sha256(f"{st.st_size}:{st.st_mtime_ns}:".encode())
            h.update(fh.read(EDGE_BYTES))
            if st.st_size > EDGE_BYTES:
                fh.seek(max(st.st_size - EDGE_BYTES, EDGE_BYTES))
                h.update(fh.read(EDGE_BYTES))
    except OSError:
        return "missing"
    return h.hexdigest()


def files_fingerprint(paths: Iterable[Path]) -> dict[str, str]:
    """{path: fingerprint}, in the order given."""
    return {str(p): file_fingerprint(p) for p in paths}


def task_key(kind: str, *parts: Any) -> str:
    """The key of a task of `kind` over `parts` (JSON-able: fingerprints, settings, the keys of
    the tasks it builds on): SHA-256 of their canonical JSON."""
    text = json.dumps([kind, *parts], sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()
