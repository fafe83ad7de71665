"""Issue 32, item 5: the sync report counts frames the scanner dropped and frame headers lost on
the serial link apart. `sync_report.json` said 33 frames dropped where 0 were: the gaps in the
header stream were all taken for dropped frames. A dropped frame has no line in the lines files
and no header; a lost header leaves its line in the files. Hand-made logs (tests/postproc/
test_sync_jumps.py's flight, no jump): every frame recorded and its header logged, then some
frames dropped and some headers lost."""

from __future__ import annotations

import dataclasses

import numpy as np

from postproc.sync import TimeStatus, header_order_note, synchronise
from postproc.sync.flightlog import HeaderColumns, SyncInput
from postproc.sync.lines import LineTable
from tests.postproc.test_sync_jumps import _flight


def _drop(inp: SyncInput, dropped: np.ndarray, lost: np.ndarray) -> tuple[SyncInput, LineTable]:
    """The log without the headers of `dropped` and `lost` frames, and the lines files without
    the `dropped` frames (indices into the headers)."""
    hdr = inp.headers
    keep_hdr = np.ones(hdr.segment.size, dtype=np.bool_)
    keep_hdr[np.concatenate([dropped, lost])] = False
    keep_line = np.ones(hdr.segment.size, dtype=np.bool_)
    keep_line[dropped] = False
    seg = hdr.segment[keep_line]
    line = np.concatenate([np.arange(np.count_nonzero(seg == s)) for s in np.unique(seg)])
    table = LineTable(seg, line, hdr.frame_counter[keep_line])
    logged = HeaderColumns(hdr.t_host_ns[keep_hdr], hdr.frame_counter[keep_hdr],
                           hdr.segment[keep_hdr])
    return dataclasses.replace(inp, headers=logged), table


def test_lost_headers_are_not_dropped_frames() -> None:
    inp, _, _ = _flight(100.0, 0)
    rng = np.random.default_rng(2)
    n = inp.headers.segment.size
    lost = np.sort(rng.choice(np.arange(100, n - 100), 33, replace=False))
    inp, table = _drop(inp, np.zeros(0, dtype=np.int64), lost)
    bare = synchronise(inp).report["lines"]  # no lines files: which gaps are frames is unknown
    assert bare["frames_dropped"] is None
    assert bare["headers_lost"] is None
    assert bare["header_gaps"] == 33
    res = synchronise(inp, table)
    counts = res.report["lines"]
    assert counts["frames_dropped"] == 0
    assert counts["headers_lost"] == 33
    assert counts["header_gaps"] == 33
    assert (res.lines.status == TimeStatus.OK).all()  # a lost header costs its line nothing


def test_dropped_frames_and_lost_headers_counted_apart() -> None:
    inp, _, _ = _flight(100.0, 0)
    rng = np.random.default_rng(3)
    n = inp.headers.segment.size
    both = rng.choice(np.arange(100, n - 100), 25, replace=False)
    dropped, lost = np.sort(both[:10]), np.sort(both[10:])
    inp, table = _drop(inp, dropped, lost)
    counts = synchronise(inp, table).report["lines"]
    assert (counts["frames_dropped"], counts["headers_lost"], counts["header_gaps"]) == (10, 15, 25)


def test_header_order_numbers_are_flagged_from_the_first_gap() -> None:
    """Without the lines files a line is numbered by header order: after a lost header the
    number is one short of the image's line, and its time would go on the wrong image line, a
    line period off. Nothing said so; the report now names where the numbers stop being sure,
    and sisa sync / calibrate warn."""
    inp, _, _ = _flight(100.0, 0)
    hdr = inp.headers
    seg = int(hdr.segment[hdr.segment.size // 2])
    in_seg = np.flatnonzero(hdr.segment == seg)
    lost = in_seg[[in_seg.size // 3, in_seg.size // 2]]
    first_line = in_seg.size // 3  # the line number the header after the first lost one gets
    inp, table = _drop(inp, np.zeros(0, dtype=np.int64), lost)
    bare = synchronise(inp)
    assert bare.report["lines"]["header_order_first_gap"] == {str(seg): first_line}
    # why it matters: from the first gap on, header order and the image's lines disagree
    mine = bare.lines.segment == seg
    by_order = bare.lines.line[mine]
    files = table.segment == seg
    by_files = table.line[files][np.isin(table.frame_counter[files], inp.headers.frame_counter)]
    assert np.array_equal(by_order[:first_line], by_files[:first_line])
    assert (by_order[first_line:] != by_files[first_line:]).all()
    note = header_order_note(bare.report["lines"])
    assert note is not None
    assert f"segment {seg} from line {first_line}" in note
    assert "--scanner" in note
    # with the lines files the numbers are the files': nothing to say
    assert synchronise(inp, table).report["lines"]["header_order_first_gap"] is None
    assert header_order_note(synchronise(inp, table).report["lines"]) is None


def test_no_header_order_note_without_gaps() -> None:
    inp, _, _ = _flight(100.0, 0)
    lines = synchronise(inp).report["lines"]
    assert lines["header_order_first_gap"] == {}
    assert header_order_note(lines) is None
