"""Crashes: recordings SIGKILLed at random moments, and disks that fill up mid-flight.

Every killed file must be readable (Python reader, recover), lose no message inside what it kept,
and keep everything up to 1.5 s before the kill. A disk error must end as one RecorderError line
with the file readable up to the failure.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

import recorder.writer as writer_module
from recorder.columns import read_columns
from recorder.messages import Topic
from recorder.reader import read_log, scan_log
from recorder.recover import recover
from recorder.writer import FlightRecorder
from sisa.cli import main
from sisa.core.errors import RecorderError
from tests.recorder.crash_child import fix, ins, kill_many
from tests.recorder.fakedisk import Disk

# every log here is cut short or damaged on purpose: the reader's warning saying so is expected
pytestmark = pytest.mark.filterwarnings("ignore::recorder.stats.DamagedLogWarning")

MAX_LOSS_NS = 1_500_000_000
ROOT = Path(__file__).resolve().parents[2]

# Five seeded kill moments in 1-3 s at 2 kHz; a sixth at 40 Hz, where a 64 KiB chunk would take
# ~6 s to fill, so only the timed flush keeps the loss under 1.5 s.
_rng = np.random.default_rng(20240611)
PLAN = [(float(d), 2000.0) for d in _rng.uniform(1.0, 3.0, 5)] + [(2.6, 40.0)]


@pytest.fixture(scope="module")
def killed(tmp_path_factory):
    return kill_many(tmp_path_factory.mktemp("killed"), PLAN)


@pytest.mark.parametrize("k", range(len(PLAN)))
def test_a_killed_recording_keeps_all_but_its_last_second(killed, k):
    run = killed[k]
    stats = scan_log(run.path)
    ins_stats = stats.topics["/ins/record"]
    assert stats.files[0].metadata["sisa.recording"]["test"] == "crash"
    assert ins_stats.count >= run.rate_hz * (run.after_ready_s - 1.5)
    assert ins_stats.lost_by_sequence == 0
    loss_ns = run.kill_ns - stats.end_ns
    assert 0 < loss_ns <= MAX_LOSS_NS, f"lost {loss_ns / 1e9:.3f} s"
    counters = read_columns(run.path, Topic.INS_RECORD)["counter"]
    assert np.array_equal(counters, np.arange(len(counters)) % 65536)


@pytest.mark.parametrize("k", range(len(PLAN)))
def test_a_killed_recording_recovers_into_a_complete_file(killed, k, tmp_path):
    run = killed[k]
    out = tmp_path / "recovered.mcap"
    report = recover(run.path, out)
    assert report.messages == scan_log(run.path).messages
    with out.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        assert summary.statistics is not None
        assert summary.statistics.message_count == report.messages
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert metadata["sisa.recovered"]["source_complete"] == "false"
    assert metadata["sisa.recording"]["test"] == "crash"
    assert list(read_log(out)) == list(read_log(run.path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recovered.mcap"]


def test_sisa_log_recover_never_overwrites_and_leaves_nothing_on_bad_input(killed, tmp_path,
                                                                           capsys):
    out = tmp_path / "out.mcap"
    out.write_bytes(b"keep me")
    assert main(["log", "recover", str(killed[0].path), str(out)]) == 2
    assert out.read_bytes() == b"keep me"
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x00" * 100)
    assert main(["log", "recover", str(junk), str(tmp_path / "new.mcap")]) == 2
    assert main(["log", "recover", str(tmp_path / "missing.mcap"), str(tmp_path / "n.mcap")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3
    assert all(line.startswith("sisa log: error: ") for line in err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.mcap", "out.mcap"]


# --- disk full ----------------------------------------------------------------------------------

def _fill_disk(monkeypatch, room):
    monkeypatch.setattr(writer_module, "_open_new", Disk(room).open)


def test_disk_full_is_one_recorder_error_and_the_file_reads_up_to_it(tmp_path, monkeypatch):
    _fill_disk(monkeypatch, 300_000)
    path = tmp_path / "full.mcap"
    written = 0

    def record() -> None:
        nonlocal written
        with FlightRecorder(path) as rec:
            for i in range(100_000):
                rec.write(ins(1_700_000_000 * 10**9 + i * 500_000, i))
                written += 1

    with pytest.raises(RecorderError) as err:
        record()
    text = str(err.value)
    assert "\n" not in text
    assert "No space left on device" in text
    assert str(path) in text
    assert path.stat().st_size == 300_000
    counters = read_columns(path, Topic.INS_RECORD)["counter"]
    assert 0 < len(counters) <= written
    assert np.array_equal(counters, np.arange(len(counters)))
    assert scan_log(path).truncated
    report = recover(path, tmp_path / "saved.mcap")
    assert report.messages == len(counters)


def test_after_a_disk_error_every_call_raises_the_same_error(tmp_path, monkeypatch):
    _fill_disk(monkeypatch, 5_000)
    rec = FlightRecorder(tmp_path / "full.mcap", chunk_size=1024)
    first = None
    for i in range(10_000):
        try:
            rec.write(ins(1_700_000_000 * 10**9 + i, i))
        except RecorderError as exc:
            first = exc
            break
    assert first is not None
    with pytest.raises(RecorderError) as again:
        rec.write(fix(1_700_000_000 * 10**9, 0))
    assert again.value is first
    rec.close()  # already reported: closing is quiet


def test_a_real_file_size_limit_ends_the_child_with_one_line(tmp_path):
    """RLIMIT_FSIZE: the kernel itself refuses the write (EFBIG), partial writes included."""
    path = tmp_path / "limited.mcap"
    proc = subprocess.run([sys.executable, "-m", "tests.recorder.crash_child", str(path), "20000",
                           "250000"], capture_output=True, text=True, cwd=ROOT, timeout=60,
                          check=False)
    assert proc.returncode == 3, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "ready"
    assert len(lines) == 2
    assert lines[1].startswith("error ")
    assert "File too large" in lines[1]
    assert path.stat().st_size <= 250_000
    written = int(lines[1].split()[1])
    stats = scan_log(path)
    assert 0 < stats.messages <= written
    assert stats.topics["/ins/record"].lost_by_sequence == 0
