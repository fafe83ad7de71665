"""Issue 32, item 1 (post-processing side): the sync does not depend on when the receiver's time
tags reach the host. With 1 of 3 frame pulses tagged (20.8 TTT a second) and every tag held
until the receiver's next second (as the emulator sent them), a host → GPS map through every
(receive time, tag) pair came out at −870 ppm with a 280 ms residual and no INS record was timed.
The map is now made from the PPS edges (their host time is the timing board's report, no serial
message), else the fixes; the tags' receive times are left out."""

from __future__ import annotations

import numpy as np

from postproc.sync import TimeStatus, synchronise
from postproc.sync.report import no_ins_timed_note
from tests.postproc.test_sync_jumps import _flight


def test_late_time_tags_do_not_bend_the_host_map() -> None:
    inp, t_meas, _ = _flight(100.0, 0, one_of_n=3, ttt_held_to_the_second=True)
    res = synchronise(inp)
    ok = res.ins.status == TimeStatus.OK
    beyond = res.ins_solution.timeline.outside_latch_span()  # the flight's ends: never timed
    assert ok[~beyond].mean() >= 0.999
    assert beyond.sum() <= 5 * 64
    assert np.abs(res.ins.t_gps_ns[ok] - t_meas[ok]).max() < 2_000
    host = res.report["pulses"]["host_map"]
    assert abs(host["rate_ppm"] - (-3.0)) < 1.0  # the host clock runs 3 ppm fast
    assert host["residual_rms_ns"] < 1e6
    assert host["from"] == "pps"


def test_the_advice_for_an_all_ambiguous_log_fits_the_log() -> None:
    """`sisa sync` told a log with 346 s of the PPS pattern to record a register period with the
    scanner off: with the pattern in the log, it now points at the coarse (host) time."""
    status = np.full(100, int(TimeStatus.AMBIGUOUS))
    host = {"from": "fixes+tags", "residual_rms_ns": 281_112_802.65, "rate_ppm": -865.87}
    with_pattern = {"pulses": {"lfsr_bits": 4, "forwarded_mode1": 238, "host_map": host}}
    note = no_ins_timed_note(status, with_pattern)
    assert note is not None
    assert "though the log has 238 mode-1 pulses" in note
    assert "residual 281 ms, rate -865.9 ppm" in note
    assert "record a register period" not in note
    without = {"pulses": {"lfsr_bits": 4, "forwarded_mode1": 3, "host_map": host}}
    assert "record a register period" in (no_ins_timed_note(status, without) or "")
    assert no_ins_timed_note(np.zeros(3, dtype=np.int64), with_pattern) is None
