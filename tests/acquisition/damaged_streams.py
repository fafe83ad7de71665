"""A GPS port's stream of NMEA sentences mixed with a receiver's own messages (UBX frames,
NovAtel logs), some damaged, and the check every such decoder must pass: no good message lost,
every bad stretch counted, every byte accounted for."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from hypothesis import strategies as st


@dataclass(frozen=True)
class MessageKind:
    """One kind of message on the port: how to draw one, the first and last index a damage may
    hit (the body its checksum covers), and the bytes a changed one may take."""

    draw: st.SearchStrategy[bytes]
    body: Callable[[bytes], tuple[int, int]]
    changed_byte: st.SearchStrategy[int]


def nmea_kind(sentences: Sequence[bytes], special: bytes = b"$*") -> MessageKind:
    """NMEA sentences; a changed byte is printable and not one of `special` (the bytes that
    start or end a message on this port)."""
    return MessageKind(st.sampled_from(sentences), lambda raw: (1, raw.index(b"*") - 1),
                       st.integers(0x20, 0x7E).filter(lambda b: b not in special))


@st.composite
def damaged_streams(draw: st.DrawFn, kinds: Sequence[MessageKind], tail: bytes
                    ) -> tuple[bytes, list[bytes], int]:
    """Messages of `kinds`, some damaged (a byte of the body changed, or cut short), then `tail`
    (a good message, so that one damaged at the end is ended); returns (stream, the good raws
    in order, the damaged count)."""
    pieces, good, damaged = [], [], 0
    for _ in range(draw(st.integers(1, 25))):
        kind = draw(st.sampled_from(kinds))
        raw = draw(kind.draw)
        damage = draw(st.sampled_from(["none", "none", "none", "flip", "cut"]))
        if damage == "none":
            pieces.append(raw)
            good.append(raw)
            continue
        index = draw(st.integers(*kind.body(raw)))
        if damage == "flip":  # a byte of the body changed: the checksum no longer matches
            old = raw[index]
            new = draw(kind.changed_byte.filter(lambda b, old=old: b != old))
            pieces.append(raw[:index] + bytes([new]) + raw[index + 1:])
        else:  # cut short: the rest never sent
            pieces.append(raw[:index])
        damaged += 1
    return b"".join([*pieces, tail]), [*good, tail], damaged


class _Stats(Protocol):
    errors: int
    bytes_skipped: int


class _Decoder(Protocol):
    stats: Any

    def feed(self, data: bytes) -> list[Any]: ...

    def finish(self) -> list[Any]: ...


def check_decoding(decoder: _Decoder, case: tuple[bytes, list[bytes], int], chunk: int) -> None:
    """`decoder` fed the stream in pieces of `chunk` bytes gives every good message in order,
    one error at least per bad stretch and never more than the damaged messages (two damaged
    ones count once when one lies inside the length a damaged frame claimed), and accounts for
    every byte."""
    stream, good, damaged = case
    out = [d for i in range(0, len(stream), chunk) for d in decoder.feed(stream[i:i + chunk])]
    out += decoder.finish()
    assert [d.raw for d in out] == good
    stats: _Stats = decoder.stats
    assert (damaged > 0) <= stats.errors <= damaged
    assert sum(len(d.raw) for d in out) + stats.bytes_skipped == len(stream)
