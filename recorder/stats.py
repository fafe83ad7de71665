"""What a read of a flight log found, per topic and per file: counts, span, gaps against each
topic's usual interval and rhythm, messages lost by sequence number, damage (docs/flight-log.md)."""


from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
from mcap.records import Channel, Schema

from recorder.health import HealthTotals
from recorder.messages import Topic
from sisa.core.errors import shown_text

GAP_FACTOR: Final = 2.0

RHYTHM_NS: Final = 2_000_000_000  # a silence a topic keeps at least this often is its rhythm

RHYTHM_BIN_NS: Final = 20_000_000_000  # ... judged over this much log time and its neighbours


# the sync unit's own outputs, silent by design between forwarded pulses (the LFSR's runs of
# zeros, up to 4 s with 4 bits): their silences say nothing about a device, so no gaps
PATTERNED_TOPICS: Final = frozenset({Topic.SYNC_FORWARD.value, Topic.PULSE_OUT.value})


MAX_GAPS_KEPT: Final = 1000

MAX_PROBLEMS_KEPT: Final = 20

SEQUENCE_MOD: Final = 2**32


@dataclass(frozen=True)
class ChannelInfo:
    """A channel as declared in the file, with its schema."""

    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes

    @classmethod
    def declared(cls, channel: Channel, schema: Schema | None) -> ChannelInfo:
        """The channel with its schema, or with none if the schema is not (yet) declared."""
        return cls(channel.id, channel.topic, channel.message_encoding,
                   schema.name if schema else "", schema.encoding if schema else "",
                   schema.data if schema else b"")


@dataclass(frozen=True)
class Gap:
    """A silence on one topic longer than `GAP_FACTOR` times its usual interval around it."""

    topic: str
    start_ns: int  # log time of the last message before the gap
    end_ns: int  # log time of the first message after it
    usual_ns: int = 0  # the topic's usual interval around it (_local_usual_ns)

    @property
    def duration_ns(self) -> int:
        return self.end_ns - self.start_ns


@dataclass
class TopicStats:
    topic: str
    schema_name: str
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    median_interval_ns: int = 0
    usual_interval_ns: int = 0  # see _usual_interval_ns
    gaps: list[Gap] = field(default_factory=list)  # the first MAX_GAPS_KEPT, in time order
    gap_count: int | None = 0  # None: not counted (PATTERNED_TOPICS)
    lost_by_sequence: int = 0  # jumps in the writer's per-topic sequence numbers

    @property
    def span_ns(self) -> int:
        return self.last_ns - self.first_ns

    @property
    def rate_hz(self) -> float:
        return (self.count - 1) * 1e9 / self.span_ns if self.count > 1 and self.span_ns else 0.0


@dataclass
class FileStats:
    path: Path
    size_bytes: int
    library: str = ""
    complete: bool = False  # the footer and the closing magic were read
    has_summary: bool = False
    chunks_read: int = 0
    chunks_skipped: int = 0  # damaged: a bad CRC, or unreadable and skipped over
    bytes_readable: int = 0  # up to the end of the last complete record
    bytes_skipped: int = 0  # in damaged records and unreadable stretches the reader read past
    problems: list[str] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @property
    def truncated(self) -> bool:
        return not self.complete

    @property
    def bytes_unreadable(self) -> int:
        return self.size_bytes - self.bytes_readable


class DamagedLogWarning(UserWarning):
    """A flight log was cut short or had damaged chunks; everything readable around them was
    read, and post-processing goes on with it."""


def damage_notes(fs: FileStats) -> list[str]:
    """What a pass could not read of one file, in words (nothing for a sound file)."""
    notes = []
    if not fs.complete:
        rest = (f", the last {fs.bytes_unreadable} bytes unreadable" if fs.bytes_unreadable
                else "")
        notes.append(f"{fs.path}: cut short (no footer, as after a power cut or a kill): "
                     f"read to its last complete chunk{rest}")
    if fs.chunks_skipped:
        chunks = f"{fs.chunks_skipped} damaged chunk{'s' if fs.chunks_skipped != 1 else ''}"
        notes.append(f"{fs.path}: {chunks} skipped ({fs.bytes_skipped} bytes): the messages in "
                     f"{'it' if fs.chunks_skipped == 1 else 'them'} are missing "
                     f"(`sisa log info {fs.path}` shows the gaps)")
    elif fs.bytes_skipped:  # a stretch inside chunks the summary indexes, no chunk start in it
        notes.append(f"{fs.path}: {fs.bytes_skipped} damaged bytes skipped: the messages in "
                     f"them are missing (`sisa log info {fs.path}` shows the gaps)")
    return notes


MAX_BAD_KEPT: Final = 20  # messages that do not decode, named (all are counted)


@dataclass(frozen=True)
class BadMessage:
    """A message that does not decode (its bytes read whole, CRC and all): what a reader
    skips and counts instead of failing on it."""

    topic: str
    log_time_ns: int
    why: str

    def text(self) -> str:
        return f"{shown_text(self.topic)} at log time {self.log_time_ns}: {self.why}"


@dataclass
class LogStats:
    """What a pass over a log (one file or a split set) found. Complete once the pass ends."""

    files: list[FileStats] = field(default_factory=list)
    topics: dict[str, TopicStats] = field(default_factory=dict)
    undecodable: int = 0  # messages that did not decode, skipped: ...
    bad: list[BadMessage] = field(default_factory=list)  # ... the first MAX_BAD_KEPT of them
    part_notes: list[str] = field(default_factory=list)  # parts of the recording not given
    health: HealthTotals = field(default_factory=HealthTotals)  # filled by `scan_log`

    def note_bad(self, topic: str, log_time_ns: int, why: str) -> None:
        self.undecodable += 1
        if len(self.bad) < MAX_BAD_KEPT:
            self.bad.append(BadMessage(topic, log_time_ns, why))

    def bad_note(self) -> str | None:
        """The messages that did not decode and were skipped, in words (None: there were
        none)."""
        if not self.undecodable:
            return None
        first = self.bad[0]
        more = (f" (the first of them: {first.text()})" if self.undecodable > 1
                else f": {first.text()}")
        return (f"{self.undecodable} message{'s' if self.undecodable != 1 else ''} that do"
                f"{'es' if self.undecodable == 1 else ''} not decode skipped{more}; `sisa log "
                "recover --drop-undecodable` makes a copy without them")

    @property
    def messages(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def start_ns(self) -> int:
        return min((t.first_ns for t in self.topics.values() if t.count), default=0)

    @property
    def end_ns(self) -> int:
        return max((t.last_ns for t in self.topics.values() if t.count), default=0)

    @property
    def truncated(self) -> bool:
        return any(f.truncated for f in self.files)

    @property
    def chunks_read(self) -> int:
        return sum(f.chunks_read for f in self.files)

    @property
    def gaps(self) -> list[Gap]:
        return sorted((g for t in self.topics.values() for g in t.gaps),
                      key=lambda g: g.start_ns)


def _usual_interval_ns(intervals: npt.NDArray[np.uint64], median_ns: int) -> int:
    """The longest silence a topic keeps at least once every RHYTHM_NS on average: its median
    interval for a steady stream, the time between bursts for one that talks in bursts (a GPS
    receiver's sentences, once a second), which the median would call a gap every time."""
    recurrences = int(intervals.sum() // RHYTHM_NS)
    if not 1 <= recurrences < len(intervals):
        return median_ns
    return max(median_ns, int(np.partition(intervals, -recurrences)[-recurrences]))


def _local_usual_ns(starts_ns: npt.NDArray[np.uint64], intervals: npt.NDArray[np.uint64],
                    overall_ns: int) -> npt.NDArray[np.int64]:
    """The usual interval around each interval: as _usual_interval_ns, over the RHYTHM_BIN_NS
    of log time it starts in and the bins either side (the longest silence kept at least every
    RHYTHM_NS there), so a topic whose rhythm changes in flight (frame pulses while the scanner
    records, the PPS alone between strips) is judged by the rhythm it had at the time. Where
    those bins are too short (under two RHYTHM_NS: the log's last seconds, a short log) or hold
    too few intervals to tell, the topic's overall usual interval."""
    bins = ((starts_ns - starts_ns[0]) // RHYTHM_BIN_NS).astype(np.int64)
    n_bins = int(bins[-1]) + 1
    span_ns = int(starts_ns[-1] - starts_ns[0] + intervals[-1])
    extent_ns = np.minimum(RHYTHM_BIN_NS, span_ns - np.arange(n_bins) * RHYTHM_BIN_NS)
    k = extent_ns // RHYTHM_NS  # the silences a bin's rhythm keeps: its k-th longest
    order = np.lexsort((-intervals.astype(np.int64), bins))  # by bin, longest first
    first = np.searchsorted(bins[order], np.arange(n_bins))
    count = np.bincount(bins, minlength=n_bins)
    per_bin = np.full(n_bins + 2, -1, dtype=np.int64)  # -1: cannot tell; padded both sides
    enough = (k >= 2) & (count >= k)
    per_bin[1:-1][enough] = intervals[order[first[enough] + k[enough] - 1]].astype(np.int64)
    around = np.maximum(np.maximum(per_bin[:-2], per_bin[1:-1]), per_bin[2:])
    usual = around[bins]
    return np.where(usual >= 0, usual, overall_ns)


def fill_timing(ts: TopicStats, times: npt.NDArray[np.uint64]) -> None:
    """Count, span, median and usual interval; the gaps: intervals longer than GAP_FACTOR x
    the usual interval around them."""
    ts.count = len(times)
    if not ts.count:
        return
    ts.first_ns, ts.last_ns = int(times[0]), int(times[-1])
    if ts.count < 3:
        return
    intervals = np.diff(times)
    ts.median_interval_ns = int(np.median(intervals))
    ts.usual_interval_ns = _usual_interval_ns(intervals, ts.median_interval_ns)
    if ts.topic in PATTERNED_TOPICS:
        ts.gap_count = None
        return
    usual = _local_usual_ns(times[:-1], intervals, ts.usual_interval_ns)
    (idx,) = np.nonzero((usual > 0) & (intervals > GAP_FACTOR * usual))
    ts.gap_count = len(idx)
    ts.gaps = [Gap(ts.topic, int(times[i]), int(times[i + 1]), int(usual[i]))
               for i in idx[:MAX_GAPS_KEPT]]
