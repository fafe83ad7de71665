"""A file system that fills up, for the recorder's disk-error tests."""

from __future__ import annotations

import errno
import io
from pathlib import Path


class Disk:
    """A file system with `room` bytes left in all: a write that does not fit writes what does
    (as the kernel does), the next one raises ENOSPC."""

    def __init__(self, room: int) -> None:
        self.room = room
        self.files: list[Path] = []

    def open(self, path: Path) -> io.BufferedWriter:
        self.files.append(path)
        return io.BufferedWriter(DiskFile(self, path))


class DiskFile(io.RawIOBase):
    def __init__(self, disk: Disk, path: Path) -> None:
        self._disk = disk
        self._fh = open(path, "xb", buffering=0)  # noqa: SIM115 - closed by close()

    def writable(self) -> bool:
        return True

    def write(self, data: bytes | bytearray | memoryview) -> int:  # type: ignore[override]
        if self._disk.room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = self._fh.write(bytes(data)[: self._disk.room])
        self._disk.room -= n
        return n

    def fileno(self) -> int:
        return self._fh.fileno()

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._fh.seek(pos, whence)

    def tell(self) -> int:
        return self._fh.tell()

    def close(self) -> None:
        self._fh.close()
        super().close()
