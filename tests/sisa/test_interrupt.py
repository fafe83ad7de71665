"""A stop (Ctrl-C, SIGTERM) is noted as well as raised, so that a checkpoint raises it again
when C code lost it (sisa.core.interrupt)."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from sisa.commands.progress import Progress
from sisa.core.interrupt import (
    Terminated,
    raise_if_stopped,
    stop_answered,
    stop_noted,
    stops_noted,
)
from sisa.core.outdir import staged_output_dir, write_whole


def _lose(sig: int) -> None:
    """Send `sig` to this process and drop the exception its handler raises."""
    try:
        os.kill(os.getpid(), sig)
        time.sleep(5)
    except KeyboardInterrupt:
        return
    raise AssertionError("the handler did not raise")


@pytest.mark.parametrize(("sig", "kind"), [(signal.SIGINT, KeyboardInterrupt),
                                           (signal.SIGTERM, Terminated)])
def test_a_lost_stop_is_raised_at_every_checkpoint(sig, kind):
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with stops_noted():
        raise_if_stopped()  # nothing asked yet
        _lose(sig)
        assert stop_noted() is kind
        with pytest.raises(kind):
            raise_if_stopped()
        bar = Progress("test", quiet=True)
        with pytest.raises(kind):
            bar.advance(1)
        with pytest.raises(kind):
            bar.step("next")
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_after_a_lost_stop_no_output_is_put_in_place(tmp_path):
    with stops_noted():
        _lose(signal.SIGINT)
        with pytest.raises(KeyboardInterrupt), staged_output_dir(tmp_path / "out") as scratch:
            (scratch / "product.txt").write_text("made after the stop")
        with pytest.raises(KeyboardInterrupt):
            write_whole(tmp_path / "file.txt", "made after the stop")
    assert not list(tmp_path.iterdir())  # neither the outputs nor their partial files


def test_a_new_block_forgets_the_last_stop_and_a_thread_has_no_handlers(tmp_path):
    with stops_noted():
        _lose(signal.SIGINT)
    with stops_noted():
        assert stop_noted() is None
        with staged_output_dir(tmp_path / "out") as scratch:
            (scratch / "product.txt").write_text("kept")
    assert (tmp_path / "out" / "product.txt").read_text() == "kept"
    seen = []

    def in_a_thread() -> None:
        with stops_noted():
            seen.append(signal.getsignal(signal.SIGINT))

    before = signal.getsignal(signal.SIGINT)
    worker = threading.Thread(target=in_a_thread)
    worker.start()
    worker.join()
    assert seen == [before]


def test_a_stop_the_command_answered_lets_its_outputs_through(tmp_path):
    """`sisa bench` keeps the run it was recording when stopped: it answers the stop."""
    with stops_noted():
        _lose(signal.SIGINT)
        stop_answered()
        raise_if_stopped()
        with staged_output_dir(tmp_path / "out") as scratch:
            (scratch / "flight.mcap").write_text("kept")
    assert (tmp_path / "out" / "flight.mcap").is_file()


def test_python_m_sisa_exits_130_after_a_ctrl_c_cpython_marked_unhandled(tmp_path):
    """A Ctrl-C during an import that runs code through CPython's PyRun_* API is marked
    unhandled by CPython though main() handles it: `python -m sisa.cli` said `interrupted`
    and died of SIGINT (-2) at exit. Here the mark is made as CPython makes it (a KeyboardInterrupt
    through PyRun_SimpleString), then a real Ctrl-C interrupts the command's start."""
    import subprocess
    import sys

    (tmp_path / "marked.py").write_text(
        "import ctypes, os, signal\n"
        "import sisa.cli as cli\n"
        "build = cli.build_parser\n"
        "def interrupted():\n"
        "    ctypes.pythonapi.PyRun_SimpleString(b'raise KeyboardInterrupt')  # the mark\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    return build()\n"
        "cli.build_parser = interrupted\n"
        "cli.run()\n")
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-m", "marked", "scenario", "show", "bench"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": f"{tmp_path}:{root}"})
    assert done.returncode == 130, done.stderr
    assert done.stderr.endswith("sisa scenario: interrupted\n"), done.stderr


def test_a_stop_ends_with_its_block(tmp_path):
    """A stop noted in one command's block must not stop what runs after it in the same
    process (tests run commands in-process: the next one's outputs were refused)."""
    with stops_noted():
        _lose(signal.SIGINT)
    raise_if_stopped()
    with staged_output_dir(tmp_path / "out") as scratch:
        (scratch / "product.txt").write_text("kept")
    assert (tmp_path / "out" / "product.txt").is_file()
