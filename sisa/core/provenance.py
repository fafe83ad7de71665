"""What an archived product says about how it was made: the software that made it and the input
files it was made from (size and SHA-256), so that a report read years later can be matched to
its data and its run repeated.
"""

from __future__ import annotations

import contextlib
import hashlib
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from sisa import __version__

HASH_CHUNK_BYTES: Final = 4 * 2**20
GIT_TIMEOUT_S: Final = 5.0


@dataclass(frozen=True)
class FileRecord:
    """One input file: as shown (relative to the run where it lies inside it), its size and
    its SHA-256 (hex) at the time the product was made."""

    shown: str
    size_bytes: int
    sha256: str


def file_record(path: Path, root: Path | None = None) -> FileRecord:
    """Size and SHA-256 of `path`, read in chunks (a scanner file of gigabytes stays out of
    memory); shown relative to `root` when it lies inside it."""
    path = Path(path)
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        while chunk := fh.read(HASH_CHUNK_BYTES):
            digest.update(chunk)
    shown = str(path)
    if root is not None:
        with contextlib.suppress(ValueError):  # outside the root: as given
            shown = str(path.resolve().relative_to(Path(root).resolve()))
    return FileRecord(shown, path.stat().st_size, digest.hexdigest())


def software_label() -> str:
    """'sisa 0.1.0 (git 5a837c1)', with ', with local changes' when the source tree it runs
    from differs from that commit; the version alone outside a git work tree."""
    revision = git_revision(Path(__file__).resolve().parents[2])
    return f"sisa {__version__}" + (f" (git {revision})" if revision else "")


def git_revision(folder: Path) -> str | None:
    """The short commit of the git work tree holding `folder`, and whether it has changes to
    tracked files; None without git or outside a work tree."""
    try:
        head = subprocess.run(["git", "-C", str(folder), "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=GIT_TIMEOUT_S, check=False)
        if head.returncode != 0 or not head.stdout.strip():
            return None
        dirty = subprocess.run(["git", "-C", str(folder), "status", "--porcelain",
                                "--untracked-files=no"], capture_output=True, text=True,
                               timeout=GIT_TIMEOUT_S, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    changed = dirty.returncode == 0 and bool(dirty.stdout.strip())
    return head.stdout.strip() + (", with local changes" if changed else "")
