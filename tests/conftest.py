"""Fixtures shared across the test tree."""

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

# Commands run by the tests have their stderr piped: their plain progress lines (every few
# seconds, sisa.commands.progress) would mix with the one-line errors and warnings the tests
# read. Off for every test and the commands they start, unless a test asks for them.
os.environ.setdefault("SISA_PROGRESS_S", "off")

JS_DIR = Path(__file__).resolve().parent / "recorder" / "js"


@pytest.fixture(scope="session")
def node_reader():
    """`node read_mcap.mjs`, with @mcap/core installed by `npm ci` from the committed lock."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.fail("node and npm are needed for the independent MCAP reader (Node >= 18)")
    lock = Path(tempfile.gettempdir()) / (
        "sisa-npm-" + hashlib.sha1(str(JS_DIR).encode()).hexdigest()[:12] + ".lock")
    with lock.open("w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # pytest-xdist workers install once, not at once
        if not (JS_DIR / "node_modules" / "@mcap" / "core").is_dir():
            proc = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=JS_DIR,
                                  capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                pytest.fail(f"`npm ci` in {JS_DIR} failed (exit {proc.returncode}): "
                            f"{proc.stderr.strip()[-1500:]}")

    def run(path):
        proc = subprocess.run([node, str(JS_DIR / "read_mcap.mjs"), str(path)],
                              capture_output=True, text=True, check=False, timeout=60)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)

    return run


