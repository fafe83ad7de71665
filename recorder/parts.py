"""The parts of a flight log: a recording split by `sisa record --split-*` is one flight in
several files, and every reader of a flight takes all of them, in order, or refuses."""


from __future__ import annotations

import contextlib
import io
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Final

from mcap.opcode import Opcode
from mcap.records import (
    Metadata,
)

from recorder.framing import (
    DEFAULT_RECORD_SIZE_LIMIT,
    MCAP_MAGIC,
    PARSE_ERRORS,
    RECORD_HEAD,
    OverLimitError,
    iter_records,
    open_log,
    read_summary,
)
from recorder.writer import (
    METADATA_NAME,
    part_path,
    split_parts,
)
from sisa.core.errors import InputError, shown_text

_METADATA_MAX: Final = 2**20  # the longest metadata record read to place a part in its recording

_HEAD_RECORDS: Final = 64  # records looked at before the first chunk for the part's metadata


# how far a part recorded without a recording id may reach back before the previous part's last
# message: threads stamp their messages before they take the recorder's lock, so the first
# messages of a part can be older than the last of the one before by that wait (a slow disk)
PART_OVERLAP_TOLERANCE_NS: Final = 2_000_000_000


_NAMES_SHOWN: Final = 4  # missing parts named in a note; more are elided


class MissingPartWarning(UserWarning):
    """A split recording is read without some of its parts (one not given, or deleted): what
    they held is missing, and post-processing goes on with the rest."""


FIRST_DATA_KEY_BYTES: Final = 32  # a chunk's start and end times, size and CRC


def first_data_key(path: Path) -> bytes | None:
    """The first bytes of a log's first chunk (or unchunked message): its start and end
    times, size and CRC. Two parts of one recording differ there; a file and a copy of it,
    even one cut short, do not. None where there is no such record (or no MCAP)."""
    try:
        fh = open_log(path)
    except InputError:  # the reader says what is wrong with it
        return None
    with fh:
        while len(head := fh.read(RECORD_HEAD)) == RECORD_HEAD:
            length = int.from_bytes(head[1:], "little")
            if head[0] in (Opcode.CHUNK, Opcode.MESSAGE):
                want = min(length, FIRST_DATA_KEY_BYTES)
                key = fh.read(want)
                return key if want and len(key) == want else None
            fh.seek(length, io.SEEK_CUR)
    return None


def recording_metadata(path: Path) -> dict[str, str]:
    """A log's `sisa.recording` metadata ({} if it has none, or is no MCAP): from the records
    before its first chunk, where the recorder writes it (so a part cut short has it too), else
    through the summary's metadata index (a recovered copy has it at its end). A damaged length
    ends the look: the reader says what is wrong with the file."""
    try:
        fh = open_log(path)
    except InputError:  # the reader says what is wrong with it
        return {}
    with fh:
        size = fh.seek(0, io.SEEK_END)
        fh.seek(len(MCAP_MAGIC))
        for _ in range(_HEAD_RECORDS):
            head = fh.read(RECORD_HEAD)
            length = int.from_bytes(head[1:], "little")
            if len(head) < RECORD_HEAD or length > size - fh.tell() or head[0] in (
                    Opcode.CHUNK, Opcode.MESSAGE, Opcode.DATA_END, Opcode.FOOTER):
                break
            if head[0] == Opcode.METADATA and length <= _METADATA_MAX:
                found = _recording_record(head + fh.read(length))
                if found is not None:
                    return found
            else:
                fh.seek(length, io.SEEK_CUR)
        summary = read_summary(fh, size, DEFAULT_RECORD_SIZE_LIMIT)
        for offset in summary.metadata_starts if summary is not None else ():
            fh.seek(offset)
            head = fh.read(RECORD_HEAD)
            length = int.from_bytes(head[1:], "little")
            if len(head) == RECORD_HEAD and length <= _METADATA_MAX:
                found = _recording_record(head + fh.read(length))
                if found is not None:
                    return found
    return {}


def _recording_record(data: bytes) -> dict[str, str] | None:
    """The `sisa.recording` metadata if the record in `data` is it (None for any other record,
    or one that does not parse)."""
    with contextlib.suppress(*PARSE_ERRORS, OverLimitError, StopIteration):
        record = next(iter_records(data, _METADATA_MAX))
        if isinstance(record, Metadata) and record.name == METADATA_NAME:
            return {str(k): str(v) for k, v in record.metadata.items()}
    return None


@dataclass(frozen=True)
class PartLabel:
    """Where a file's `sisa.recording` metadata places it: which part of which recording."""

    path: Path
    index: int  # its `part`: 0, 1, ...
    first_part: str  # the file name of part 0
    recording_id: str  # "" in a log recorded before parts carried one

    def same_recording(self, other: PartLabel) -> bool:
        """By the recording id; without one (an older log), by the first part's name only."""
        return (self.recording_id, self.first_part) == (other.recording_id, other.first_part)


def part_label(path: Path) -> PartLabel | None:
    """Where `path` sits in its recording; None for a file without SISA's part metadata (not
    written by SISA's recorder, or damaged there)."""
    meta = recording_metadata(path)
    try:
        index = int(meta["part"])
    except (KeyError, ValueError):
        return None
    if index < 0 or "first_part" not in meta:
        return None
    return PartLabel(Path(path), index, meta["first_part"], meta.get("recording_id", ""))


@dataclass(frozen=True)
class SplitSet:
    """The files of a log as they are to be read, and what is missing of the recording."""

    paths: list[Path]  # in part order when every file says its part, else as given
    notes: list[str]  # the parts of the recording that are not given, in words
    check_times: bool  # parts without a recording id: their log times must follow each other


def split_set(paths: Sequence[Path]) -> SplitSet:
    """Check that the files are parts of ONE recording and put them in part order (the order
    they are given in carries no meaning). InputError names a part of another recording (told
    by the recording id; in a log recorded before parts carried one, by the first part's name,
    and while it is read by its log times: `LogReader`) or a part given twice over (a part and
    its recovered copy). Files without SISA's part metadata are read as given, unchecked."""
    paths = [Path(p) for p in paths]
    labels = [part_label(p) for p in paths]
    known = [label for label in labels if label is not None]
    _refuse_mixed(known)
    if len(known) < len(labels):
        return SplitSet(paths, [], False)
    known.sort(key=lambda label: label.index)
    return SplitSet([label.path for label in known], _missing_notes(known),
                    len(known) > 1 and not known[0].recording_id)


def _refuse_mixed(labels: list[PartLabel]) -> None:
    """InputError for a part of another recording than most of `labels`, or a part twice."""
    if len(labels) < 2:
        return
    in_order = sorted(labels, key=lambda label: label.index)
    # the recording most parts are of (on a tie, the one with the lowest part), by its first
    counts = Counter((label.recording_id, label.first_part) for label in in_order)
    ref = next(label for label in in_order
               if (label.recording_id, label.first_part) == counts.most_common(1)[0][0])
    for label in in_order:
        if not label.same_recording(ref):
            raise InputError(f"{label.path} is part {label.index} of another recording "
                             f"({_which(label)}) than {ref.path} ({_which(ref)}): each "
                             "flight's parts are read together, not mixed")
    seen: dict[int, PartLabel] = {}
    for label in labels:
        other = seen.setdefault(label.index, label)
        if other is not label:
            raise InputError(f"{label.path} is part {label.index} of the recording, as is "
                             f"{other.path} (a copy, or a recovered copy of it?): each part of "
                             "a flight is read once")


def _which(label: PartLabel) -> str:
    """The recording a part says it is of, in words (its metadata shown safely: damage can
    leave anything there)."""
    if label.recording_id:
        return f"id {shown_text(label.recording_id)}"
    return f"no recording id, first part {shown_text(label.first_part)}"


def _missing_notes(labels: list[PartLabel]) -> list[str]:
    """Words for the parts missing before and between `labels` (in part order); parts after
    the last cannot be told from the end of the flight."""
    notes = []
    first = labels[0]
    if first.index > 0:
        what, verb = _parts_phrase(first, 0, first.index)
        notes.append(f"{first.path} is part {first.index} of a split recording whose {what} "
                     f"{verb} not given: the log is read from part {first.index} on")
    for before, after in pairwise(labels):
        if after.index > before.index + 1:
            what, verb = _parts_phrase(first, before.index + 1, after.index)
            notes.append(f"{what} of the split recording {shown_text(first.first_part)} {verb} "
                         f"not given (between {before.path} and {after.path}): the log is read "
                         f"without {'it' if verb == 'is' else 'them'}, a hole in the flight")
    return notes


def _parts_phrase(label: PartLabel, start: int, stop: int) -> tuple[str, str]:
    """('part 2 (flight_002.mcap)', 'is') or ('parts 0-1 (flight.mcap, flight_001.mcap)',
    'are'): parts start..stop-1 of label's recording, with their file names."""
    names = [shown_text(part_path(Path(label.first_part), i).name) for i in range(start, stop)]
    if len(names) > _NAMES_SHOWN:
        names = [*names[:_NAMES_SHOWN - 1], "...", names[-1]]
    if stop - start == 1:
        return f"part {start} ({names[0]})", "is"
    return f"parts {start}-{stop - 1} ({', '.join(names)})", "are"


def flight_parts(files: Sequence[Path]) -> list[Path]:
    """The files of a flight log: as given when several; when one, it and the numbered parts of
    a split recording beside it (flight.mcap, flight_001.mcap, ...: `sisa record --split-*`),
    so that naming the first part never reads a flight only in part. The parts are put in
    part order, and a part of another recording is refused here, before any work starts
    (`recorder.reader.split_set`; the readers check again). A missing file is left for the
    reader to report."""
    if len(files) != 1:
        seen: set[Path] = set()
        for path in files:
            if path.resolve() in seen:
                raise InputError(f"{path} is given twice: each part of a flight is read once")
            seen.add(path.resolve())
    parts = list(files) if len(files) != 1 else split_parts(files[0]) or list(files)
    first: dict[bytes, Path] = {}
    for path in parts if len(parts) > 1 else []:  # one file cannot repeat itself
        key = first_data_key(path)
        if key in first:
            raise InputError(f"{path} starts with the same data as {first[key]} (a copy of "
                             "it?): each part of a flight is read once")
        if key is not None:
            first[key] = path
    return split_set(parts).paths

