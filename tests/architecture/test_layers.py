"""The layer rules are enforced, not only written: `lint-imports` (run by `make test`) keeps every
contract on the tree as it is, and breaks the right one when a copy of the tree is given an
import that crosses a layer, reaches into a stage's insides or closes a cycle."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("sisa", "emulators", "acquisition", "recorder", "postproc")
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def _lint(tree: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=tree, capture_output=True,
                          text=True, check=False, timeout=120,
                          env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"})


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tree = tmp_path_factory.mktemp("tree")
    shutil.copy(ROOT / "pyproject.toml", tree)
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tree / pkg,
                        ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.c"))
    return tree


def test_the_tree_keeps_every_contract(tree_copy: Path) -> None:
    proc = _lint(tree_copy)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 broken" in proc.stdout


@pytest.mark.parametrize(("module", "line", "broken"), [
    # post-processing reading simulation truth through the emulators
    ("postproc/sync/config.py", "import emulators.scenario", "postproc never imports emulators"),
    # the acquisition climbing up into post-processing
    ("acquisition/lfsr.py", "import postproc.sync", "one-way layers"),
    # a command reaching past a stage's public face
    ("sisa/commands/sync.py", "import postproc.sync.pipeline", "insides only through its package"),
    # georeferencing below the sync it builds on
    ("postproc/sync/lines.py", "import postproc.georef", "stage order"),
    # a cycle inside one package (recorder.writer imports recorder.messages)
    ("recorder/messages.py", "import recorder.writer", "no cycles inside a package"),
])
def test_a_broken_rule_fails(tree_copy: Path, module: str, line: str, broken: str) -> None:
    path = tree_copy / module
    original = path.read_text(encoding="utf-8")
    try:
        path.write_text(original + f"\n{line}  # broken on purpose\n", encoding="utf-8")
        proc = _lint(tree_copy)
    finally:
        path.write_text(original, encoding="utf-8")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    broken_lines = [ln for ln in proc.stdout.splitlines() if ln.endswith("BROKEN")]
    assert any(broken in ln for ln in broken_lines), proc.stdout
