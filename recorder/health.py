"""What a recording's health reports add up to: per stream, the recorder's own counts of decode
errors, drops, late edges and outages over the whole flight (`sisa log info`).

Each periodic `sisa.StreamHealth` carries its stream's counters since its recorder started, so
the last report of a run holds the run's totals. A recorder started again (a new process, its
counters from zero) shows as counters going down; the runs are added up. Reports with `event`
set (a device lost or restored) sum a device's streams and are not counted again. A counter
the schema gained later is 0 in a log from before it; a report that does not hold the fields as
the schema declares them (a damaged or foreign log) is skipped and counted.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy.typing as npt

from recorder.messages import StreamHealth, Topic

# the counters a report carries, in the order `sisa log info` shows them
COUNTERS: Final = ("checksum_errors", "framing_errors", "bytes_skipped", "drops",
                   "deadline_misses", "disconnects", "reconnects")
# their headings in `sisa log info` (checksum_errors, framing_errors, deadline_misses shortened)
HEADINGS: Final = ("checksum", "framing", "bytes_skipped", "drops", "late", "disconnects",
                   "reconnects")
STREAM_ORDER: Final = ("gps", "scanner", "ins", "pps", "ppf")
# for read_topics: every field of the log's own schema (older ones lack the later counters)
HEALTH_WANTED: Final[dict[str, None]] = {Topic.HEALTH.value: None}
# counters added to the schema later (a default in the dataclass): a log from before has none
_LATER: Final = {f.name: f.default for f in dataclasses.fields(StreamHealth)
                 if f.default is not dataclasses.MISSING}


@dataclass
class StreamTotals:
    stream: str
    reports: int = 0
    _done_messages: int = 0  # the finished runs' totals
    _done: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COUNTERS, 0))
    _last: dict[str, int] = field(default_factory=dict)  # the current run's last report
    _done_refused: dict[str, int] = field(default_factory=dict)
    _last_refused: dict[str, int] = field(default_factory=dict)

    def add(self, values: dict[str, int], refused: dict[str, int] | None = None) -> None:
        if self._last and values["messages"] < self._last["messages"]:  # a new run
            self._done_messages += self._last["messages"]
            for name in COUNTERS:
                self._done[name] += self._last[name]
            self._done_refused = _summed(self._done_refused, self._last_refused)
        self._last = values
        self._last_refused = refused or {}
        self.reports += 1

    @property
    def refused(self) -> dict[str, int]:
        """The decode errors by reason (a log from before reasons were reported has none)."""
        return _summed(self._done_refused, self._last_refused)

    @property
    def messages(self) -> int:
        return self._done_messages + self._last.get("messages", 0)

    @property
    def counts(self) -> dict[str, int]:
        return {name: self._done[name] + self._last.get(name, 0) for name in COUNTERS}

    @property
    def decode_errors(self) -> int:
        return self.counts["checksum_errors"] + self.counts["framing_errors"]


@dataclass
class HealthTotals:
    streams: dict[str, StreamTotals] = field(default_factory=dict)
    unreadable: int = 0  # reports without the schema's fields

    def add(self, report: dict[str, Any]) -> None:
        """One decoded `sisa.StreamHealth`."""
        stream = report.get("stream")
        values = {name: report.get(name, _LATER.get(name)) for name in ("messages", *COUNTERS)}
        if not isinstance(stream, str) or not all(
                type(v) is int and v >= 0 for v in values.values()):
            self.unreadable += 1
            return
        refused = _refusals(report)
        if refused is None:
            self.unreadable += 1
            return
        if report.get("event"):
            return
        self.streams.setdefault(stream, StreamTotals(stream)).add(
            {k: v for k, v in values.items() if isinstance(v, int)}, refused)

    @classmethod
    def from_columns(cls, columns: dict[str, npt.NDArray[Any]]) -> HealthTotals:
        """The totals of the reports as read_topics gives them (HEALTH_WANTED)."""
        totals = cls()
        names = [name for name in columns if name != "log_time_ns"]
        for row in zip(*(columns[name].tolist() for name in names), strict=True):
            totals.add(dict(zip(names, row, strict=True)))
        return totals

    def verdict(self) -> str:
        """The problems in one phrase, or that there were none."""
        return ", ".join(self.problems()) or "no decode error, drop, late edge or disconnect"

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON: the problems' phrases ([] when clean) and each stream's totals."""
        return {"problems": self.problems(), "unreadable_reports": self.unreadable,
                "streams": {t.stream: {"reports": t.reports, "messages": t.messages, **t.counts,
                                       "refused_by_reason": t.refused}
                            for t in self.ordered()}}

    def ordered(self) -> list[StreamTotals]:
        known = [self.streams[s] for s in STREAM_ORDER if s in self.streams]
        return known + [t for s, t in sorted(self.streams.items()) if s not in STREAM_ORDER]

    def problems(self) -> list[str]:
        """What went wrong, summed over the streams, as phrases ([] for a clean recording)."""
        streams = self.streams.values()
        sums = [(sum(t.decode_errors for t in streams), "decode error"),
                (sum(t.counts["drops"] for t in streams), "drop"),
                (sum(t.counts["deadline_misses"] for t in streams), "late edge"),
                (sum(t.counts["disconnects"] for t in streams if t.stream != "ppf"),
                 "disconnect")]  # pps and ppf share the pulse link: counted once, as pps
        return [f"{n} {what}{'s' if n != 1 else ''}" for n, what in sums if n]


def _summed(a: dict[str, int], b: dict[str, int]) -> dict[str, int]:
    return {k: a.get(k, 0) + b.get(k, 0) for k in sorted(a.keys() | b.keys())}


def _refusals(report: dict[str, Any]) -> dict[str, int] | None:
    """A report's refusals by reason; {} from a log from before them; None if damaged."""
    reasons, counts = report.get("refused_reasons", []), report.get("refused_counts", [])
    if (not isinstance(reasons, list) or not isinstance(counts, list)
            or len(reasons) != len(counts)
            or not all(isinstance(r, str) for r in reasons)
            or not all(type(n) is int and n >= 0 for n in counts)):
        return None
    return dict(zip(reasons, counts, strict=True))


def recording_note(health: HealthTotals, flight: Path) -> str | None:
    """The warning of a post-processing command whose log's recorder counted problems (what
    the log holds may be short of what the devices sent): None for a clean recording."""
    problems = health.problems()
    if not problems:
        return None
    return (f"the recorder counted {', '.join(problems)} while recording {flight.name}: records "
            f"or lines may be missing for it (per stream: sisa log info {flight})")
