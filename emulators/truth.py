"""Simulation truth, kept beside a run and never in the flight log.

Each table is columnar (one Python list per column while running, spilled to a temporary file in
blocks, written once as CSV with a commented header that names every column and unit).
Post-processing never reads these files; tests, benchmarks and the accuracy report of a simulated
run do.
"""

from __future__ import annotations

import contextlib
import csv
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any, Final

import numpy as np

from sisa.core.errors import InputError
from sisa.core.outdir import create_partial

SPILL_ROWS: Final = 100_000  # rows held in memory per table before they go to a temporary file
ROWS_MARK: Final = "# rows: "  # in the commented header: a table cut short is told by its count


class TruthTable:
    """Rows of one truth table, appended while the emulation runs.

    Rows are held as columns in memory up to `spill_rows`, then written as CSV rows to a
    temporary file, so an emulation of hours (millions of INS records at 10x rates) keeps its
    memory flat; `write_csv` joins the spilled rows and the held ones."""

    def __init__(self, name: str, columns: dict[str, str], description: str,
                 spill_rows: int = SPILL_ROWS) -> None:
        self.name = name
        self.columns = columns  # column name → unit/meaning
        self.description = description
        self.spill_rows = spill_rows
        self._data: dict[str, list[Any]] = {c: [] for c in columns}
        self._spill: IO[str] | None = None
        self._spilled = 0

    def append(self, **row: Any) -> None:
        for col, values in self._data.items():
            values.append(row[col])
        self._maybe_spill()

    def extend(self, **cols: Iterable[Any]) -> None:
        for col, values in self._data.items():
            values.extend(cols[col])
        self._maybe_spill()

    def __len__(self) -> int:
        return self._spilled + self._held()

    def _held(self) -> int:
        return len(next(iter(self._data.values()))) if self._data else 0

    def _maybe_spill(self) -> None:
        held = self._held()
        if held < self.spill_rows:
            return
        if self._spill is None:
            # lives as long as the table (deleted when closed or collected)
            self._spill = tempfile.TemporaryFile("w+", newline="", encoding="utf-8")  # noqa: SIM115
        csv.writer(self._spill).writerows(zip(*self._data.values(), strict=True))
        self._spilled += held
        for values in self._data.values():
            values.clear()

    def column(self, name: str) -> np.ndarray[Any, Any]:
        if self._spill is None:
            return np.asarray(self._data[name])
        return self._read_back()[name]

    def _read_back(self) -> dict[str, np.ndarray[Any, Any]]:
        """Every row, spilled ones included, as typed columns (as `read_truth_csv` gives)."""
        with tempfile.TemporaryDirectory() as tmp:
            return read_truth_csv(self.write_csv(Path(tmp)))

    def write_csv(self, folder: Path) -> Path:
        """`folder/NAME.csv`, written whole: under a partial name, renamed once complete; on
        failure (a full disk) nothing is left of it. OSError as the write gives it."""
        path = Path(folder) / f"{self.name}.csv"
        tmp, fd = create_partial(path)
        try:
            with os.fdopen(fd, "w", newline="", encoding="utf-8") as fh:
                self._write_rows(fh)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise
        return path

    def _write_rows(self, fh: IO[str]) -> None:
        fh.write(f"# {self.description}\n")
        fh.write(f"{ROWS_MARK}{len(self)}\n")
        for col, meaning in self.columns.items():
            fh.write(f"# {col}: {meaning}\n")
        writer = csv.writer(fh)
        writer.writerow(list(self.columns))
        if self._spill is not None:
            self._spill.flush()
            self._spill.seek(0)
            try:
                shutil.copyfileobj(self._spill, fh)
            finally:  # later rows go on at its end, whatever happened here
                self._spill.seek(0, 2)
        writer.writerows(zip(*self._data.values(), strict=True))


def read_truth_csv(path: Path) -> dict[str, np.ndarray[Any, Any]]:
    """A truth table back as columns (int64 where every value is an integer); an InputError
    naming the file when it is missing, unreadable, or cut or damaged (a row of another
    width: were tracebacks in `sisa process` and `calibrate`; fewer rows than its header's
    count: a table cut at a row boundary read as a shorter one)."""
    path = Path(path)
    declared: list[str] = []
    try:
        with path.open(encoding="utf-8") as fh:
            rows = list(csv.reader(_data_lines(fh, declared)))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{path}: unreadable truth table: {exc}") from None
    if not rows:
        raise InputError(f"{path}: empty truth table (no header line)")
    header, body = rows[0], rows[1:]
    short = next((n for n, r in enumerate(body, start=1) if len(r) != len(header)), None)
    if short is not None:
        raise InputError(f"{path}: data row {short} has {len(body[short - 1])} values for "
                         f"{len(header)} columns: the truth table is cut or damaged")
    if declared and declared[0] != str(len(body)):  # tables written before 2026-11-27: none
        raise InputError(f"{path}: {len(body)} data rows where its header says {declared[0]}: "
                         "the truth table is cut or damaged")
    out: dict[str, np.ndarray[Any, Any]] = {}
    for i, col in enumerate(header):
        values = [r[i] for r in body]
        try:
            ints = [int(v) for v in values]
        except ValueError:
            try:
                out[col] = np.array([float(v) for v in values])
            except ValueError:
                out[col] = np.array(values)
            continue
        try:
            out[col] = np.array(ints, dtype=np.int64)
        except OverflowError:
            row = next(n for n, v in enumerate(ints, start=1) if not -2**63 <= v < 2**63)
            raise InputError(f"{path}: data row {row}: {col} = {values[row - 1][:30]} is "
                             "beyond a 64-bit integer: the truth table is damaged") from None
    return out


def _data_lines(fh: Iterable[str], declared: list[str]) -> Iterator[str]:
    """The CSV lines of a truth table; the row count its header declares goes to `declared`."""
    for line in fh:
        if line.startswith(ROWS_MARK):
            declared.append(line[len(ROWS_MARK):].strip())
        elif not line.startswith("#"):
            yield line
