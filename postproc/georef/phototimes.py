"""The photo times table: each photo's number and mid-exposure GPS time, what `photo_eo` takes.

    times = read_photo_times(Path("photo_times.csv"))
    eo = photo_eo(traj, times.labels, times.t_mid_gps_ns, camera.mounting)

A CSV (lines starting with `#` are comments) with at least the columns `photo_number`
(a whole number ≥ 0) and `t_mid_gps_ns` (int64 GPS nanoseconds; −1 or any negative value: the
photo was not timed); other columns are ignored. The simulation's `truth/photos.csv` has this
form, and so has the sync's `photo_times.csv` (issue 37, part 3a), which `sisa process` uses
(a run's truth only for a log without the camera's records, said in its output). Photo k is labelled
`photo_{k:06d}`, the name of its image file (`photo_000017.bil`).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from sisa.core.errors import InputError, shown_value

I64 = npt.NDArray[np.int64]

COLUMNS: Final = ("photo_number", "t_mid_gps_ns")
MAX_ROWS: Final = 10_000_000
MAX_BYTES: Final = 2_000_000_000


def photo_label(number: int) -> str:
    """The label (and image file stem) of photo `number`."""
    return f"photo_{number:06d}"


@dataclass(frozen=True)
class PhotoTimes:
    """Photo numbers and mid-exposure GPS times (int64 ns; negative: not timed)."""

    photo_number: I64
    t_mid_gps_ns: I64

    @property
    def labels(self) -> list[str]:
        return [photo_label(int(k)) for k in self.photo_number.tolist()]

    def timed(self) -> PhotoTimes:
        keep = self.t_mid_gps_ns >= 0
        return PhotoTimes(self.photo_number[keep], self.t_mid_gps_ns[keep])

    def time_of(self, numbers: I64) -> I64:
        """Time of each photo number (−1 for a number the table lacks)."""
        lookup = dict(zip(self.photo_number.tolist(), self.t_mid_gps_ns.tolist(), strict=True))
        return np.array([lookup.get(int(k), -1) for k in numbers.tolist()], np.int64)


def read_photo_times(path: Path) -> PhotoTimes:
    """The table, or InputError naming the file and the first bad row (nothing guessed: a
    time that is not a whole number, a repeated photo number, a missing column)."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_BYTES:
            raise InputError(f"{path}: larger than {MAX_BYTES} bytes: not a photo times table")
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot read the photo times: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (photo times)") from None
    body = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if not body:
        raise InputError(f"{path}: no photo times (no header line)")
    if len(body) > MAX_ROWS + 1:
        raise InputError(f"{path}: more than {MAX_ROWS} photos")
    try:
        rows = list(csv.reader(io.StringIO("\n".join(body))))
    except csv.Error as exc:
        raise InputError(f"{path}: unreadable CSV: {exc}") from None
    header = [h.strip() for h in rows[0]]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: no column {missing[0]} (a photo times table has "
                         f"{', '.join(COLUMNS)})")
    cols = [header.index(c) for c in COLUMNS]
    out = np.empty((len(rows) - 1, 2), np.int64)
    for k, r in enumerate(rows[1:], start=1):
        if len(r) != len(header):
            raise InputError(f"{path}: data row {k} has {len(r)} values for {len(header)} "
                             "columns")
        for c, (col, name) in enumerate(zip(cols, COLUMNS, strict=True)):
            try:
                out[k - 1, c] = int(r[col].strip())
            except (ValueError, OverflowError):
                raise InputError(f"{path}: data row {k}, {name}: {shown_value(r[col])} is not "
                                 "a whole number") from None
    numbers, times = out[:, 0], out[:, 1]
    if (numbers < 0).any():
        raise InputError(f"{path}: data row {int(np.argmax(numbers < 0)) + 1}: a negative "
                         "photo number")
    uniq, counts = np.unique(numbers, return_counts=True)
    if (counts > 1).any():
        raise InputError(f"{path}: photo number {int(uniq[np.argmax(counts > 1)])} is given "
                         "twice")
    return PhotoTimes(numbers, times)
