"""A flight log's raw channels read again as the live loop read them: the same arrivals, with no
device and no waiting, for measuring the recorder's own work back to back
(`bench/acquisition_headroom.py`) and for checking that the way they are handed over changes
nothing (tests).

Each wire's raw items are cut into the reads a loop reading every `read_interval_ns` made of
them (what the wire brought in one interval) and turned into what `LiveSources` returns for such
a read: serial bytes as they are, SLCAN lines parsed into CAN frames, edge messages decoded.
"""

from __future__ import annotations

from collections.abc import Iterator

from acquisition.live import Arrival, Source
from acquisition.pulses import Edge, EdgeStreamDecoder, PulseLine, encode_edge
from acquisition.slcan_bulk import encode_frame_line, parse_frame_lines
from recorder.framing import Paths
from recorder.replay import BoardModel, CanFrame, RecordedEdge, iter_schedule, survey_log


def raw_reads(paths: Paths, read_interval_ns: int) -> list[tuple[int, Source, bytes]]:
    """(read time, wire, what the wire brought since the read before), in read order."""
    timeline = survey_log(paths).timeline(BoardModel())
    reads: list[tuple[int, Source, bytes]] = []
    pending: dict[Source, bytearray] = {}
    t_read = -1
    for item in iter_schedule(paths):
        t = (item.t_log_ns // read_interval_ns + 1) * read_interval_ns
        if t != t_read:
            reads += [(t_read, source, bytes(data)) for source, data in pending.items()]
            pending, t_read = {}, t
        data = pending.setdefault(Source(str(item.wire)), bytearray())
        p = item.payload
        if isinstance(p, CanFrame):
            data += encode_frame_line(p.arbitration_id, p.is_extended_id, p.data)
        elif isinstance(p, RecordedEdge):
            data += encode_edge(Edge(PulseLine[p.line], p.link_seq,
                                     timeline.t_edge_ns(p.board_ns)))
        else:
            data += p
    reads += [(t_read, source, bytes(data)) for source, data in pending.items()]
    return reads


def arrivals(reads: list[tuple[int, Source, bytes]], edges: EdgeStreamDecoder,
             ) -> Iterator[Arrival]:
    """The reads as `LiveSources.poll` hands them out (edges decoded by `edges`, whose counts
    the acquisition reports)."""
    for t, source, data in reads:
        if source is Source.INS:  # every line a frame, each ending in a terminator
            yield Arrival(t, source, parse_frame_lines(data[:-1])[0])
        elif source is Source.PULSES:
            for decoded in edges.feed(data):
                yield Arrival(t, source, decoded.message)
        else:
            yield Arrival(t, source, data)
