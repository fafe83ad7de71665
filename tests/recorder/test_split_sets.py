"""The parts of a split recording are read as ONE flight: never mixed with another flight's, in
part order whatever order they are given in, and a part that is missing is said.

Found by a bad-input sweep: a part of another flight in the folder was merged silently (`sisa
georef` ran 10 minutes and gave wrong products), a missing middle part only showed as a gap, a
set given out of order was read so, and `log recover` of a first part hid the others.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from recorder import writer as writer_module
from recorder.columns import read_columns, read_topics
from recorder.messages import RawBytes, Topic
from recorder.parts import MissingPartWarning, flight_parts, recording_metadata
from recorder.reader import scan_log
from recorder.recover import recover
from recorder.writer import FlightRecorder, part_path, split_parts
from sisa.cli import main
from sisa.core.errors import InputError
from tests.recorder import T0_NS

STEP_NS = 10_000_000  # one message every 10 ms
SPLIT_S = 10.0


def _record(folder: Path, t0_ns: int = T0_NS, n: int = 4000, name: str = "flight.mcap",
            split_s: float | None = SPLIT_S) -> list[Path]:
    """A flight of `n` GPS sentences 10 ms apart, in parts of 10 s of log time (4 parts)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    with FlightRecorder(path, split_duration_s=split_s) as rec:
        for i in range(n):
            rec.write(RawBytes(t0_ns + i * STEP_NS, "gps", b"$GPZDA,%d\r\n" % i), Topic.GPS_RAW)
    return split_parts(path)


def _mixed(folder: Path, a: list[Path], b: list[Path]) -> list[Path]:
    """Parts 0, 1, 3 of flight `a` and part 2 of flight `b`, side by side as flight*.mcap."""
    folder.mkdir()
    for src in (a[0], a[1], b[2], a[3]):
        shutil.copy(src, folder / src.name)
    return split_parts(folder / "flight.mcap")


def _part_metadata_edited(monkeypatch: pytest.MonkeyPatch,
                          edit: Callable[[dict[str, str]], dict[str, str]]) -> None:
    """The recorder writing each part's metadata as `edit` makes it."""
    real = writer_module._Part.create.__func__  # type: ignore[attr-defined]

    def create(cls: type, path: Path, chunk_size: int, metadata: dict[str, str]) -> object:
        return real(cls, path, chunk_size, edit(metadata))

    monkeypatch.setattr(writer_module._Part, "create", classmethod(create))


@pytest.fixture
def without_ids(monkeypatch: pytest.MonkeyPatch) -> None:
    """The recorder as it was before parts carried a recording id."""
    _part_metadata_edited(monkeypatch, lambda metadata: {
        k: v for k, v in metadata.items() if k != "recording_id"})


def test_every_part_carries_its_recorders_own_recording_id(tmp_path: Path) -> None:
    a, b = _record(tmp_path / "a"), _record(tmp_path / "b")
    ids_a = {recording_metadata(p)["recording_id"] for p in a}
    ids_b = {recording_metadata(p)["recording_id"] for p in b}
    assert len(a) == 4
    assert len(ids_a) == len(ids_b) == 1
    assert ids_a != ids_b
    assert len(next(iter(ids_a))) == 32  # a UUID's hex


def test_the_callers_metadata_never_replaces_the_recorders_own(tmp_path: Path) -> None:
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={"part": 7, "recording_id": "x", "scenario": "s"}) as rec:
        rec.write(RawBytes(T0_NS, "gps", b"x"), Topic.GPS_RAW)
    meta = recording_metadata(path)
    assert (meta["part"], meta["recording_id"], meta["scenario"]) == ("0", rec.recording_id, "s")


def test_a_part_of_another_flight_is_refused_by_the_readers_and_commands(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a, b = _record(tmp_path / "a"), _record(tmp_path / "b", T0_NS + 100 * 10**9)
    parts = _mixed(tmp_path / "mixed", a, b)
    id_a, id_b = (recording_metadata(p[0])["recording_id"] for p in (a, b))
    said = (f"{parts[2]} is part 2 of another recording (id {id_b}) than {parts[0]} (id "
            f"{id_a}): each flight's parts are read together, not mixed")
    for read in (scan_log, lambda p: read_topics(p, {"/gps/raw": None}), flight_parts):
        with pytest.raises(InputError) as err:
            read(parts)
        assert str(err.value) == said
    with pytest.raises(InputError, match="is part 2 of another recording"):
        flight_parts([parts[0]])  # the first part alone: the others are found beside it
    assert main(["log", "info", str(parts[0])]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"sisa log: error: {said}"]
    assert captured.out == ""


@pytest.mark.usefixtures("without_ids")
@pytest.mark.parametrize("offset_s", [-100, 100])
def test_parts_without_an_id_of_another_flight_are_refused_by_their_log_times(
        tmp_path: Path, offset_s: int) -> None:
    """Before: the span grew (549 s -> 783 s), with an INS 'reboot' in the middle."""
    a, b = _record(tmp_path / "a"), _record(tmp_path / "b", T0_NS + offset_s * 10**9)
    assert "recording_id" not in recording_metadata(a[0])
    parts = _mixed(tmp_path / "mixed", a, b)
    late = parts[2] if offset_s < 0 else parts[3]  # b's part begins before a's part 1 ends,
    # or a's part 3 before b's part 2 ends
    before = parts[1] if offset_s < 0 else parts[2]
    with pytest.raises(InputError) as err:
        scan_log(parts)
    assert str(err.value).startswith(f"{late} is part of another recording than {before}: it "
                                     "begins ")
    assert scan_log(a).topics["/gps/raw"].count == 4000  # its own parts read whole


@pytest.mark.usefixtures("without_ids")
def test_parts_without_an_id_named_for_another_first_part_are_refused(tmp_path: Path) -> None:
    a = _record(tmp_path / "a")
    b = _record(tmp_path / "b", name="other.mcap")  # the same log times
    shutil.copy(b[2], tmp_path / "a" / "flight_002.mcap")
    with pytest.raises(InputError, match=r"flight_002\.mcap is part 2 of another recording \(no "
                       r"recording id, first part other\.mcap\) than .*flight\.mcap \(no "
                       r"recording id, first part flight\.mcap\)"):
        scan_log(a)


@pytest.mark.usefixtures("without_ids")
def test_parts_without_an_id_may_overlap_by_a_threads_wait(tmp_path: Path) -> None:
    """A message stamped before a split and written after it is no reason to refuse a log."""
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, split_duration_s=SPLIT_S) as rec:
        for i in range(1500):
            rec.write(RawBytes(T0_NS + i * STEP_NS, "gps", b"x"), Topic.GPS_RAW)
        rec.write(RawBytes(T0_NS + 9 * 10**9, "gps", b"late"), Topic.GPS_RAW)  # into part 1
    parts = split_parts(path)
    assert len(parts) == 2
    assert scan_log(parts).topics["/gps/raw"].count == 1501


def test_a_part_and_its_recovered_copy_are_refused(tmp_path: Path) -> None:
    parts = _record(tmp_path / "a")
    copy = tmp_path / "copy.mcap"
    recover(parts[2], copy)
    with pytest.raises(InputError, match=rf"{copy} is part 2 of the recording, as is "
                       rf"{parts[2]} \(a copy, or a recovered copy of it\?\)"):
        scan_log([*parts, copy])


def test_a_recovered_cut_last_part_reads_with_the_others_in_any_order(tmp_path: Path) -> None:
    parts = _record(tmp_path / "a")
    cut = tmp_path / "cut" / "flight_003.mcap"
    cut.parent.mkdir()
    data = parts[3].read_bytes()
    cut.write_bytes(data[:len(data) * 2 // 3])
    recovered = tmp_path / "recovered.mcap"
    recover(cut, recovered)  # its metadata moves to its end
    stats = scan_log([recovered, parts[0], parts[2], parts[1]])
    assert [f.path for f in stats.files] == [*parts[:3], recovered]
    assert stats.part_notes == []
    gps = stats.topics["/gps/raw"]
    assert 3000 < gps.count < 4000
    assert gps.lost_by_sequence == 0


def test_a_missing_middle_part_is_said_by_log_info_and_the_readers(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parts = _record(tmp_path / "a")
    parts[2].unlink()
    given = split_parts(parts[0])
    note = (f"part 2 (flight_002.mcap) of the split recording flight.mcap is not given "
            f"(between {parts[1]} and {parts[3]}): the log is read without it, a hole in the "
            "flight")
    assert main(["log", "info", str(parts[0])]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"sisa log: warning: {note}"]
    assert "part=3" in captured.out
    assert scan_log(given).part_notes == [note]
    notes: list[str] = []  # sisa georef: its warnings
    read_topics(given, {"/gps/raw": None}, notes=notes)
    assert notes == [note]
    with pytest.warns(MissingPartWarning, match="flight_002.mcap"):  # sisa sync, calibrate
        read_topics(given, {"/gps/raw": None})


def test_many_missing_parts_are_named_in_short(tmp_path: Path) -> None:
    parts = _record(tmp_path / "a", n=9000)
    assert len(parts) == 9
    notes = scan_log([parts[0], parts[8]]).part_notes
    assert notes == [f"parts 1-7 (flight_001.mcap, flight_002.mcap, flight_003.mcap, ..., "
                     f"flight_007.mcap) of the split recording flight.mcap are not given "
                     f"(between {parts[0]} and {parts[8]}): the log is read without them, a "
                     "hole in the flight"]


def test_a_middle_part_alone_says_which_parts_are_not_given(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parts = _record(tmp_path / "a")
    assert main(["log", "info", str(parts[2])]) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"sisa log: warning: {parts[2]} is part 2 of a split recording whose parts 0-1 "
        "(flight.mcap, flight_001.mcap) are not given: the log is read from part 2 on"]
    assert scan_log(parts[1]).part_notes == [
        f"{parts[1]} is part 1 of a split recording whose part 0 (flight.mcap) is not given: "
        "the log is read from part 1 on"]
    assert scan_log(parts[0]).part_notes == []


def test_parts_given_out_of_order_are_read_in_part_order(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parts = _record(tmp_path / "a")
    shuffled = [parts[2], parts[0], parts[3], parts[1]]
    assert flight_parts(shuffled) == parts
    stats = scan_log(shuffled)
    assert [f.path for f in stats.files] == parts
    gps = stats.topics["/gps/raw"]
    assert (gps.count, gps.lost_by_sequence, gps.gap_count) == (4000, 0, 0)
    times = read_columns(shuffled, Topic.GPS_RAW)["log_time_ns"]
    assert np.array_equal(times, T0_NS + STEP_NS * np.arange(4000))
    assert main(["log", "info", *map(str, shuffled)]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    listed = [line.split(":")[0] for line in captured.out.splitlines() if ".mcap:" in line]
    assert listed == [str(p) for p in parts]


def test_recover_of_a_first_part_says_the_further_parts_are_not_in_its_output(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parts = _record(tmp_path / "a")
    out = tmp_path / "rec.mcap"
    assert main(["log", "recover", str(parts[0]), str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"sisa log: warning: flight_001.mcap, flight_002.mcap, flight_003.mcap beside "
        f"{parts[0]} are further parts of the same recording, not in {out}: recover each to "
        f"{out.name}'s numbered names (`sisa log recover {parts[1]} {part_path(out, 1)}`, ...), "
        f"and readers given {out} take them together"]
    assert "(complete)" in captured.out
    for k in (1, 2, 3):  # as it says
        assert main(["log", "recover", str(parts[k]), str(part_path(out, k))]) == 0
    capsys.readouterr()
    assert scan_log(flight_parts([out])).topics["/gps/raw"].count == 4000
    single = _record(tmp_path / "single", n=100, split_s=None)
    assert main(["log", "recover", str(single[0]), str(tmp_path / "single.mcap")]) == 0
    assert capsys.readouterr().err == ""  # a log of one file: nothing to say


def test_part_metadata_damage_made_unprintable_is_shown_escaped_in_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The names and ids the parts' metadata give go into one-line messages: damage there (a
    line break, a terminal's escape sequence) is shown escaped, and the parts still compare
    as they are."""
    damaged = {"first_part": "fl\nig\x1b[2Jht.mcap", "recording_id": "id\x1b[31m\n2"}
    _part_metadata_edited(monkeypatch, lambda metadata: {**metadata, **damaged})
    parts = _record(tmp_path / "a")
    other = _record(tmp_path / "b", T0_NS + 100 * 10**9, name="other.mcap")
    monkeypatch.undo()
    assert recording_metadata(parts[0])["first_part"] == damaged["first_part"]
    notes = scan_log([parts[0], parts[3]]).part_notes  # parts 1-2 not given
    assert notes == [r"parts 1-2 ('fl\nig\x1b[2Jht_001.mcap', 'fl\nig\x1b[2Jht_002.mcap') of "
                     r"the split recording 'fl\nig\x1b[2Jht.mcap' are not given (between "
                     f"{parts[0]} and {parts[3]}): the log is read without them, a hole in "
                     "the flight"]
    good = _record(tmp_path / "c")
    shutil.copy(other[2], tmp_path / "c" / "flight_002.mcap")  # a damaged part among good ones
    assert main(["log", "info", str(good[0])]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "\x1b" not in err
    assert r"(id 'id\x1b[31m\n2')" in err
