"""The parts of a flight log: a recording split by `sisa record --split-*` is one flight in
several files, and every reader of a flight takes all of them, in order, or refuses."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from recorder.reader import first_data_key, split_set
from recorder.writer import split_parts
from sisa.core.errors import InputError


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

