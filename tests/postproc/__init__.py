"""Helpers shared by the post-processing tests."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pytest

from sisa.cli import main


def simulated_once(tmp_path_factory: pytest.TempPathFactory, name: str, scenario_toml: str
                   ) -> Path:
    """A run of `scenario_toml` made once per test session, by the first xdist worker that
    asks (under a lock: the others wait for it and share it); its run folder."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = root / name
    with (root / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / "done").is_file():
            folder.mkdir(exist_ok=True)
            (folder / "scenario.toml").write_text(scenario_toml, encoding="utf-8")
            assert main(["simulate", "--scenario", str(folder / "scenario.toml"),
                         "--out", str(folder / "run")]) == 0
            (folder / "done").write_text("")
    return folder / "run"
