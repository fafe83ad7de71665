"""A baseline revision to time beside this checkout, for the benches that run both in turn
(bench/simulate_speed.py, bench/process_speed.py)."""

from __future__ import annotations

import contextlib
import filecmp
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def rev_of(rev: str) -> str:
    """REV as a short commit id."""
    return subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", rev], check=True,
                          capture_output=True, text=True).stdout.strip()


def _compiled(tree: Path) -> None:
    """The C extensions of the tree: this checkout's copied where their source is the same,
    else built in place (with the flags the tree's pyproject.toml declares)."""
    same = True
    for src in tree.glob("postproc/**/_*.c"):
        mine = REPO / src.relative_to(tree)
        built = sorted(mine.parent.glob(f"{mine.stem}*.so"))
        if mine.is_file() and built and filecmp.cmp(src, mine, shallow=False):
            for so in built:
                shutil.copy2(so, src.parent / so.name)
        else:
            same = False
    if not same:
        subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()",
                        "build_ext", "--inplace"], cwd=tree, check=True, capture_output=True)


@contextlib.contextmanager
def baseline_tree(rev: str | None) -> Iterator[Path | None]:
    """REV checked out (detached) in a temporary worktree with its compiled kernels, removed
    after; None without a REV."""
    if rev is None:
        yield None
        return
    tmp = Path(tempfile.mkdtemp(prefix="sisa-baseline-", dir="/tmp"))
    tree = tmp / "tree"
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(tree), rev],
                   check=True, capture_output=True)
    try:
        _compiled(tree)
        yield tree
    finally:
        subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)],
                       check=False, capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)
