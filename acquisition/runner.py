"""The acquisition: every device stream decoded, the sync filter run, everything recorded.

One `Acquisition` object is fed events in arrival order by a transport layer (in-process for a
virtual-time simulation, threads on ptys/CAN/TCP in real time). It is single-threaded by design:
the sync filter sees one ordered stream of events. Raw bytes are always logged before decoding, so
nothing the devices said is lost even when a decoder rejects it.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import can

from acquisition.camera_photo import PhotoStreamDecoder
from acquisition.clocks import TimingBoard
from acquisition.codec import DecodeStats, ErrorPolicy
from acquisition.ins_can import InsRecord, InsRecordAssembler
from acquisition.nmea import (
    FixQuality,
    Gga,
    Gns,
    NmeaStreamDecoder,
    PashrPtt,
    PashrTtt,
    Rmc,
    Zda,
    gps_ns_from_time_of_week,
    gps_ns_from_utc,
    gps_ns_from_utc_time_of_day,
)
from acquisition.novatel import (
    BestPos,
    ClockStatus,
    MarkTime,
    NmeaNovatelStreamDecoder,
    PositionType,
    SolutionStatus,
    TimeLog,
    time_is_fine,
)
from acquisition.pulses import EDGE_SIZE, EDGE_TIME_LIMIT_NS, Edge, PulseLine
from acquisition.scanner_header import HeaderStreamDecoder
from acquisition.syncfilter import Forward, Log, Mode, SyncFilter, SyncFilterConfig
from acquisition.ubx import NmeaUbxStreamDecoder, TimeBase, TimTm2, TimTp
from recorder.messages import (
    CAN_EXTENDED_FLAG,
    CameraPhotoLog,
    FrameHeaderLog,
    GpsFix,
    GpsTimeTag,
    InsRecordLog,
    LoggedMessage,
    PulseEdgeLog,
    RawBytes,
    RawCanFrames,
    StreamHealth,
    Topic,
)
from sisa.core.timescale import NS_PER_S, NS_PER_WEEK, gps_ns_from_unix_ns

LogSink = Callable[[LoggedMessage, Topic | None], None]
GATE_DELAY_NS = 1_000  # the box's input → output propagation
# an edge this much earlier than the one before it: its source restarted on an earlier timeline
# (edges on one link come in time order; a restart that goes back less holds forwards back
# for less than this)
TIMELINE_RESTART_NS = NS_PER_S
NOON_NS = 12 * 3600 * NS_PER_S  # the instant a date stands for when it comes without a time


@dataclass
class StreamCounters:
    """What the health channel reports for one stream."""

    expected_hz: float
    messages: int = 0
    gaps: int = 0
    drops: int = 0
    deadline_misses: int = 0
    last_t_host_ns: int | None = None
    window_messages: int = 0
    rate_hz: float = 0.0
    stats: DecodeStats = field(default_factory=DecodeStats)

    def seen(self, t_host_ns: int, gap_ns: int) -> None:
        if self.last_t_host_ns is not None and t_host_ns - self.last_t_host_ns > gap_ns:
            self.gaps += 1
        self.last_t_host_ns = t_host_ns
        self.messages += 1
        self.window_messages += 1


# which health streams each device link feeds (the pulse link carries every pulse line); the
# camera's two streams exist only when the configuration has a camera
SOURCE_STREAMS: dict[str, tuple[str, ...]] = {
    "gps": ("gps",), "scanner": ("scanner",), "ins": ("ins",),
    "pulses": ("pps", "ppf", "camera_pulse"), "camera": ("camera",),
}
# the health stream of each input pulse line
LINE_STREAM: dict[PulseLine, str] = {
    PulseLine.PPS: "pps", PulseLine.PPF: "ppf", PulseLine.CAMERA: "camera_pulse"}
# the input line a forwarded pulse came in on
SOURCE_LINE: dict[str, PulseLine] = {
    "PPS": PulseLine.PPS, "PPF": PulseLine.PPF, "CAMERA": PulseLine.CAMERA}
STREAM_SOURCE = {stream: source for source, streams in SOURCE_STREAMS.items()
                 for stream in streams}


@dataclass
class LinkCounters:
    """Disconnects and reconnects of one device link."""

    disconnects: int = 0
    reconnects: int = 0
    lost_t_host_ns: int | None = None  # while the device is away: when it went
    down_ns: int = 0  # total time away (closed outages)
    outages: list[tuple[int, int]] = field(default_factory=list)  # (went, came back), host ns


@dataclass(frozen=True)
class AcquisitionConfig:
    leap_s: int
    sync: SyncFilterConfig
    ins_rate_hz: float
    nmea_rate_hz: float
    line_rate_hz: float
    health_interval_ns: int = NS_PER_S
    edge_deadline_ns: int = 20_000_000  # an edge later than this (beyond the link's best) is a miss
    read_interval_ns: int = 0  # real time: devices read on this clock (LiveSources), 0: at once
    accept_nmea_without_checksum: bool = False  # else such sentences are refused and counted
    gps_ubx: bool = False  # the receiver interleaves UBX frames with its NMEA (u-blox)
    gps_novatel: bool = False  # the receiver sends NovAtel ASCII logs (and maybe NMEA) (OEM7)
    camera_rate_hz: float | None = None  # a frame camera's photos a second at most; None: none
    # where its photo message may arrive after its pulse, ms (for the log's metadata)
    camera_message_window_ms: tuple[float, float] | None = None


def gps_sentences_hz(config: AcquisitionConfig, mode: Mode) -> float:
    """Sentences a second the receiver should send: GGA + RMC per epoch, ZDA and PTT per
    second, and a TTT for every pulse the sync unit sends to its event input, which depends
    on the mode: 1 of n frame pulses in mode 2; in mode 1 the LFSR's one-bits (2^(b-1) of
    every 2^b - 1 seconds), and only if mode-1 pulses go to the receiver at all."""
    sync = config.sync
    if mode is Mode.FRAMES:
        events_hz = config.line_rate_hz / sync.one_of_n
    elif sync.event_input_in_mode1:
        events_hz = 2 ** (sync.lfsr_bits - 1) / (2 ** sync.lfsr_bits - 1)
    else:
        events_hz = 0.0
    if config.gps_novatel:  # BESTPOS per epoch, TIME per second, MARK1TIME per event
        return config.nmea_rate_hz + 1 + events_hz
    return config.nmea_rate_hz * 2 + 2 + events_hz


class Acquisition:
    """Decoders + sync filter + recorder, fed one event at a time."""

    def __init__(self, config: AcquisitionConfig, log: LogSink,
                 send_edge: Callable[[Edge], None], board: TimingBoard | None = None,
                 pulse_stats: DecodeStats | None = None) -> None:
        """`pulse_stats`: the pulse link decoder's counts (bytes that were no edge:
        `LiveSources.pulse_stats`), reported as the pps stream's (the first stream of the
        link); the counts of the link's garbage never reached the health channel before."""
        self.config = config
        self.log = log
        self.send_edge = send_edge
        self.board = board or TimingBoard()
        self.session = 0
        self.filter = SyncFilter(config.sync, session=0, board_ns=self.board.start_count_ns,
                                 t_host_ns=0)  # replaced by the first event's times in _start
        self._started = False
        decoder = (NmeaNovatelStreamDecoder if config.gps_novatel
                   else NmeaUbxStreamDecoder if config.gps_ubx else NmeaStreamDecoder)
        self.gps = decoder(ErrorPolicy.COUNT,
                           accept_missing_checksum=config.accept_nmea_without_checksum)
        self.ins = InsRecordAssembler(ErrorPolicy.COUNT)
        self.headers = HeaderStreamDecoder(ErrorPolicy.COUNT)
        self.photos = PhotoStreamDecoder(ErrorPolicy.COUNT)
        self.streams = {
            "gps": StreamCounters(gps_sentences_hz(config, Mode.PPS)),
            "ins": StreamCounters(config.ins_rate_hz),
            "scanner": StreamCounters(config.line_rate_hz),
            "pps": StreamCounters(1.0),
            "ppf": StreamCounters(config.line_rate_hz),
        }
        if config.camera_rate_hz is not None:
            self.streams["camera"] = StreamCounters(config.camera_rate_hz)
            self.streams["camera_pulse"] = StreamCounters(config.camera_rate_hz)
        if pulse_stats is not None:
            self.streams["pps"].stats = pulse_stats
        self.links = {source: LinkCounters() for source in SOURCE_STREAMS}
        self._utc_date: dt.date | None = None
        self._undated_tags: list[tuple[int, PashrPtt | PashrTtt]] = []
        self._last_fix_gps_ns: int | None = None
        # the GGA's day: the one nearest the receiver's last dated instant (RMC/ZDA) or last fix
        self._dating_gps_ns: int | None = None
        self._gga_seen = False  # GNS fixes are logged only from a receiver that sends no GGA
        self._last_in: dict[PulseLine, tuple[int, int]] = {}  # line → (board_ns, t_edge_ns)
        self._next_health_ns: int | None = None
        self.last_pps_gps_ns: int | None = None
        self.down_until_board_ns: int | None = None
        self._edge_offset_min_ns: int | None = None
        self._first_edge_host_ns: int | None = None
        self._last_edge_board_ns: int | None = None
        self.timeline_restarts = 0  # pulse sources that came back on an earlier timeline
        self._t_host_now_ns = 0
        self._can_batch = _CanBatch()
        self.forwards_sent = 0

    # --- serial ports ----------------------------------------------------------------------

    def on_gps_bytes(self, t_host_ns: int, data: bytes) -> None:
        self._start(t_host_ns)
        self.log(RawBytes(t_host_ns, "gps", data), Topic.GPS_RAW)
        for item in self.gps.feed(data):
            self.streams["gps"].seen(t_host_ns, 3 * NS_PER_S)
            self._on_gps(t_host_ns, item.message)
        self.streams["gps"].stats = self.gps.stats

    def _on_gps(self, t_host_ns: int, msg: object) -> None:
        if isinstance(msg, Rmc | Zda) and msg.utc_date is not None:
            self._utc_date = msg.utc_date
            time_of_day = msg.utc_time_of_day_ns
            self._dating_gps_ns = gps_ns_from_utc(
                msg.utc_date, NOON_NS if time_of_day is None else time_of_day, self.config.leap_s)
            self._flush_undated_tags()
        if isinstance(msg, Gga):
            self._gga_seen = True
        if isinstance(msg, Gga) or (isinstance(msg, Gns) and not self._gga_seen):
            if (self._dating_gps_ns is not None and msg.utc_time_of_day_ns is not None
                    and msg.lat_deg is not None and msg.lon_deg is not None):
                self._log_fix(t_host_ns, msg, msg.utc_time_of_day_ns, self._dating_gps_ns)
        elif isinstance(msg, PashrPtt | PashrTtt):
            if self._utc_date is None and len(self._undated_tags) < MAX_UNDATED_TAGS:
                self._undated_tags.append((t_host_ns, msg))  # its week from the receiver's date
                return
            self._flush_undated_tags()
            self._on_ashtech_tag(t_host_ns, msg)
        elif isinstance(msg, TimTp) and not msg.not_locked:
            # TIM-TP states the next pulse; it comes after the pulse one second before it
            t_gps = msg.pulse_gps_ns - NS_PER_S + (self._leap_ns if msg.time_base_utc else 0)
            self._time_tag(t_host_ns, True, t_gps % NS_PER_WEEK, t_gps)
        elif (isinstance(msg, TimTm2) and msg.new_rising_edge and msg.time_valid
              and msg.time_base in (TimeBase.GNSS, TimeBase.UTC)):
            utc = msg.time_base == TimeBase.UTC
            t_gps = msg.rising_gps_ns + (self._leap_ns if utc else 0)
            self._time_tag(t_host_ns, False, t_gps % NS_PER_WEEK, t_gps)
        elif isinstance(msg, BestPos | TimeLog | MarkTime):
            self._on_novatel(t_host_ns, msg)

    def _on_novatel(self, t_host_ns: int, msg: BestPos | TimeLog | MarkTime) -> None:
        """NovAtel logs: a fix of BESTPOS; a PTT of TIME (logged on the second, the second of
        the PPS just sent); a TTT of MARK1TIME. Times are complete (week and seconds) and in
        GPS time; a time log from a receiver that does not know GPS time finely (its time
        status), or whose clock model is not valid, is not used."""
        if isinstance(msg, BestPos):
            self._log_novatel_fix(t_host_ns, msg)
        elif not time_is_fine(msg.header):
            return
        elif isinstance(msg, TimeLog) and msg.clock_status is ClockStatus.VALID:
            t_gps = msg.pps_gps_ns
            self._time_tag(t_host_ns, True, t_gps % NS_PER_WEEK, t_gps)
        elif isinstance(msg, MarkTime) and msg.status is ClockStatus.VALID \
                and msg.header.name != "MARK2TIME":  # the event input the sync unit drives
            t_gps = msg.gps_ns
            self._time_tag(t_host_ns, False, t_gps % NS_PER_WEEK, t_gps)

    def _log_novatel_fix(self, t_host_ns: int, pos: BestPos) -> None:
        """BESTPOS as a fix: its epoch from the header, height ellipsoidal (MSL height +
        undulation), GGA's quality for its position type (0 unless a solution was computed),
        the satellites used; it states no HDOP."""
        quality = (NOVATEL_QUALITY.get(pos.position_type, FixQuality.INVALID)
                   if pos.solution_status is SolutionStatus.SOL_COMPUTED else FixQuality.INVALID)
        t_gps = pos.header.gps_ns
        self._last_fix_gps_ns = t_gps
        self.log(GpsFix(t_host_ns, t_gps, pos.lat_deg, pos.lon_deg, pos.height_ellipsoidal_m,
                        int(quality), pos.svs_used, float("nan")), None)

    def _flush_undated_tags(self) -> None:
        """The time tags held for the receiver's date, in order (with the host clock's guess of
        the week if the date never came: a receiver without RMC or ZDA sentences)."""
        held, self._undated_tags = self._undated_tags, []
        for t_host_ns, msg in held:
            self._on_ashtech_tag(t_host_ns, msg)

    def _on_ashtech_tag(self, t_host_ns: int, msg: PashrPtt | PashrTtt) -> None:
        """An Ashtech tag states the time of week only: its week is resolved here."""
        t_gps = gps_ns_from_time_of_week(msg.gps_time_of_week_ns, self._gps_estimate(t_host_ns))
        self._time_tag(t_host_ns, isinstance(msg, PashrPtt), msg.gps_time_of_week_ns, t_gps)

    @property
    def _leap_ns(self) -> int:
        return self.config.leap_s * NS_PER_S

    def _time_tag(self, t_host_ns: int, pps: bool, gps_time_of_week_ns: int, t_gps: int) -> None:
        """A receiver's time tag, of its PPS (logged as PTT, and the sync filter told which
        GPS second that PPS was) or of a pulse on its event input (TTT)."""
        self.log(GpsTimeTag(t_host_ns, "PTT" if pps else "TTT", gps_time_of_week_ns, t_gps),
                 None)
        if pps:
            second = (t_gps + NS_PER_S // 2) // NS_PER_S * NS_PER_S
            self.last_pps_gps_ns = second
            self._apply(self.filter.on_gps_time(second, t_host_ns))

    def _log_fix(self, t_host_ns: int, fix: Gga | Gns, utc_time_of_day_ns: int,
                 near_gps_ns: int) -> None:
        """A GGA (or GNS) with time and position: quality 0 if the receiver left it null (GNS
        has none: its best mode indicator stands for it), satellites -1 if null. Its day is the
        one nearest the receiver's last RMC/ZDA or the last fix, whichever came last: a GGA after
        midnight before the next date, and one that comes after the next day's ZDA (a receiver
        whose ZDA runs ahead), both keep their day. (The last date plus a day when the fix fell
        12 h before the last one put the second a day late, and every fix after it.)"""
        t_gps = gps_ns_from_utc_time_of_day(utc_time_of_day_ns, self.config.leap_s, near_gps_ns)
        self._last_fix_gps_ns = self._dating_gps_ns = t_gps
        height = fix.height_ellipsoidal_m
        quality = fix.quality if fix.quality is not None else FixQuality.INVALID
        self.log(GpsFix(t_host_ns, t_gps, fix.lat_deg or 0.0, fix.lon_deg or 0.0,
                        height if height is not None else float("nan"), int(quality),
                        fix.satellites if fix.satellites is not None else -1,
                        fix.hdop if fix.hdop is not None else float("nan")), None)

    def _gps_estimate(self, t_host_ns: int) -> int:
        """Best guess of GPS time now, to pick the GPS week of a time-of-week tag: the last
        fix, else the receiver's date (noon of it), else the host clock. The host clock may be
        weeks off the flight (a replayed or emulated flight, a logger whose clock was never
        set): tags wait for the date rather than take a week from it (the recorder showed
        `week 2447` for its first 2 s of a June flight replayed in November, then 2423)."""
        if self._last_fix_gps_ns is not None:
            return self._last_fix_gps_ns
        if self._utc_date is not None:
            return gps_ns_from_utc(self._utc_date, NOON_NS, self.config.leap_s)
        return gps_ns_from_unix_ns(t_host_ns, self.config.leap_s)

    def on_scanner_bytes(self, t_host_ns: int, data: bytes) -> None:
        self._start(t_host_ns)
        self.log(RawBytes(t_host_ns, "scanner", data), Topic.SCANNER_RAW)
        for item in self.headers.feed(data):
            h = item.message
            self.streams["scanner"].seen(t_host_ns, NS_PER_S)
            self.log(FrameHeaderLog(t_host_ns, h.frame_counter, h.integration_time_us,
                                    int(h.mode), h.segment, h.bands), None)
            self._apply(self.filter.on_header(h, t_host_ns))
        self.streams["scanner"].stats = self.headers.stats

    def on_camera_bytes(self, t_host_ns: int, data: bytes) -> None:
        """The frame camera's port: raw bytes, then every photo message (which photo its
        last pulse was: matched in post-processing, on host time)."""
        self._start(t_host_ns)
        self.log(RawBytes(t_host_ns, "camera", data), Topic.CAMERA_RAW)
        counters = self.streams.get("camera")
        for item in self.photos.feed(data):
            msg = item.message
            if counters is not None:
                counters.seen(t_host_ns, 10 * NS_PER_S)
            self.log(CameraPhotoLog(t_host_ns, msg.photo_number, msg.exposure_time_us), None)
        if counters is not None:
            counters.stats = self.photos.stats

    # --- CAN -------------------------------------------------------------------------------

    def on_can_frame(self, t_host_ns: int, msg: can.Message) -> None:
        self.on_can_frames(t_host_ns, (msg,))

    def on_can_frames(self, t_host_ns: int, frames: Sequence[can.Message]) -> None:
        """The frames one read of the bus returned (one host time): a burst is handled in
        one call, as ~450 frames a second one by one cost more in calls than in decoding."""
        self._start(t_host_ns)
        batch, ins, counters = self._can_batch, self.ins, self.streams["ins"]
        for msg in frames:
            batch.add(t_host_ns, msg)
            if batch.full(t_host_ns):
                self._flush_can()
            item = ins.feed(msg, t_host_ns)
            if item is not None:
                counters.seen(t_host_ns, NS_PER_S // 4)
                self.log(_ins_log(t_host_ns, item.message), None)
        counters.stats = ins.stats
        counters.drops = ins.frames.lost

    def on_can_garbled(self, t_host_ns: int, lines: int, bytes_skipped: int = 0) -> None:
        """Adapter lines that did not parse as CAN frames: framing errors of the INS stream,
        their bytes skipped (6 MB of noise on an SLCAN link showed as 48 bytes before)."""
        self._start(t_host_ns)
        self.ins.stats.framing_errors += lines
        self.ins.stats.bytes_skipped += bytes_skipped
        self.streams["ins"].stats = self.ins.stats

    # --- pulse lines -----------------------------------------------------------------------

    def on_edge(self, t_host_ns: int, edge: Edge) -> None:
        """An input edge (PPS, ppf), acted on at its own timestamp."""
        self._start(t_host_ns)
        if not -EDGE_TIME_LIMIT_NS <= edge.t_ns <= EDGE_TIME_LIMIT_NS:
            self._edge_time_out_of_range()
            return
        board_ns = self.board.counter_ns(edge.t_ns)
        self.log(PulseEdgeLog(t_host_ns, edge.line.name, board_ns, edge.seq), Topic.PULSE_IN)
        last = self._last_edge_board_ns
        went_back = last is not None and board_ns < last - TIMELINE_RESTART_NS
        self._last_edge_board_ns = board_ns
        if went_back:
            self._timeline_restarted(board_ns, t_host_ns)
        self._last_in[edge.line] = (board_ns, edge.t_ns)
        self._check_deadline(t_host_ns, edge)
        if self.down_until_board_ns is not None:
            if board_ns < self.down_until_board_ns:
                return
            self.restart_filter(board_ns, t_host_ns)
        if edge.line is PulseLine.PPS:
            self.streams["pps"].seen(t_host_ns, 2 * NS_PER_S)
            self._apply(self.filter.on_pps(board_ns, t_host_ns))
        elif edge.line is PulseLine.PPF:
            self.streams["ppf"].seen(t_host_ns, NS_PER_S)
            self._apply(self.filter.on_ppf(board_ns, t_host_ns))
        elif edge.line is PulseLine.CAMERA:
            if "camera_pulse" in self.streams:
                self.streams["camera_pulse"].seen(t_host_ns, 10 * NS_PER_S)
            self._apply(self.filter.on_camera(board_ns, t_host_ns))

    def ppf_may_forward(self, ppf_unseen: int, gap_ns: int | None) -> bool:
        """Could handling the next ppf forward a pulse, with `ppf_unseen` ppf before it not
        handled yet, `gap_ns` after the ppf before it (edge time; None: none before)? False
        only when it surely cannot: the live loop then holds it back with the other arrivals
        (acquisition.handover). An idle gap (the scanner off and on again, switching modes) or
        an earlier timeline (a new session) is never held."""
        if not self._started or self.down_until_board_ns is not None or gap_ns is None:
            return True
        if not -TIMELINE_RESTART_NS <= gap_ns <= self.config.sync.idle_after_ns // 2:
            return True
        return self.filter.ppf_may_forward(ppf_unseen)

    def _edge_time_out_of_range(self) -> None:
        """An edge no timing board gives (`EDGE_TIME_LIMIT_NS`): a framing error of the pulse
        link, dropped before the board counts it (its count and a forward's time overflowed the
        log's and the link's 64-bit integers)."""
        stats = self.streams["pps"].stats
        stats.framing_errors += 1
        stats.bytes_skipped += EDGE_SIZE

    def _timeline_restarted(self, board_ns: int, t_host_ns: int) -> None:
        """An edge seconds earlier than the one before it: the pulse source came back on an earlier
        timeline (an emulator restarted from the start of its flight). Every state kept in
        board time (the PPS train, the dead time, the last forward) now lies in the future and
        would hold back every forward until the board caught up with it: a new sync session
        starts from the initial state, and edge lateness is measured afresh."""
        self.timeline_restarts += 1
        self._edge_offset_min_ns = self._first_edge_host_ns = None
        self._last_in.clear()
        if self.down_until_board_ns is None:
            self.restart_filter(board_ns, t_host_ns)

    def _check_deadline(self, t_host_ns: int, edge: Edge) -> None:
        """Edge lateness = arrival delay beyond the smallest delay seen so far on the link (the
        link's own latency); later than the deadline is a miss, counted in the health channel."""
        offset = t_host_ns - edge.t_ns
        if self._edge_offset_min_ns is None or offset < self._edge_offset_min_ns:
            self._edge_offset_min_ns = offset
        if self._first_edge_host_ns is None:
            self._first_edge_host_ns = t_host_ns
        if t_host_ns - self._first_edge_host_ns < NS_PER_S:
            return  # warm-up: edges queued on the link before the reader ran are not misses
        if offset - self._edge_offset_min_ns > self.config.edge_deadline_ns:
            counters = self.streams.get(LINE_STREAM.get(edge.line, "ppf"))
            if counters is not None:
                counters.deadline_misses += 1

    def tick(self, t_host_ns: int, t_edge_clock_ns: int) -> None:
        """Time passes with nothing arriving: scanner-off detection and health reports."""
        if not self._started:
            return
        self._t_host_now_ns = t_host_ns
        if self._can_batch.full(t_host_ns):
            self._flush_can()
        board_ns = self.board.counter_ns(t_edge_clock_ns)
        self._apply(self.filter.tick(board_ns))
        self._health(t_host_ns)

    def _apply(self, actions: list[Forward | Log]) -> None:
        for action in actions:
            if isinstance(action, Log):
                self.log(action.message, None)
            else:
                self._forward(action)

    def _forward(self, fwd: Forward) -> None:
        board_in, t_in = self._last_in[SOURCE_LINE[fwd.source]]
        t_out = t_in + (fwd.board_ns - board_in)
        targets = [PulseLine.INS_SYNC] if fwd.to_ins else []
        if fwd.to_gps_event:
            targets.append(PulseLine.GPS_EVENT)
        self.forwards_sent += 1
        for target in targets:
            self.send_edge(Edge(target, 0, t_out))
            self.log(PulseEdgeLog(self._t_host_now_ns, target.name, fwd.board_ns, 0),
                     Topic.PULSE_OUT)

    # --- device links ----------------------------------------------------------------------

    def on_link_lost(self, t_host_ns: int, source: str, error: str) -> None:
        """A device went away (its reader reopens it): logged at once in the health channel."""
        link = self.links[source]
        link.disconnects += 1
        link.lost_t_host_ns = t_host_ns
        self._link_event(t_host_ns, source, "link_lost", t_host_ns, -1, error)

    def on_link_restored(self, t_host_ns: int, source: str, lost_t_host_ns: int,
                         attempts: int) -> None:
        """The device is back after [lost_t_host_ns, t_host_ns]."""
        link = self.links[source]
        link.reconnects += 1
        link.lost_t_host_ns = None
        link.down_ns += t_host_ns - lost_t_host_ns
        link.outages.append((lost_t_host_ns, t_host_ns))
        self._link_event(t_host_ns, source, "link_restored", lost_t_host_ns, t_host_ns,
                         f"reopened after {attempts} attempt(s)")

    def on_link_rejected(self, t_host_ns: int, source: str, lost_t_host_ns: int,
                         why: str) -> None:
        """The device's port opened again with something else behind it: given up (the
        device is still away), logged at once with why."""
        self._link_event(t_host_ns, source, "link_rejected", lost_t_host_ns, -1, why)

    def _link_event(self, t_host_ns: int, source: str, event: str, lost_ns: int,
                    restored_ns: int, detail: str) -> None:
        counters = [self.streams[name] for name in SOURCE_STREAMS[source] if name in self.streams]
        stats = [c.stats for c in counters]
        link = self.links[source]
        reasons, counts = _refused(stats)
        self.log(StreamHealth(
            t_host_ns, source, sum(c.messages for c in counters),
            sum(c.rate_hz for c in counters), sum(c.expected_hz for c in counters),
            sum(c.gaps for c in counters), sum(s.checksum_errors for s in stats),
            sum(s.framing_errors for s in stats), sum(s.bytes_skipped for s in stats),
            sum(c.drops for c in counters), sum(c.deadline_misses for c in counters),
            event=event, link_lost_ns=lost_ns, link_restored_ns=restored_ns,
            disconnects=link.disconnects, reconnects=link.reconnects, link_error=detail,
            refused_reasons=reasons, refused_counts=counts), None)

    # --- lifecycle -------------------------------------------------------------------------

    def _start(self, t_host_ns: int) -> None:
        self._t_host_now_ns = t_host_ns  # the event being handled: what a forward is logged at
        if not self._started:
            self._started = True
            self._next_health_ns = t_host_ns + self.config.health_interval_ns
            self.filter = SyncFilter(self.config.sync, session=0,
                                     board_ns=self.board.start_count_ns, t_host_ns=t_host_ns)
            self._apply(self.filter.start_actions())
        elif self._next_health_ns is not None and t_host_ns >= self._next_health_ns:
            self._health(t_host_ns)

    def restart_filter(self, board_ns: int, t_host_ns: int) -> None:
        """The sync program came back after a crash: a new session from the initial state."""
        self.down_until_board_ns = None
        self.session += 1
        self.filter = SyncFilter(self.config.sync, session=self.session, board_ns=board_ns,
                                 t_host_ns=t_host_ns)
        self._apply(self.filter.start_actions())

    def crash_filter(self, until_board_ns: int) -> None:
        """The sync program died: nothing is forwarded or logged by it until it restarts."""
        self.down_until_board_ns = until_board_ns

    def _health(self, t_host_ns: int) -> None:
        if self._next_health_ns is None or t_host_ns < self._next_health_ns:
            return
        window_s = self.config.health_interval_ns / NS_PER_S
        self.streams["gps"].expected_hz = gps_sentences_hz(self.config, self.filter.mode)
        for name, c in self.streams.items():
            s = c.stats
            c.rate_hz = c.window_messages / window_s
            link = self.links[STREAM_SOURCE[name]]
            lost = -1 if link.lost_t_host_ns is None else link.lost_t_host_ns
            reasons, counts = _refused([s])
            self.log(StreamHealth(t_host_ns, name, c.messages, c.rate_hz,
                                  c.expected_hz, c.gaps, s.checksum_errors, s.framing_errors,
                                  s.bytes_skipped, c.drops, c.deadline_misses,
                                  link_lost_ns=lost, disconnects=link.disconnects,
                                  reconnects=link.reconnects, refused_reasons=reasons,
                                  refused_counts=counts), None)
            c.window_messages = 0
        self._next_health_ns = t_host_ns + self.config.health_interval_ns

    def _flush_can(self) -> None:
        batch = self._can_batch.take()
        if batch is not None:
            self.log(batch, None)

    def finish(self, t_host_ns: int) -> None:
        self._flush_undated_tags()
        self._flush_can()
        self._apply(self.filter.flush())
        self._next_health_ns = t_host_ns
        self._health(t_host_ns)


# GGA's fix quality for NovAtel's position types (the others: 0)
NOVATEL_QUALITY: dict[PositionType, FixQuality] = {
    PositionType.SINGLE: FixQuality.GPS,
    PositionType.PSRDIFF: FixQuality.DGPS,
    PositionType.WAAS: FixQuality.DGPS,
    PositionType.NARROW_INT: FixQuality.RTK_FIXED,
    PositionType.WIDE_INT: FixQuality.RTK_FIXED,
    PositionType.L1_INT: FixQuality.RTK_FIXED,
    PositionType.NARROW_FLOAT: FixQuality.RTK_FLOAT,
    PositionType.L1_FLOAT: FixQuality.RTK_FLOAT,
    PositionType.PPP: FixQuality.RTK_FLOAT,
    PositionType.PROPAGATED: FixQuality.ESTIMATED,
    PositionType.FIXEDPOS: FixQuality.MANUAL,
}

# Time tags held for the receiver's date (an RMC or ZDA, which follows within the second):
# a receiver that sends no date has its tags' week from the host clock after these
MAX_UNDATED_TAGS = 4


class _CanBatch:
    """Raw CAN frames waiting to be logged together."""

    MAX_FRAMES = 128
    MAX_AGE_NS = 200_000_000  # well inside the 1 s a crash may lose; ~5 batches a second

    def __init__(self) -> None:
        self.times: list[int] = []
        self.ids: list[int] = []
        self.dlcs: list[int] = []
        self.data = bytearray()

    def _clear(self) -> None:
        self.times, self.ids, self.dlcs, self.data = [], [], [], bytearray()

    def add(self, t_host_ns: int, msg: can.Message) -> None:
        self.times.append(t_host_ns)
        self.ids.append(msg.arbitration_id | (CAN_EXTENDED_FLAG if msg.is_extended_id else 0))
        payload = bytes(msg.data)
        self.dlcs.append(len(payload))
        self.data += payload

    def full(self, t_host_ns: int) -> bool:
        return bool(self.times) and (len(self.times) >= self.MAX_FRAMES
                                     or t_host_ns - self.times[0] >= self.MAX_AGE_NS)

    def take(self) -> RawCanFrames | None:
        if not self.times:
            return None
        t0 = self.times[0]
        batch = RawCanFrames(t0, [t - t0 for t in self.times], self.ids, self.dlcs,
                             bytes(self.data))
        self._clear()
        return batch


def _refused(stats: Sequence[DecodeStats]) -> tuple[list[str], list[int]]:
    """The streams' refusals by reason, summed: reasons sorted, and their counts."""
    total: dict[str, int] = {}
    for s in stats:
        for reason, n in s.refused.items():
            total[reason] = total.get(reason, 0) + n
    reasons = sorted(total)
    return reasons, [total[r] for r in reasons]


def _ins_log(t_host_ns: int, rec: InsRecord) -> InsRecordLog:
    rx, ry, rz = rec.body_rate_rps
    vn, ve, vd = rec.vel_ned_mps
    return InsRecordLog(t_host_ns, rec.counter, rec.ins_time_ticks, rec.roll_rad, rec.pitch_rad,
                        rec.heading_rad, rx, ry, rz, vn, ve, vd, int(rec.status), rec.sync_flag,
                        rec.sync_time_ticks)
