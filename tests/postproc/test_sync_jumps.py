"""Issue 32, item 2: after an INS clock jump the records do not show, the records are timed again
from the pulses that follow it, wherever it falls; only the records between the latches on
either side of the jump are lost (`clock_jump`), never more than the pulse spacing.

Hand-made log arrays (the emulators' clocks and noise, as bench/sync_speed.py makes them): 64 Hz
INS whose clock jumps by −0.4 ms (or +7 ms) at a chosen time, half-way between two records (an
INS measures on its own clock grid, so the jump shows in no record interval), a 4-bit LFSR on the
PPS with the scanner off, 1 of 64 frame pulses of a 16 ms scanner during two strips.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from acquisition.lfsr import Lfsr
from postproc.sync import (
    GpsTimes,
    HeaderColumns,
    InsColumns,
    SisaColumns,
    SyncInput,
    TimeStatus,
    synchronise,
)
from postproc.sync.coarse import Latches
from postproc.sync.insfit import ClockRun
from postproc.sync.insjumps import carry_runs
from postproc.sync.linefit import fit_line

I64 = npt.NDArray[np.int64]
NS = 1_000_000_000
T0 = 1_465_549_200 * NS
INS_OFFSET, INS_PPM, PERIOD, RES = 12_500_000_000, 35.0, 15_625_000, 1_000
LINE_NS, ONE_OF_N = 16_000_000 * (1 + 15e-6), 64
SECONDS = 200
STRIPS = ((60.0, 120.0), (140.0, 196.0))  # the log ends 4 s after the second strip


def _host(t: I64) -> I64:
    return t - 18 * NS + 37_000_000 + np.rint((t - T0) * 3e-6).astype(np.int64)


def _board(t: I64) -> I64:
    return NS + (t - T0) + np.rint((t - T0) * 12e-6).astype(np.int64)


def _flight(jump_at_s: float, jump_ns: int, seed: int = 1, one_of_n: int = ONE_OF_N,
            ttt_held_to_the_second: bool = False) -> tuple[SyncInput, I64, I64]:
    """The log, every record's true measurement epoch, and the jump's record index (the first
    record measured after it). `ttt_held_to_the_second`: every TTT reaches the host only with
    the receiver's next second (as the emulator sent them before issue 32, item 1)."""
    rng = np.random.default_rng(seed)
    sec = T0 + np.arange(SECONDS, dtype=np.int64) * NS
    edge = sec + np.rint(rng.normal(0, 20, SECONDS)).astype(np.int64)
    bits = np.resize(np.array(Lfsr.maximal(4, 1).sequence(15)), SECONDS) == 1
    s = np.arange(SECONDS)
    scanning = np.zeros(SECONDS, dtype=np.bool_)
    for a, b in STRIPS:
        scanning |= (s >= a) & (s <= b + 1)
    fwd1 = bits & ~scanning
    t_mid, seg = [], []
    for i, (a, b) in enumerate(STRIPS):
        k = np.arange(int(a * NS / LINE_NS) + 1, int(b * NS / LINE_NS))
        t_mid.append(T0 + 123_456 + np.rint(k * LINE_NS).astype(np.int64))
        seg.append(np.full(k.size, i))
    mids, segs = np.concatenate(t_mid), np.concatenate(seg).astype(np.int64)
    pick = np.concatenate([np.flatnonzero(segs == i)[2::one_of_n] for i in range(len(STRIPS))])
    pulses = np.sort(np.concatenate([edge[fwd1], mids[pick]]) + 1_000)

    # the INS clock: offset, drift, and a jump at t_jump (placed half-way between two records)
    grid = (-(-INS_OFFSET // PERIOD) + np.arange(SECONDS * 64 - 64, dtype=np.int64)) * PERIOD
    before = T0 + np.ceil((grid - INS_OFFSET) / (1 + INS_PPM * 1e-6)).astype(np.int64)
    j = int(np.searchsorted(before, T0 + round(jump_at_s * NS)))
    t_jump = (before[j - 1] + before[j]) // 2
    after = T0 + np.ceil((grid - INS_OFFSET - jump_ns) / (1 + INS_PPM * 1e-6)).astype(np.int64)
    t_meas = np.where(np.arange(grid.size) < j, before, after)
    assert (np.diff(t_meas) > 0).all()
    assert after[j] >= t_jump

    def clock(t: I64) -> I64:
        e = t - T0
        return INS_OFFSET + e + np.rint(e * INS_PPM * 1e-6).astype(np.int64) + np.where(
            t >= t_jump, jump_ns, 0)

    pulses = pulses[pulses < t_meas[-1]]
    rec, first = np.unique(np.searchsorted(t_meas, pulses), return_index=True)
    flag = np.zeros(grid.size, dtype=np.bool_)
    flag[rec] = True
    latch = np.zeros(grid.size, dtype=np.int64)
    latch[rec] = clock(pulses[first]) // RES * RES // 100
    status = np.full(grid.size, 2, dtype=np.int64) | np.where(flag, 0x10, 0)
    ins = InsColumns(_host(t_meas + 56_500_000 + rng.integers(100_000, 400_000, grid.size)),
                     np.arange(grid.size, dtype=np.int64) % (1 << 16), grid // 100, status, flag,
                     latch)
    n1, n2 = int(fwd1.sum()), pick.size
    out = np.concatenate([edge[fwd1], mids[pick]]) + 1_000
    sisa = SisaColumns(
        _host(edge + 50_000), _board(edge), sec, np.zeros(SECONDS, dtype=np.bool_),
        _host(out), np.zeros(n1 + n2, np.int64), _board(out),
        np.concatenate([np.ones(n1, np.int64), np.full(n2, 2, np.int64)]),
        np.concatenate([np.zeros(n1, np.bool_), np.ones(n2, np.bool_)]),
        np.concatenate([np.zeros(n1, np.bool_), np.ones(n2, np.bool_)]),
        np.concatenate([sec[fwd1], np.full(n2, -1, np.int64)]),
        np.concatenate([np.full(n1, -1, np.int64), pick % (1 << 16)]),
        np.array([4], dtype=np.int64), 2 * len(STRIPS))
    ttt = mids[pick] + 1_000
    sent = -(-ttt // NS) * NS + 25_000_000 if ttt_held_to_the_second else ttt + 30_000_000
    gps = GpsTimes(_host(sec + 48_000_000), sec,
                   np.concatenate([_host(sec + 25_000_000), _host(sent)]),
                   np.concatenate([(edge + 50) // 100 * 100, (ttt + 50) // 100 * 100]),
                   np.concatenate([np.ones(SECONDS, np.bool_), np.zeros(n2, np.bool_)]))
    headers = HeaderColumns(_host(mids + 9_600_000), np.arange(mids.size) % (1 << 16), segs)
    return SyncInput(ins, gps, sisa, headers), t_meas, np.int64(j)


# where the jump falls: in the first block of latches (right after the first pulse); in the
# static PPS stretch; mid-strip; 26 s before the end, in the last strip (2 336 records ambiguous
# in the issue); 6 s before the end, in the strip; in the last seconds, past the strip
JUMP_AT_S = (5.5, 30.2, 95.3, 174.4, 190.6, 197.5)


@pytest.mark.parametrize("jump_ns", [-400_000, 7_000_000])
@pytest.mark.parametrize("jump_at_s", JUMP_AT_S)
def test_records_are_timed_again_from_the_pulses_after_a_jump(jump_at_s: float,
                                                              jump_ns: int) -> None:
    inp, t_meas, j = _flight(jump_at_s, jump_ns)
    res = synchronise(inp)
    ok = res.ins.status == TimeStatus.OK
    err = res.ins.t_gps_ns[ok] - t_meas[ok]
    assert np.abs(err).max() < 2_000  # no wrong tag: every time within 2 µs
    lr = res.ins_solution.timeline.latch_record
    last = lr[lr < j].max() if (lr < j).any() else -1
    nxt = lr[lr >= j].min()
    beyond = res.ins_solution.timeline.outside_latch_span()  # the flight's ends: never timed
    assert not ok[beyond].any()
    assert beyond.sum() <= 5 * 64
    lost = np.flatnonzero(~ok & ~beyond)
    # only the records measured between the latched pulses on either side of the jump are lost
    # (the record carrying a latch is measured after its pulse)
    assert lost.size == 0 or (lost.min() >= last and lost.max() < nxt), (lost.min(), lost.max())
    assert (res.ins.status[lost] == TimeStatus.CLOCK_JUMP).all() or last < 0
    spacing = (t_meas[nxt] - t_meas[max(last, 0)]) / NS
    assert spacing <= 4.1  # the pulse spacing: 1.024 s in a strip, ≤ 4 s of the LFSR
    assert lost.size <= spacing * 64 + 1


def test_a_pulse_train_too_dense_to_tell_the_jump_stays_flagged() -> None:
    """With a forwarded pulse every 10 ms, two pulses lie within a record period of where the
    line puts the first latch after the jump: which one it was is unknown, so nothing past the
    jump is timed on it (never a guess)."""
    x = np.arange(0.0, 10.0, 0.5)
    y = np.sort(np.concatenate([x[:10] + 100.0, 100.0 + np.arange(5.0, 10.0, 0.01)]))
    lat = Latches(x, np.zeros(x.size, np.int64), x + 100.0)
    pul = np.searchsorted(y, x[:10] + 100.0)
    run = ClockRun(0, fit_line(x[:10], y[pul]), np.arange(10), pul)
    # past x = 5 s the latches came 3 ms late on the INS clock: a jump
    lat = Latches(np.concatenate([x[:10], x[10:] + 0.003]), lat.piece, lat.u_s)
    assert carry_runs([run], lat, y, 5e-7, 3e-6, 0.015625) == [run]
