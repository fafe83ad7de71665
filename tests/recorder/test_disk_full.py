"""A disk that fills up (ENOSPC), fails (EIO on fsync) or refuses a file past a size (EFBIG),
at every step of a recording: while a file is started, while recording, while a split rolls over
to a new part, while the summary is written at the end.

Whatever the step, the recorder must end in ONE RecorderError (one line, naming the file and the
reason; every later call raises the same error), keep everything it had flushed, release its
files, and leave no file that is not readable MCAP. From the command line, `sisa record` on a
disk that fills up exits non-zero with one line on stderr.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pty
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

import recorder.writer as writer_module
from recorder.columns import read_columns
from recorder.messages import Topic
from recorder.reader import scan_log
from recorder.writer import FlightRecorder, split_parts
from sisa.cli import main
from sisa.core.errors import RecorderError
from tests.recorder.crash_child import fix, ins
from tests.recorder.fakedisk import Disk

# every log here is cut short or damaged on purpose: the reader's warning saying so is expected
pytestmark = pytest.mark.filterwarnings("ignore::recorder.stats.DamagedLogWarning")

T0 = 1_700_000_000 * 10**9
MESSAGES = 3000  # INS records at 500 Hz of log time, a fix every 25th
FLUSH_EVERY = 200
ROOT = Path(__file__).resolve().parents[2]


@dataclass
class Outcome:
    errors: list[RecorderError] = field(default_factory=list)
    written: int = 0  # INS records accepted by write()
    safe: int = 0  # INS records flushed (flush() returned, or their part was finished)
    paths: list[Path] = field(default_factory=list)


def _open_fds() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


def record(path: Path, *, split_size_bytes: int | None = None) -> Outcome:
    """A deterministic recording (timed flushes far away, explicit ones every FLUSH_EVERY)."""
    out = Outcome()
    rec = None
    try:
        rec = FlightRecorder(path, split_size_bytes=split_size_bytes, flush_interval_s=60.0,
                             chunk_size=2048)
        for i in range(MESSAGES):
            parts = len(rec.paths)
            rec.write(ins(T0 + i * 2_000_000, i))
            if len(rec.paths) > parts:  # a split finished the previous part with i - 1
                out.safe = max(out.safe, i)
            out.written = i + 1
            if i % 25 == 0:
                rec.write(fix(T0 + i * 2_000_000, i))
            if i % FLUSH_EVERY == FLUSH_EVERY - 1:
                rec.flush()
                out.safe = i + 1
    except RecorderError as exc:
        out.errors.append(exc)
    if rec is not None and out.errors:  # every later call: the same error
        for call in (lambda: rec.write(ins(T0, 0)), rec.flush):
            with pytest.raises(RecorderError) as again:
                call()
            assert again.value is out.errors[0]
    if rec is not None:
        try:
            rec.close()  # quiet if the error was already raised, else raises it once
            if not out.errors:
                out.safe = out.written
        except RecorderError as exc:
            out.errors.append(exc)
        out.paths = list(rec.paths)
    return out


@pytest.fixture(scope="module")
def sizes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, int]:
    """Bytes a whole recording takes, unsplit and split (the disks below are smaller)."""
    folder = tmp_path_factory.mktemp("full")
    one = record(folder / "one.mcap")
    split = record(folder / "split.mcap", split_size_bytes=16_384)
    assert not one.errors
    assert not split.errors
    assert len(split.paths) > 5
    return {"one": sum(p.stat().st_size for p in one.paths),
            "split": sum(p.stat().st_size for p in split.paths)}


# Where the disk fills: in the first file's header (0, 30, 200 bytes), then spread over the whole
# recording, and in its last bytes (the summary at close).
ROOMS = [0, 30, 200, 0.05, 0.13, 0.31, 0.5, 0.77, 0.93, 0.98, 0.995, 0.999, -1]


def _room(spec: float, total: int) -> int:
    if isinstance(spec, int) and spec >= 0:
        return spec
    return total - 1 if spec == -1 else int(total * spec)


def check_after_disk_error(out: Outcome, folder: Path, stem: str, capsys) -> None:
    """One error, said well; every file left readable; nothing flushed lost; no fd leaked."""
    assert len(out.errors) == 1, f"{len(out.errors)} errors: {out.errors}"
    text = str(out.errors[0])
    assert "\n" not in text
    assert "No space left on device" in text or "Input/output error" in text
    assert str(folder) in text
    left = sorted(p for p in folder.iterdir() if stem in p.name)
    parts = split_parts(folder / f"{stem}.mcap")
    assert left == sorted(parts), f"files that are not parts: {set(left) - set(parts)}"
    if not parts:
        assert out.safe == 0
        return
    for part in parts:
        assert main(["log", "info", str(part)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    counters = read_columns(parts, Topic.INS_RECORD)["counter"]
    assert np.array_equal(counters, np.arange(len(counters)))
    assert out.safe <= len(counters) <= out.written, "a flushed message was lost"
    assert scan_log(parts).topics.get("/ins/record") is None or \
        scan_log(parts).topics["/ins/record"].lost_by_sequence == 0


@pytest.mark.parametrize("split", [False, True], ids=["one-file", "split"])
@pytest.mark.parametrize("spec", ROOMS, ids=[str(r) for r in ROOMS])
def test_a_full_disk_at_any_step(spec: float, split: bool, sizes: dict[str, int],
                                 tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                 capsys: pytest.CaptureFixture[str]) -> None:
    room = _room(spec, sizes["split" if split else "one"])
    disk = Disk(room)
    monkeypatch.setattr(writer_module, "_open_new", disk.open)
    fds = _open_fds()
    out = record(tmp_path / "flight.mcap", split_size_bytes=16_384 if split else None)
    assert _open_fds() <= fds, "a file was left open"
    assert sum(p.stat().st_size for p in tmp_path.iterdir()) <= room
    check_after_disk_error(out, tmp_path, "flight", capsys)


@pytest.mark.parametrize("nth", [1, 2, 3, 7, 12])
def test_an_fsync_that_fails_is_one_error_too(nth: int, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """EIO from fsync (a dying card): at the first file's start, a flush, a split, the end."""
    calls = [0]
    real_fsync = os.fsync

    def failing_fsync(fd: int) -> None:
        calls[0] += 1
        if calls[0] >= nth:
            raise OSError(errno.EIO, "Input/output error")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", failing_fsync)
    out = record(tmp_path / "flight.mcap", split_size_bytes=16_384)
    monkeypatch.setattr(os, "fsync", real_fsync)
    check_after_disk_error(out, tmp_path, "flight", capsys)


# --- the command line -------------------------------------------------------------------------

LIMITED = ("import resource, signal, sys\n"
           "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG, not a core-dumping signal\n"
           "limit = int(sys.argv[1])\n"
           "resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))\n"
           "from sisa.cli import main\n"
           "sys.exit(main(sys.argv[2:]))\n")


def test_sisa_record_on_a_full_disk_exits_with_one_line(tmp_path: Path) -> None:
    """`sisa record` with a real kernel limit (RLIMIT_FSIZE): the GPS stream on a pty fills it."""
    from acquisition.nmea import FixQuality, encode, gga_from_fix

    master, slave = pty.openpty()
    os.set_blocking(master, False)  # a child that stops reading must not block the test
    out = tmp_path / "flight.mcap"
    limit = 150_000  # ~2.5 s of this stream in the log: after a couple of timed flushes
    proc = subprocess.Popen([sys.executable, "-c", LIMITED, str(limit), "record", "--quiet",
                             "--gps", os.ttyname(slave), "--out", str(out), "--duration", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        sentence = encode(gga_from_fix(1_400_000_000 * 10**9, 18, 41.5, 2.1, 600.0, 49.5,
                                       FixQuality.RTK_FIXED, 12, 0.7))
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            with contextlib.suppress(BlockingIOError):
                os.write(master, sentence)
            time.sleep(0.01)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        os.close(master)
        os.close(slave)
    assert proc.returncode == 2, err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("sisa record: error: cannot write ")
    assert "File too large" in lines[0]
    assert str(tmp_path) in lines[0]
    assert lines[0].endswith("readable up to its last complete chunk and `sisa log recover` "
                             "makes it whole")  # the file is kept: how to use it
    parts = split_parts(out)
    assert parts == [out]
    assert out.stat().st_size <= limit
    stats = scan_log(parts)
    assert stats.messages > 0
    assert stats.topics["/gps/raw"].lost_by_sequence == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.mcap"]
