"""Framing of a possibly damaged MCAP file: whole records only, lengths bounded, chunks checked
and inflated within their declared size, the footer and summary found and CRC-checked. The
reader's ground floor (recorder.reader explains why it reads this way)."""


from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import stat
import struct
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Final

import lz4.frame  # type: ignore[import-untyped]  # no stubs; mcap depends on it
import zstandard
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    McapRecord,
    MetadataIndex,
    Schema,
)
from mcap.stream_reader import StreamReader

from recorder.writer import (
    KNOWN_SCHEMA_BYTES,
    METADATA_NAME,
    SCHEMA_ENCODING,
)
from sisa.core.errors import InputError

MCAP_MAGIC: Final = b"\x89MCAP0\r\n"

DEFAULT_RECORD_SIZE_LIMIT: Final = 256 * 2**20  # our chunks are 64 KiB; 256 MiB is corruption


# OverflowError: a length of 2^63 or more inside a chunk, which mcap hands to a read
PARSE_ERRORS: Final = (McapError, ValueError, struct.error, UnicodeDecodeError, KeyError,
                        OverflowError)


RECORD_HEAD: Final = 9  # opcode u8, length u64

_FOOTER_BODY: Final = 20  # summary_start u64, summary_offset_start u64, summary_crc u32

KNOWN_OPCODES: Final = frozenset(int(op) for op in Opcode)

ZEROED_OPCODE: Final = 0x00  # no MCAP record type: what zero-filled storage frames as


# a Chunk's fixed fields: start and end time, uncompressed size u64; CRC u32; compression name
# length u32; records length u64
_CHUNK_FIXED: Final = 40


_COMPRESSIONS: Final = frozenset({b"", b"lz4", b"zstd"})

_CHUNK_PEEK: Final = RECORD_HEAD + _CHUNK_FIXED + 4  # enough of a chunk to judge its framing

SCAN_BLOCK: Final = 2**20

DECLARATION_MAX: Final = 2**16  # the longest Schema or Channel record salvaged from damage

PathArg = Path | str

Paths = PathArg | Sequence[PathArg]


class OverLimitError(ValueError):
    """A length field beyond the record size limit: refused before anything is allocated."""


class WholeRecords:
    """A file source that returns all the bytes asked for or none: a record cut by the end of
    the file then reads as end-of-file, never as a short record. A length field beyond the file
    or the size limit is refused before anything is allocated for it."""

    def __init__(self, fh: BinaryIO, position: int, size: int, limit: int) -> None:
        self._fh = fh
        self.position = position
        self._size = size
        self._limit = limit

    def read(self, n: int) -> bytes:
        if n > self._limit:
            raise OverLimitError(f"a field of {n} bytes exceeds the limit {self._limit}")
        if n > self._size - self.position:
            return b""
        data = self._fh.read(n)
        if len(data) < n:
            return b""
        self.position += n
        return data

    def seek(self, position: int) -> None:
        self._fh.seek(position)
        self.position = position


class _RecordBytes(io.BytesIO):
    """One record's bytes. A field claiming more than the size limit is refused before it is
    allocated; either it or a smaller one that overruns the record only damages the record."""

    def __init__(self, data: bytes, limit: int) -> None:
        super().__init__(data)
        self._limit = limit

    def read(self, n: int | None = -1) -> bytes:
        if n is not None and n > self._limit:
            raise OverLimitError(f"a field of {n} bytes exceeds the limit {self._limit}")
        return super().read(n)


def iter_records(data: bytes, limit: int, *, emit_chunks: bool = False) -> Iterator[McapRecord]:
    """The MCAP records in `data` (no magic), under the reader's size limit."""
    return StreamReader(_RecordBytes(data, limit), skip_magic=True, emit_chunks=emit_chunks,
                        record_size_limit=None).records


def log_paths(path_or_paths: Paths) -> list[Path]:
    """One log file or several (a split recording) as a list."""
    if isinstance(path_or_paths, str | Path):
        return [Path(path_or_paths)]
    return [Path(p) for p in path_or_paths]


def open_log(path: Path) -> BinaryIO:
    """Open an MCAP file for reading past its magic; InputError (one line) if it is not one."""
    try:
        # without blocking: a FIFO would wait for a writer forever (refused just below)
        fh = open(path, "rb", opener=_open_nonblocking)  # noqa: SIM115 - the caller closes it
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    mode = os.fstat(fh.fileno()).st_mode
    if not stat.S_ISREG(mode):  # a log is read by offsets, and its size is its file's
        fh.close()
        raise InputError(f"{path}: not an MCAP file (not a regular file: {_file_kind(mode)})")
    os.set_blocking(fh.fileno(), True)
    magic = fh.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        fh.close()
        what = "empty" if not magic else "no MCAP magic"
        raise InputError(f"{path}: not an MCAP file ({what})")
    return fh


def _open_nonblocking(path: str, flags: int) -> int:
    return os.open(path, flags | os.O_NONBLOCK)


def _file_kind(mode: int) -> str:
    kinds = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((kind for test, kind in kinds if test(mode)), "a special file")


def length_problem(opcode: int, length: int, limit: int, room: int | None = None) -> str:
    what = f"a record (opcode {opcode:#04x}) of {length} bytes"
    if length > limit:
        return f"{what} exceeds limit {limit}"
    return f"{what} runs past the end of the file ({room} bytes from its start)"


@dataclass(frozen=True)
class Summary:
    """The summary section of a complete file, read only when its CRC checks."""

    declarations: list[Schema | Channel]
    chunk_starts: list[int]  # sorted
    resume_points: list[int]  # sorted: chunks, metadata records, the summary, the footer
    metadata_starts: list[int] = field(default_factory=list)  # the sisa.recording records


def _footer(fh: BinaryIO, size: int) -> tuple[int, bytes] | None:
    """(offset, bytes) of the footer record of a file that ends in one and the closing magic."""
    footer_at = size - len(MCAP_MAGIC) - RECORD_HEAD - _FOOTER_BODY
    if footer_at <= len(MCAP_MAGIC):
        return None
    fh.seek(footer_at)
    footer = fh.read(RECORD_HEAD + _FOOTER_BODY + len(MCAP_MAGIC))
    if footer[0] != Opcode.FOOTER or footer[-len(MCAP_MAGIC):] != MCAP_MAGIC or \
            int.from_bytes(footer[1:RECORD_HEAD], "little") != _FOOTER_BODY:
        return None
    return footer_at, footer


def footer_points(fh: BinaryIO, size: int) -> list[int]:
    """Where the summary section (when the footer gives a plausible start) and the footer of a
    file that ends in a footer begin: places to read on at when its summary cannot be used."""
    found = _footer(fh, size)
    if found is None:
        return []
    footer_at, footer = found
    (summary_start,) = struct.unpack_from("<Q", footer, RECORD_HEAD)
    return [summary_start, footer_at] if len(MCAP_MAGIC) < summary_start < footer_at \
        else [footer_at]


def read_summary(fh: BinaryIO, size: int, limit: int) -> Summary | None:
    """The summary section, when the file ends in a footer whose summary CRC checks; None
    otherwise (a file cut short, a damaged summary)."""
    found = _footer(fh, size)
    if found is None:
        return None
    footer_at, footer = found
    summary_start, _, summary_crc = struct.unpack_from("<QQI", footer, RECORD_HEAD)
    if not len(MCAP_MAGIC) < summary_start < footer_at or footer_at - summary_start > limit \
            or summary_crc == 0:
        return None
    fh.seek(summary_start)
    summary = fh.read(footer_at - summary_start)
    checked = footer[:RECORD_HEAD + _FOOTER_BODY - 4]  # the footer up to its CRC field
    if zlib.crc32(checked, zlib.crc32(summary)) != summary_crc:
        return None
    declarations: list[Schema | Channel] = []
    chunks: set[int] = set()
    metadata: set[int] = set()
    points = {summary_start, footer_at}
    in_data = range(len(MCAP_MAGIC), summary_start)
    # it ends in EndOfFile (no footer in these bytes); its CRC has checked what came before
    with contextlib.suppress(*PARSE_ERRORS, OverLimitError):
        for record in iter_records(summary, limit):
            if isinstance(record, Schema | Channel):
                declarations.append(record)
            elif isinstance(record, ChunkIndex) and record.chunk_start_offset in in_data:
                chunks.add(record.chunk_start_offset)
            elif isinstance(record, MetadataIndex) and record.offset in in_data:
                points.add(record.offset)
                if record.name == METADATA_NAME:
                    metadata.add(record.offset)
    return Summary(declarations, sorted(chunks), sorted(points | chunks), sorted(metadata))


def find_chunk(fh: BinaryIO, first: int, last: int, bound: int, limit: int) -> int | None:
    """The offset of the first Chunk record that starts in [first, last), ends by `bound` and
    whose framing is consistent; None if there is none."""
    pos = first
    while pos < last:
        span = min(SCAN_BLOCK, last - pos)
        fh.seek(pos)
        buf = fh.read(span + _CHUNK_PEEK)
        i = buf.find(Opcode.CHUNK.to_bytes(1, "little"), 0, span)
        while i >= 0:
            if _chunk_framing(buf, i, bound - pos - i, limit):
                return pos + i
            i = buf.find(Opcode.CHUNK.to_bytes(1, "little"), i + 1, span)
        pos += span
    return None


def _chunk_framing(buf: bytes, i: int, room: int, limit: int) -> bool:
    """Whether a Chunk record at buf[i] frames consistently: its length fits in `room` and the
    limit, its compression is one MCAP names, and its records length is what is left of it.
    Random bytes, or a message's bytes, pass with odds of about 2^-64."""
    if len(buf) - i < RECORD_HEAD + _CHUNK_FIXED - 8:
        return False
    length, _, _, uncompressed, _, name_len = struct.unpack_from("<QQQQII", buf, i + 1)
    if not _CHUNK_FIXED <= length <= min(limit, room - RECORD_HEAD) or uncompressed > limit \
            or len(buf) - i < RECORD_HEAD + _CHUNK_FIXED + name_len:
        return False
    at = i + RECORD_HEAD + _CHUNK_FIXED - 8
    if buf[at:at + name_len] not in _COMPRESSIONS:
        return False
    (records_len,) = struct.unpack_from("<Q", buf, at + name_len)
    return bool(records_len == length - _CHUNK_FIXED - name_len)


def is_ours(schema: Schema) -> bool:
    """A schema exactly as SISA's recorder writes it."""
    return schema.encoding == SCHEMA_ENCODING and schema.data in KNOWN_SCHEMA_BYTES.get(
        schema.name, frozenset())


def uncompressed_chunk(chunk: Chunk, limit: int) -> Chunk:
    """The chunk with its records uncompressed, never inflated past the size it declares (nor
    the record size limit): a damaged size or a compression bomb must not allocate gigabytes."""
    if chunk.uncompressed_size > limit:
        raise ValueError(f"declares {chunk.uncompressed_size} bytes uncompressed (limit {limit})")
    data = chunk.data
    if chunk.compression:
        data = _inflate(chunk.compression, data, chunk.uncompressed_size + 1)
    if len(data) != chunk.uncompressed_size:
        raise ValueError("size does not match its header")
    return dataclasses.replace(chunk, compression="", data=data)


def _inflate(compression: str, data: bytes, max_bytes: int) -> bytes:
    """At most `max_bytes` of the decompressed data."""
    try:
        if compression == "zstd":
            out = bytearray()
            with zstandard.ZstdDecompressor().stream_reader(data) as reader:
                while len(out) < max_bytes and (piece := reader.read(max_bytes - len(out))):
                    out += piece
            return bytes(out)
        if compression == "lz4":
            inflated: bytes = lz4.frame.LZ4FrameDecompressor().decompress(data,
                                                                          max_length=max_bytes)
            return inflated
    except (zstandard.ZstdError, RuntimeError) as exc:
        raise ValueError(f"{compression}: {exc}") from None
    raise ValueError(f"unknown compression {compression!r}")
