"""Simulation truth, kept beside a run and never in the flight log.

Each table is columnar (one Python list per column while running, written once as CSV with a
commented header that names every column and unit). Post-processing never reads these files; tests,
benchmarks and the accuracy report of a simulated run do.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np


class TruthTable:
    """Rows of one truth table, appended while the emulation runs."""

    def __init__(self, name: str, columns: dict[str, str], description: str) -> None:
        self.name = name
        self.columns = columns  # column name → unit/meaning
        self.description = description
        self._data: dict[str, list[Any]] = {c: [] for c in columns}

    def append(self, **row: Any) -> None:
        for col, values in self._data.items():
            values.append(row[col])

    def extend(self, **cols: Iterable[Any]) -> None:
        for col, values in self._data.items():
            values.extend(cols[col])

    def __len__(self) -> int:
        return len(next(iter(self._data.values()))) if self._data else 0

    def column(self, name: str) -> np.ndarray[Any, Any]:
        return np.asarray(self._data[name])

    def write_csv(self, folder: Path) -> Path:
        path = Path(folder) / f"{self.name}.csv"
        with path.open("w", newline="", encoding="utf-8") as fh:
            fh.write(f"# {self.description}\n")
            for col, meaning in self.columns.items():
                fh.write(f"# {col}: {meaning}\n")
            writer = csv.writer(fh)
            writer.writerow(list(self.columns))
            writer.writerows(zip(*self._data.values(), strict=True))
        return path


def read_truth_csv(path: Path) -> dict[str, np.ndarray[Any, Any]]:
    """A truth table back as columns (int64 where every value is an integer)."""
    with Path(path).open(encoding="utf-8") as fh:
        rows = list(csv.reader(line for line in fh if not line.startswith("#")))
    header, body = rows[0], rows[1:]
    out: dict[str, np.ndarray[Any, Any]] = {}
    for i, col in enumerate(header):
        values = [r[i] for r in body]
        try:
            out[col] = np.array([int(v) for v in values], dtype=np.int64)
        except ValueError:
            try:
                out[col] = np.array([float(v) for v in values])
            except ValueError:
                out[col] = np.array(values)
    return out
