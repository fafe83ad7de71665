"""The INS navigation record on the CAN bus: seven classic frames, declared once, encoded by the
emulator and assembled by the acquisition.

Every frame has an 11-bit ID, DLC 8 and little-endian bit numbering (see acquisition.fields; a DBC
generated from the same declaration is `acquisition/ins.dbc`). Positions are start bit | length:

| ID    | frame            | 0|8 | payload (LSB)                                                |
|-------|------------------|-----|--------------------------------------------------------------|
| 0x100 | INS_TIME         | seq | status 8|8, ins_time_ticks 16|48 (100 ns)                    |
| 0x101 | INS_ROLL_PITCH   | seq | roll_rad 8|28 s, pitch_rad 36|28 s (1e-7 rad)                |
| 0x102 | INS_HEADING      | seq | heading_rad 8|32 (1e-7 rad, [0, 2π)), counter_high 40|24     |
| 0x103 | INS_RATE_XY      | seq | body_rate_x_rps 8|24 s, body_rate_y_rps 32|24 s (1e-6 rad/s) |
| 0x104 | INS_RATE_Z_VEL_N | seq | body_rate_z_rps 8|24 s, vel_n_mps 32|24 s (1 mm/s)           |
| 0x105 | INS_VEL_ED       | seq | vel_e_mps 8|24 s, vel_d_mps 32|24 s (1 mm/s)                 |
| 0x106 | INS_SYNC         | seq | sync_time_ticks 8|48 (100 ns), crc8 56|8                     |

s = signed (two's complement). `seq` is the low byte of the record counter and `counter_high` the
rest (counter = counter_high·256 + seq), so every frame says which record it belongs to and the
assembler never joins frames of two records. Bits 56–63 of 0x103–0x105 are zero. `crc8` is
CRC-8/SAE-J1850 over the 55 bytes before it (frames in ID order, seq bytes included): a real
controller drops frames that fail the bus CRC, but the record CRC also catches corruption introduced
above the bus (emulated faults, gateways, logs) and a frame from another record that slipped in.
The SYNC_PULSE status bit is the record's sync_flag: a pulse was latched since the previous record,
at INS-clock time sync_time_ticks.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from enum import IntEnum, IntFlag
from typing import NamedTuple

import can

from acquisition.checksums import crc8_sae_j1850
from acquisition.codec import Decoded, DecodeStats, ErrorPolicy, report_error
from acquisition.fields import Field, Layout, LayoutError
from sisa.core.errors import EncodeError

TICK_NS = 100
TICKS_MASK = (1 << 48) - 1  # the INS clock and the latch wrap at 48 bits
FRAME_BYTES = 8
DBC_TRANSMITTER = "INS"
DBC_RECEIVER = "SISA"

_ATTITUDE_LSB_RAD = 1e-7
_RATE_LSB_RPS = 1e-6
_VEL_LSB_MPS = 1e-3


class InsStatus(IntFlag):
    """Status bits of a record; bits 5–7 are reserved and must be zero."""

    ALIGNING = 0x01  # static alignment running: attitude not yet valid
    NAVIGATING = 0x02  # aligned, navigating
    DEGRADED = 0x04  # navigating with reduced accuracy
    REBOOTED = 0x08  # first records after power-up: clock and counter restarted
    SYNC_PULSE = 0x10  # a sync pulse was latched since the previous record (= sync_flag)


class InsFrameId(IntEnum):
    """Arbitration IDs, in the order the frames of one record are sent."""

    TIME = 0x100
    ROLL_PITCH = 0x101
    HEADING = 0x102
    RATE_XY = 0x103
    RATE_Z_VEL_N = 0x104
    VEL_ED = 0x105
    SYNC = 0x106


@dataclass(frozen=True)
class InsRecord:
    """One navigation record as the INS sends it (its own clock, not GPS time)."""

    counter: int  # record counter, wraps at 2^counter_bits
    ins_time_ticks: int  # INS clock, 100 ns ticks, wraps at 2^48
    roll_rad: float
    pitch_rad: float
    heading_rad: float  # true heading in [0, 2π)
    body_rate_rps: tuple[float, float, float]  # x, y, z (body frame)
    vel_ned_mps: tuple[float, float, float]  # north, east, down
    status: InsStatus
    sync_flag: bool  # a pulse was latched since the previous record
    sync_time_ticks: int  # INS-clock time of the latched pulse, 100 ns ticks, wraps at 2^48


@dataclass(frozen=True)
class FrameSpec:
    frame_id: InsFrameId
    layout: Layout
    comment: str


def _angle(name: str, start: int, length: int, low: float, high: float) -> Field:
    return Field(name, start, length, signed=low < 0, scale=_ATTITUDE_LSB_RAD, unit="rad",
                 minimum=low, maximum=high)


def _rate(name: str, start: int) -> Field:
    return Field(name, start, 24, signed=True, scale=_RATE_LSB_RPS, unit="rad/s",
                 minimum=-4.0, maximum=4.0, comment="body angular rate")


def _vel(name: str, start: int) -> Field:
    return Field(name, start, 24, signed=True, scale=_VEL_LSB_MPS, unit="m/s",
                 minimum=-1000.0, maximum=1000.0, comment="velocity in local level NED")


def _ticks(name: str, start: int, comment: str) -> Field:
    return Field(name, start, 48, unit="100ns", comment=comment)


_SEQ = Field("seq", 0, 8, comment="low 8 bits of the record counter")


def _frame(frame_id: InsFrameId, comment: str, *fields: Field) -> FrameSpec:
    return FrameSpec(frame_id, Layout(f"INS_{frame_id.name}", FRAME_BYTES, (_SEQ, *fields)),
                     comment)


FRAMES: tuple[FrameSpec, ...] = (
    _frame(InsFrameId.TIME, "record time and status",
           Field("status", 8, 8, maximum=0x1F, comment="InsStatus bits; 5-7 reserved"),
           _ticks("ins_time_ticks", 16, "INS clock at the record time, wraps at 2^48")),
    _frame(InsFrameId.ROLL_PITCH, "attitude",
           _angle("roll_rad", 8, 28, -math.pi, math.pi),
           _angle("pitch_rad", 36, 28, -math.pi / 2, math.pi / 2)),
    _frame(InsFrameId.HEADING, "true heading and high part of the counter",
           _angle("heading_rad", 8, 32, 0.0, 2 * math.pi),
           Field("counter_high", 40, 24, comment="record counter without its low byte")),
    _frame(InsFrameId.RATE_XY, "body rates x, y",
           _rate("body_rate_x_rps", 8), _rate("body_rate_y_rps", 32)),
    _frame(InsFrameId.RATE_Z_VEL_N, "body rate z, north velocity",
           _rate("body_rate_z_rps", 8), _vel("vel_n_mps", 32)),
    _frame(InsFrameId.VEL_ED, "east and down velocity",
           _vel("vel_e_mps", 8), _vel("vel_d_mps", 32)),
    _frame(InsFrameId.SYNC, "latched sync pulse and record checksum",
           _ticks("sync_time_ticks", 8, "INS clock when the sync pulse was latched"),
           Field("crc8", 56, 8, comment="CRC-8/SAE-J1850 over the 55 record bytes before it")),
)

FRAMES_PER_RECORD = len(FRAMES)
RECORD_BYTES = FRAMES_PER_RECORD * FRAME_BYTES
_INDEX_BY_ID = {int(spec.frame_id): i for i, spec in enumerate(FRAMES)}
_FIELD_BY_NAME = {f.name: f for spec in FRAMES for f in spec.layout.fields}
_SEQ_RING = 256 * FRAMES_PER_RECORD  # frame positions before seq repeats

if FRAMES[-1].layout.fields[-1] != _FIELD_BY_NAME["crc8"] or _FIELD_BY_NAME["crc8"].start_bit != 56:
    raise LayoutError("crc8 must be the last byte of the last frame")


# --- checksum -------------------------------------------------------------------------------



# --- encoding -------------------------------------------------------------------------------

def _wire_values(rec: InsRecord) -> dict[str, float]:
    rx, ry, rz = rec.body_rate_rps
    vn, ve, vd = rec.vel_ned_mps
    return {
        "seq": rec.counter & 0xFF, "counter_high": rec.counter >> 8, "status": int(rec.status),
        "ins_time_ticks": rec.ins_time_ticks, "sync_time_ticks": rec.sync_time_ticks,
        "roll_rad": rec.roll_rad, "pitch_rad": rec.pitch_rad, "heading_rad": rec.heading_rad,
        "body_rate_x_rps": rx, "body_rate_y_rps": ry, "body_rate_z_rps": rz,
        "vel_n_mps": vn, "vel_e_mps": ve, "vel_d_mps": vd, "crc8": 0,
    }


def _check_record(rec: InsRecord, counter_bits: int) -> None:
    if not 0 <= rec.counter < 1 << counter_bits:
        raise EncodeError(f"counter = {rec.counter} is outside [0, 2^{counter_bits})")
    if (InsStatus.SYNC_PULSE in rec.status) != rec.sync_flag:
        raise EncodeError(f"sync_flag = {rec.sync_flag} disagrees with status {rec.status!r}: "
                          "the SYNC_PULSE bit carries sync_flag on the wire")
    if rec.heading_rad >= 2 * math.pi:
        raise EncodeError(f"heading_rad = {rec.heading_rad!r} is not in [0, 2π)")


def _pack_frames(values: dict[str, float]) -> list[bytes]:
    """The frames' data, the checksum put in the last byte (packed as 0 first: the CRC
    covers the 55 bytes before it, checked above)."""
    datas = [spec.layout.pack_from(values) for spec in FRAMES]
    datas[-1] = datas[-1][:-1] + bytes((crc8_sae_j1850(b"".join(datas)[:-1]),))
    return datas


_FRAME_IDS = tuple(int(spec.frame_id) for spec in FRAMES)


def encode_record(rec: InsRecord, *, counter_bits: int = 16) -> list[can.Message]:
    """The record's frames in send order; values are rounded to the nearest LSB.

    Raises EncodeError for a value outside its declared range or a counter that does not fit
    counter_bits (the emulator wraps its counter; this refuses one that was not wrapped).
    """
    _check_record(rec, counter_bits)
    return [can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)
            for frame_id, data in zip(_FRAME_IDS, _pack_frames(_wire_values(rec)), strict=True)]


# --- decoding -------------------------------------------------------------------------------

def frames_from_raw(raw: bytes) -> list[tuple[int, bytes]]:
    """Split a Decoded.raw back into (arbitration ID, data) pairs.

    Decoded.raw of a record is its frames in order, each as the ID (u16 little-endian) followed by
    the 8 data bytes, so the log keeps exactly what came off the bus.
    """
    step = 2 + FRAME_BYTES
    return [(int.from_bytes(raw[i:i + 2], "little"), raw[i + 2:i + step])
            for i in range(0, len(raw), step)]


def _unpack_frames(datas: list[bytes]) -> tuple[dict[str, int], list[str]]:
    """Raw values of every field, and the names of those outside their declared range."""
    raws: dict[str, int] = {}
    bad: list[str] = []
    for spec, data in zip(FRAMES, datas, strict=True):
        bad += spec.layout.unpack_raw_into(data, raws)
    return raws, bad


_SCALING = {name: (f.scale, f.offset) for name, f in _FIELD_BY_NAME.items()}


def _record_from_raws(raws: dict[str, int]) -> InsRecord:
    def phys(name: str) -> float:  # (Field.to_physical, its scaling looked up once)
        scale, offset = _SCALING[name]
        return raws[name] * scale + offset

    status = InsStatus(raws["status"])
    return InsRecord(
        counter=(raws["counter_high"] << 8) | raws["seq"],
        ins_time_ticks=raws["ins_time_ticks"],
        roll_rad=phys("roll_rad"), pitch_rad=phys("pitch_rad"), heading_rad=phys("heading_rad"),
        body_rate_rps=(phys("body_rate_x_rps"), phys("body_rate_y_rps"), phys("body_rate_z_rps")),
        vel_ned_mps=(phys("vel_n_mps"), phys("vel_e_mps"), phys("vel_d_mps")),
        status=status, sync_flag=InsStatus.SYNC_PULSE in status,
        sync_time_ticks=raws["sync_time_ticks"],
    )


@dataclass
class CanFrameStats:
    """Frame-level counts beside the record-level DecodeStats."""

    lost: int = 0  # missing by sequence position: exact while < 128 records go missing in a row
    # (a jump forward counts once the next frame follows it: a lone frame out of sequence is a
    # corrupted seq byte, not a loss); with arrival times, never more than the bus could carry
    duplicate: int = 0  # identical to the frame just before (a retransmission)
    foreign: int = 0  # other IDs, extended IDs, remote or error frames: other nodes' traffic
    malformed: int = 0  # one of our IDs with a DLC other than 8
    restarts: int = 0  # the sender began again at seq 0 after a silence: a reboot, not a loss


@dataclass
class _Partial:
    """Frames received so far of one record (all with the same seq)."""

    seq: int
    frames: list[tuple[int, bytes]] = field(default_factory=list)
    last_index: int = -1
    broken: bool = False  # a frame of this record is missing or conflicting


RESTART_SILENCE_NS = 500_000_000  # silence before a seq-0 frame that marks a device restart
# the most frames any classic CAN bus carries: 1 Mbit/s over a frame of 8 data bytes without
# stuffing (111 bits). Frames counted lost, plus those received, cannot outrun it: random
# sequence numbers (a garbage stream, a foreign node on our IDs) otherwise counted hundreds
# lost per frame received (53 M for 270 k in a hostile-device sweep)
MAX_FRAMES_PER_S = 1_000_000 // 111


class InsRecordAssembler:
    """Joins the frames of each record, checks them, and yields records.

    A record is delivered only when its seven frames arrive in order with one seq and the CRC and
    every range check pass. Every other record seen at least in part (joining the bus mid-record
    included) counts one error, framing (incomplete, out of range) or checksum (CRC mismatch),
    and its frames count as skipped bytes; a frame with a corrupted seq byte splits its record
    into pieces that count one error each. Under ErrorPolicy.RAISE the error raises DecodeError,
    whose offset is the number of frames fed before the failing one and whose raw holds the
    rejected frames (as in Decoded.raw). A record still open at the end is counted by flush().
    """

    def __init__(self, policy: ErrorPolicy = ErrorPolicy.COUNT) -> None:
        self.policy = policy
        self.stats = DecodeStats()
        self.frames = CanFrameStats()
        self._partial: _Partial | None = None
        self._last_frame: tuple[int, bytes] | None = None
        self._last_position: int | None = None
        self._jump: tuple[int, int] | None = None  # (position, frames skipped) not yet trusted
        self._last_t_ns: int | None = None
        self._frames_fed = 0
        # frames the bus could have carried unseen (with arrival times), as of the arrival
        # `_room_t_ns` and the frame count `_room_fed`: brought up to date only when a loss
        # is counted, not per frame
        self._loss_room = 0.0
        self._room_t_ns: int | None = None
        self._room_fed = 0

    def feed(self, msg: can.Message, t_ns: int | None = None) -> Decoded[InsRecord] | None:
        """Take one frame off the bus; return a record when this frame completes one. With the
        frame's arrival time `t_ns`, a first frame of seq 0 after `RESTART_SILENCE_NS` of
        silence is the device starting again (counted in `frames.restarts`): the frames it
        did not send in between are not lost."""
        self._frames_fed += 1
        index = self._our_index(msg)
        if index is None:
            self.frames.foreign += 1
            return None
        frame = (msg.arbitration_id, bytes(msg.data))
        if len(frame[1]) != FRAME_BYTES:
            self.frames.malformed += 1
            self.stats.bytes_skipped += len(frame[1])
            if self._partial is not None:
                self._partial.broken = True
            return None
        if frame == self._last_frame:
            self.frames.duplicate += 1
            return None
        self._last_frame = frame
        if t_ns is not None:
            if self._room_t_ns is None:
                self._room_t_ns, self._room_fed = t_ns, self._frames_fed
            silent = self._last_t_ns is not None and t_ns - self._last_t_ns > RESTART_SILENCE_NS
            self._last_t_ns = t_ns
            if silent and frame[1][0] == 0 and index == 0:
                self.frames.restarts += 1
                self._last_position, self._jump = None, None
        self._count_gap(frame[1][0], index)
        return self._place(frame[1][0], index, frame)

    def flush(self) -> None:
        """End of stream: count a record left incomplete."""
        if self._partial is not None:
            partial, self._partial = self._partial, None
            self._reject(partial, "framing", "record incomplete at end of stream")

    @staticmethod
    def _our_index(msg: can.Message) -> int | None:
        if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return None
        return _INDEX_BY_ID.get(msg.arbitration_id)

    def _count_gap(self, seq: int, index: int) -> None:
        """Frames missing before this one by sequence position. A frame out of sequence is held
        until the next one: if that follows it, the jump was real (frames skipped forward were
        lost); if it follows the frame before, the held frame had a corrupted seq byte (it took
        its slot; its record fails its CRC and counts there); if neither, counting starts
        afresh."""
        position = seq * FRAMES_PER_RECORD + index
        last, held = self._last_position, self._jump
        self._jump = None
        self._last_position = position
        if last is None:
            return
        gap = (position - last - 1) % _SEQ_RING
        if held is not None:
            held_at, skipped = held
            after_held = (position - held_at - 1) % _SEQ_RING
            if after_held < _SEQ_RING // 2 and after_held <= gap:
                self._lose(skipped + after_held)  # the held frame was right
            elif gap < _SEQ_RING // 2:
                self._lose(max(0, gap - 1))  # it was not, and took one slot
            return
        if gap:
            self._jump = (position, gap if gap < _SEQ_RING // 2 else 0)  # 0: a step back
            self._last_position = last

    def _lose(self, frames: int) -> None:
        """Count frames lost; with arrival times, no more than the bus could have carried
        since the first frame, less those received (MAX_FRAMES_PER_S)."""
        if self._last_t_ns is None or self._room_t_ns is None:
            self.frames.lost += frames
            return
        carried = max(0, self._last_t_ns - self._room_t_ns) * MAX_FRAMES_PER_S / 1e9
        room = min(float(_SEQ_RING), self._loss_room + carried
                   - (self._frames_fed - self._room_fed))
        counted = max(0, min(frames, int(room)))
        self.frames.lost += counted
        self._loss_room = room - counted
        self._room_t_ns, self._room_fed = self._last_t_ns, self._frames_fed

    def _place(self, seq: int, index: int, frame: tuple[int, bytes]) -> Decoded[InsRecord] | None:
        partial = self._partial
        if partial is not None and (index == 0 or seq != partial.seq):
            self._partial = None
            self._reject(partial, "framing", f"record seq {partial.seq} incomplete "
                         f"({len(partial.frames)} of {FRAMES_PER_RECORD} frames)")
            partial = None
        if partial is None:
            partial = self._partial = _Partial(seq)
        if index != partial.last_index + 1:
            partial.broken = True
        partial.frames.append(frame)
        partial.last_index = max(partial.last_index, index)
        if index < FRAMES_PER_RECORD - 1:
            return None
        self._partial = None
        return self._finish(partial)

    def _finish(self, partial: _Partial) -> Decoded[InsRecord] | None:
        if partial.broken:
            self._reject(partial, "framing", f"record seq {partial.seq} has missing or "
                         "conflicting frames")
            return None
        datas = [data for _, data in partial.frames]
        payload = b"".join(datas)
        if crc8_sae_j1850(payload[:-1]) != payload[-1]:
            self._reject(partial, "checksum", f"record seq {partial.seq}: CRC-8 mismatch")
            return None
        raws, bad = _unpack_frames(datas)
        if bad:
            self._reject(partial, "framing", f"record seq {partial.seq}: out of range {bad}")
            return None
        self.stats.count_message("ins_record")
        return Decoded(_raw_bytes(partial.frames), _record_from_raws(raws))

    def _reject(self, partial: _Partial, kind: str, message: str) -> None:
        self.stats.bytes_skipped += FRAME_BYTES * len(partial.frames)
        report_error(self.policy, self.stats, kind, message, offset=self._frames_fed - 1,
                     raw=_raw_bytes(partial.frames))


def _raw_bytes(frames: list[tuple[int, bytes]]) -> bytes:
    return b"".join(can_id.to_bytes(2, "little") + data for can_id, data in frames)


# --- bus load -------------------------------------------------------------------------------

class BusLoad(NamedTuple):
    bits_per_record: int  # classic base frames, no stuff bits
    bits_per_record_worst: int  # with the worst-case number of stuff bits
    load: float  # fraction of the bit rate
    load_worst: float


def frame_bits(dlc: int, *, worst_case_stuffing: bool) -> int:
    """Bits on the wire for one classic base-format data frame, interframe space included.

    47 fixed bits (SOF, 11-bit ID, RTR, IDE, r0, DLC, CRC-15, delimiters, ACK, EOF, IFS) plus the
    data; stuffing adds at most one bit per four after the first of the 34 + 8·dlc stuffed bits.
    """
    bits = 47 + 8 * dlc
    return bits + (34 + 8 * dlc - 1) // 4 if worst_case_stuffing else bits


def record_bus_load(rate_hz: float = 64.0, bitrate_bps: int = 500_000) -> BusLoad:
    """The share of a CAN bus the record stream takes at rate_hz records per second."""
    nominal = FRAMES_PER_RECORD * frame_bits(FRAME_BYTES, worst_case_stuffing=False)
    worst = FRAMES_PER_RECORD * frame_bits(FRAME_BYTES, worst_case_stuffing=True)
    return BusLoad(nominal, worst, nominal * rate_hz / bitrate_bps, worst * rate_hz / bitrate_bps)


# --- DBC ------------------------------------------------------------------------------------

def _dbc_number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 2**63 else repr(float(x))


def _dbc_signal(f: Field) -> str:
    sign = "-" if f.signed else "+"
    return (f" SG_ {f.name} : {f.start_bit}|{f.length_bits}@1{sign} "
            f"({_dbc_number(f.scale)},{_dbc_number(f.offset)}) "
            f"[{_dbc_number(f.low)}|{_dbc_number(f.high)}] \"{f.unit}\" {DBC_RECEIVER}")


def _dbc_comments() -> list[str]:
    lines = ['CM_ "SISA INS record: generated by acquisition.ins_can.dbc_text(); do not edit.";']
    for spec in FRAMES:
        lines.append(f'CM_ BO_ {int(spec.frame_id)} "{spec.comment}";')
        lines += [f'CM_ SG_ {int(spec.frame_id)} {f.name} "{f.comment}";'
                  for f in spec.layout.fields if f.comment]
    return lines


def dbc_text() -> str:
    """The DBC file describing every frame and signal, generated from FRAMES."""
    nodes = f"BU_: {DBC_TRANSMITTER} {DBC_RECEIVER}"
    lines = ['VERSION ""', "", "NS_ :", "", "BS_:", "", nodes, ""]
    for spec in FRAMES:
        lines.append(f"BO_ {int(spec.frame_id)} {spec.layout.name}: {FRAME_BYTES} "
                     f"{DBC_TRANSMITTER}")
        lines += [_dbc_signal(f) for f in spec.layout.fields]
        lines.append("")
    return "\n".join([*lines, *_dbc_comments()]) + "\n"


if __name__ == "__main__":  # regenerate: python -m acquisition.ins_can > acquisition/ins.dbc
    sys.stdout.write(dbc_text())
