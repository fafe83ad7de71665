"""The README's two commands on a fresh machine (issue 33, item 12): `make test` needed gpsd,
node/npm and gdal-bin, which only `.ci/run` installed. One dependency step, tools/deps.sh,
serves `make demo`, `make test` and `.ci/run`: it installs what is missing (Debian packages, as
root or with password-less sudo) or says clearly what is missing and how to install it."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEPS = ROOT / "tools" / "deps.sh"
HOST_GPSD = os.path.exists("/usr/sbin/gpsd")  # found there even off the PATH


def _tool(folder: Path, name: str, body: str) -> None:
    path = folder / name
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)


def _machine(tmp_path: Path, *, uid: int, apt: bool) -> tuple[dict[str, str], Path]:
    """A PATH with bash and a Python that has its headers and venv, and nothing else the
    project needs: no C compiler, gpsd, node, npm, gdalwarp or chromium (and no sudo)."""
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    (bin_ / "bash").symlink_to("/bin/bash")
    _tool(bin_, "python3", "exit 0")  # Python.h and ensurepip: there
    _tool(bin_, "id", f"echo {uid}")
    log = tmp_path / "apt.log"
    if apt:
        _tool(bin_, "apt-get", f'echo "$@" >> {log}')
    return {"PATH": str(bin_), "HOME": str(tmp_path)}, log


def _deps(env: dict[str, str], *groups: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["/bin/bash", str(DEPS), *groups], env=env, capture_output=True,
                          text=True, timeout=60, check=False)


def test_without_root_it_says_what_is_missing_and_how_to_install_it(tmp_path: Path) -> None:
    env, log = _machine(tmp_path, uid=1000, apt=True)
    done = _deps(env, "test")
    assert done.returncode == 1
    packages = ["gcc", *([] if HOST_GPSD else ["gpsd"]), "gpsd-clients", "nodejs", "npm",
                "gdal-bin", "chromium"]
    assert f"  sudo apt-get install -y {' '.join(packages)}\n" in done.stderr
    assert "deps: missing on this machine:\n" in done.stderr
    assert "  - gdalwarp (the reference ortho) (Debian package gdal-bin)\n" in done.stderr
    assert "not root and no password-less sudo" in done.stderr
    assert not log.exists()  # nothing tried


def test_as_root_it_installs_what_is_missing(tmp_path: Path) -> None:
    env, log = _machine(tmp_path, uid=0, apt=True)
    done = _deps(env, "demo")
    assert done.returncode == 0, done.stderr
    assert log.read_text().splitlines() == ["update -qq", "install -y -qq gcc"]
    assert done.stderr == "deps: installing gcc (apt-get)\n"


def test_without_apt_get_it_names_the_tools(tmp_path: Path) -> None:
    env, _ = _machine(tmp_path, uid=0, apt=False)
    done = _deps(env, "make", "demo")
    assert done.returncode == 1
    assert "  - make (the README's commands) (Debian package make)\n" in done.stderr
    assert "no apt-get here" in done.stderr


def test_a_complete_machine_needs_nothing(tmp_path: Path) -> None:
    env, log = _machine(tmp_path, uid=1000, apt=True)
    for name in ("cc", "make"):
        _tool(Path(env["PATH"]), name, "exit 0")
    done = _deps(env, "make", "demo")
    assert (done.returncode, done.stderr) == (0, "")
    assert not log.exists()


@pytest.mark.parametrize(("where", "says"), [
    ("Makefile", "bash tools/deps.sh demo"),  # before the venv is made (make demo, make test)
    ("Makefile", "bash tools/deps.sh test"),  # make test
    (".ci/run", "bash tools/deps.sh make test"),
])
def test_the_readme_commands_and_ci_share_the_step(where: str, says: str) -> None:
    assert says in (ROOT / where).read_text()
