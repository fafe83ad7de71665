"""Every message the flight log holds, declared once: its topic, its fields and their units.

The acquisition builds these; the recorder writes them (JSON, one JSON Schema per type, generated
from the dataclass); post-processing reads them back. Times are int64 ns on a named clock:
- `t_host_ns`: the logging computer's clock when the bytes arrived (not GPS time);
- `board_ns`: the SISA timing board's free-running counter (its own offset and drift);
- `t_gps_ns`: GPS time, only where a device stated it (NMEA, PTT, TTT), resolved to a full date.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, get_type_hints


class Topic(StrEnum):
    GPS_RAW = "/gps/raw"
    GPS_FIX = "/gps/fix"
    GPS_LOCATION = "/gps/location_fix"  # foxglove.LocationFix, for the map panel
    GPS_TIME_TAG = "/gps/time_tag"
    INS_RAW = "/ins/raw_can"
    INS_RECORD = "/ins/record"
    SCANNER_RAW = "/scanner/raw"
    SCANNER_HEADER = "/scanner/header"
    CAMERA_RAW = "/camera/raw"
    CAMERA_PHOTO = "/camera/photo"
    PULSE_IN = "/pulses/in"
    PULSE_OUT = "/pulses/out"
    SYNC_SESSION = "/sisa/session"
    SYNC_PPS = "/sisa/pps"
    SYNC_FORWARD = "/sisa/forward"
    SYNC_MODE = "/sisa/mode"
    SYNC_CAMERA = "/sisa/camera_pulse"
    HEALTH = "/sisa/health"


class LoggedMessage:
    """Base of the logged dataclasses: each names its topic and its schema."""

    topic: ClassVar[Topic]
    schema_name: ClassVar[str]
    t_host_ns: int  # every logged message has its host receive time

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)  # type: ignore[call-overload, no-any-return]


@dataclass(frozen=True)
class RawBytes(LoggedMessage):
    """Bytes exactly as read from a serial port, with the host time of the read."""

    topic: ClassVar[Topic] = Topic.GPS_RAW  # overridden per port by the writer
    schema_name: ClassVar[str] = "sisa.RawBytes"
    t_host_ns: int
    port: str
    data: bytes


CAN_EXTENDED_FLAG = 0x8000_0000  # set in an arbitration id when the frame uses 29-bit ids


@dataclass(frozen=True)
class RawCanFrames(LoggedMessage):
    """CAN frames exactly as received, batched (up to 128 frames or 200 ms) to keep the log's
    per-message cost low; every frame keeps its own host receive time."""

    topic: ClassVar[Topic] = Topic.INS_RAW
    schema_name: ClassVar[str] = "sisa.RawCanFrames"
    t_host_ns: int  # receive time of the first frame
    t_offsets_ns: list[int]  # each frame's receive time minus t_host_ns
    arbitration_ids: list[int]  # with CAN_EXTENDED_FLAG for 29-bit ids
    dlcs: list[int]
    data: bytes  # the frames' data bytes, concatenated (lengths in dlcs)


@dataclass(frozen=True)
class GpsFix(LoggedMessage):
    """A decoded GGA (with the date from RMC/ZDA), or a NovAtel BESTPOS: the antenna position
    the receiver reported."""

    topic: ClassVar[Topic] = Topic.GPS_FIX
    schema_name: ClassVar[str] = "sisa.GpsFix"
    t_host_ns: int
    t_gps_ns: int
    lat_deg: float
    lon_deg: float
    height_m: float  # ellipsoidal: GGA altitude + geoid separation (BESTPOS: + undulation)
    quality: int  # GGA's (BESTPOS: of its position type, 0 unless a solution was computed)
    satellites: int
    hdop: float  # NaN from BESTPOS (it states none)


@dataclass(frozen=True)
class GpsTimeTag(LoggedMessage):
    """A receiver's time tag in GPS time: of its PPS (kind "PTT": Ashtech $PASHR,PTT, u-blox
    UBX-TIM-TP or NovAtel TIMEA) or of a pulse on its event input ("TTT": $PASHR,TTT,
    UBX-TIM-TM2 or NovAtel MARK1TIMEA)."""

    topic: ClassVar[Topic] = Topic.GPS_TIME_TAG
    schema_name: ClassVar[str] = "sisa.GpsTimeTag"
    t_host_ns: int
    kind: str  # "PTT" | "TTT"
    gps_time_of_week_ns: int
    t_gps_ns: int  # Ashtech: week of last fix, else receiver's date, else host; others: stated


@dataclass(frozen=True)
class InsRecordLog(LoggedMessage):
    """A decoded INS record, values in SI units as on the wire."""

    topic: ClassVar[Topic] = Topic.INS_RECORD
    schema_name: ClassVar[str] = "sisa.InsRecord"
    t_host_ns: int
    counter: int
    ins_time_ticks: int  # 100 ns ticks of the INS clock, 48-bit, wraps
    roll_rad: float
    pitch_rad: float
    heading_rad: float
    rate_x_rps: float
    rate_y_rps: float
    rate_z_rps: float
    vel_n_mps: float
    vel_e_mps: float
    vel_d_mps: float
    status: int
    sync_flag: bool
    sync_time_ticks: int


@dataclass(frozen=True)
class FrameHeaderLog(LoggedMessage):
    topic: ClassVar[Topic] = Topic.SCANNER_HEADER
    schema_name: ClassVar[str] = "sisa.FrameHeader"
    t_host_ns: int
    frame_counter: int
    integration_time_us: int
    mode: int
    segment: int
    bands: int


@dataclass(frozen=True)
class CameraPhotoLog(LoggedMessage):
    """A decoded photo message of the frame camera (acquisition.camera_photo): which photo it
    has just taken; its host time is when the message arrived, a latency after the exposure."""

    topic: ClassVar[Topic] = Topic.CAMERA_PHOTO
    schema_name: ClassVar[str] = "sisa.CameraPhoto"
    t_host_ns: int
    photo_number: int  # wraps at 2^camera.photo_counter_bits
    exposure_time_us: int


@dataclass(frozen=True)
class PulseEdgeLog(LoggedMessage):
    """A pulse edge seen (in) or generated (out) by the SISA, on its timing board's counter."""

    topic: ClassVar[Topic] = Topic.PULSE_IN
    schema_name: ClassVar[str] = "sisa.PulseEdge"
    t_host_ns: int
    line: str  # PPS | PPF | CAMERA | INS_SYNC | GPS_EVENT
    board_ns: int
    link_seq: int  # sequence number of the edge on its link; gaps are edges lost in transport


@dataclass(frozen=True)
class SyncSession(LoggedMessage):
    """Written when the sync filter starts (or restarts mid-flight): its configuration."""

    topic: ClassVar[Topic] = Topic.SYNC_SESSION
    schema_name: ClassVar[str] = "sisa.SyncSession"
    t_host_ns: int
    session: int
    board_ns: int
    lfsr_bits: int
    lfsr_taps: list[int]
    lfsr_initial_state: int
    one_of_n: int
    min_spacing_ns: int  # no two forwarded pulses closer than this
    event_input_in_mode1: bool


@dataclass(frozen=True)
class SyncPps(LoggedMessage):
    """Every PPS the SISA saw: its GPS second, the register, and whether it was forwarded."""

    topic: ClassVar[Topic] = Topic.SYNC_PPS
    schema_name: ClassVar[str] = "sisa.SyncPps"
    t_host_ns: int
    session: int
    board_ns: int
    gps_second_ns: int  # from PTT (or ZDA); -1 if the receiver did not say
    mode: int  # 1 or 2
    lfsr_state: int  # register state after stepping on this PPS (-1: rejected as spurious)
    lfsr_bit: int  # output bit; the register steps in both modes (-1: rejected as spurious)
    forwarded: bool


@dataclass(frozen=True)
class SyncForward(LoggedMessage):
    """Every pulse the SISA forwarded to the INS sync input (and the GPS event input)."""

    topic: ClassVar[Topic] = Topic.SYNC_FORWARD
    schema_name: ClassVar[str] = "sisa.SyncForward"
    t_host_ns: int
    session: int
    seq: int  # per session, from 0
    board_ns: int
    mode: int
    source: str  # PPS | PPF
    to_gps_event: bool
    gps_second_ns: int  # mode 1: the GPS second of the forwarded PPS (-1 unknown)
    frame_counter: int  # mode 2: counter of the forwarded frame (-1 unknown)
    frame_counter_source: str  # header | inferred | unknown | n/a


@dataclass(frozen=True)
class SyncCameraPulse(LoggedMessage):
    """Every frame-camera pulse the SISA saw, on its timing board, and whether it went to the
    GPS event input (only when the input was free: docs/sync.md, "Two sensors, one event
    input"). Camera pulses never go to the INS."""

    topic: ClassVar[Topic] = Topic.SYNC_CAMERA
    schema_name: ClassVar[str] = "sisa.SyncCameraPulse"
    t_host_ns: int
    session: int
    seq: int  # per session, from 0
    board_ns: int  # input edge (the forwarded output edge is GATE_DELAY_NS later)
    to_gps_event: bool  # False: the event input was taken by another pulse within its period


@dataclass(frozen=True)
class SyncModeSwitch(LoggedMessage):
    topic: ClassVar[Topic] = Topic.SYNC_MODE
    schema_name: ClassVar[str] = "sisa.SyncModeSwitch"
    t_host_ns: int
    session: int
    board_ns: int
    from_mode: int
    to_mode: int
    reason: str


@dataclass(frozen=True)
class StreamHealth(LoggedMessage):
    """Per-stream counters, written about once a second while recording; also written at once,
    with `event` set, when a device goes away or comes back (its stream is then the source:
    gps, scanner, ins, or pulses for the pulse link that carries pps and ppf). The pulse
    link's decode errors (bytes that were no edge, edges with impossible times) are counted
    in the pps stream's."""

    topic: ClassVar[Topic] = Topic.HEALTH
    schema_name: ClassVar[str] = "sisa.StreamHealth"
    t_host_ns: int
    stream: str
    messages: int
    rate_hz: float  # messages in the last report's window, per second
    expected_hz: float  # what the device sends at its settings (gps: follows the sync mode)
    gaps: int
    checksum_errors: int
    framing_errors: int
    bytes_skipped: int
    drops: int
    deadline_misses: int
    event: str = ""  # "" a periodic report | "link_lost" | "link_restored" | "link_rejected"
    link_lost_ns: int = -1  # host time the device went away (events; reports while it is away)
    link_restored_ns: int = -1  # host time it came back (link_restored events)
    disconnects: int = 0  # times the device went away since the recording started
    reconnects: int = 0  # times it came back
    link_error: str = ""  # why it went (lost) or is not the device (rejected); reopen attempts
    # the checksum and framing errors again, by reason (e.g. "nmea.no_checksum": 3): the
    # decoder's reason names, sorted, and the count of each (a report from before has none)
    refused_reasons: list[str] = dataclasses.field(default_factory=list)
    refused_counts: list[int] = dataclasses.field(default_factory=list)


LOGGED_TYPES: tuple[type[LoggedMessage], ...] = (
    RawBytes, RawCanFrames, GpsFix, GpsTimeTag, InsRecordLog, FrameHeaderLog, PulseEdgeLog,
    SyncSession, SyncPps, SyncForward, SyncModeSwitch, StreamHealth, CameraPhotoLog,
    SyncCameraPulse,
)

_JSON_TYPES: dict[object, dict[str, Any]] = {
    int: {"type": "integer"},
    float: {"type": "number"},  # a non-finite value travels as the string "NaN"/"Infinity"
    str: {"type": "string"},
    bool: {"type": "boolean"},
    bytes: {"type": "string", "contentEncoding": "base64"},
    list[int]: {"type": "array", "items": {"type": "integer"}},
    list[str]: {"type": "array", "items": {"type": "string"}},
}


def json_schema(cls: type[LoggedMessage]) -> dict[str, Any]:
    """JSON Schema of a logged type, generated from its fields (one definition)."""
    hints = get_type_hints(cls)
    props = {f.name: dict(_JSON_TYPES[hints[f.name]])
             for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    return {"title": cls.schema_name, "type": "object", "properties": props,
            "required": list(props)}
