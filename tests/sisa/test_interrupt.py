"""A stop (Ctrl-C, SIGTERM) is noted as well as raised, so that a checkpoint raises it again
when C code lost it (sisa.core.interrupt)."""

from __future__ import annotations

import os
import signal
import threading
import time

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
