"""gpsd on an emulated GPS receiver (`sisa emulate --gpsd`): any gpsd client (cgps, gpspipe,
QGIS, a navigation display) then sees the emulated flight.

gpsd runs in the foreground as a child of the command (`-N`), reads the device without waiting
for a client (`-n`), never writes to it (`-b`: no probe strings into the emulator's port) and
listens on loopback only, on a port of its own (`-S`), so that a gpsd of the system on 2947 is
left alone. It reads its own copy of the receiver's stream (a second pty), so that a recorder on
the receiver's port gets every byte: two readers of one pty would each get part of them.
"""

from __future__ import annotations

import contextlib
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Final

from sisa.core.errors import InputError

GPSD_FALLBACK: Final = Path("/usr/sbin/gpsd")  # Debian's, not on a user's PATH
READY_TIMEOUT_S: Final = 10.0
STOP_TIMEOUT_S: Final = 5.0


def gpsd_binary() -> str:
    """The gpsd executable; InputError saying how to get it when there is none."""
    found = shutil.which("gpsd")
    if found is None and GPSD_FALLBACK.is_file():
        found = str(GPSD_FALLBACK)
    if found is None:
        raise InputError("--gpsd: gpsd is not installed (Debian: apt-get install gpsd); leave "
                         "out --gpsd, or open the GPS port with any NMEA client")
    return found


def free_port() -> int:
    """A loopback TCP port free now (gpsd binds it a moment later)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Gpsd:
    """A gpsd child process on `device`, serving clients on 127.0.0.1:`port`."""

    def __init__(self, device: str, port: int = 0) -> None:
        self.port = port or free_port()
        self.address = f"127.0.0.1:{self.port}"
        # its messages to a file, not a pipe nobody reads (a full pipe would stop gpsd)
        self._log = tempfile.TemporaryFile("w+", encoding="utf-8", errors="replace")  # noqa: SIM115  # closed by stop()
        self._proc = subprocess.Popen(
            [gpsd_binary(), "-N", "-n", "-b", "-S", str(self.port), device],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self._log)
        try:
            self._wait_ready()
        except BaseException:
            self.stop()
            raise

    @property
    def pid(self) -> int:
        return self._proc.pid

    def _wait_ready(self) -> None:
        """Until gpsd accepts a connection; InputError with its last words if it exits."""
        deadline = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline:
            if self._proc.poll() is not None:
                self._log.seek(0)
                said = self._log.read().strip()
                last = said.splitlines()[-1] if said else f"exit code {self._proc.returncode}"
                raise InputError(f"--gpsd: gpsd stopped at once on port {self.port}: {last}")
            with contextlib.suppress(OSError), socket.create_connection(
                    ("127.0.0.1", self.port), timeout=0.2):
                return
            time.sleep(0.05)
        raise InputError(f"--gpsd: gpsd did not listen on port {self.port} within "
                         f"{READY_TIMEOUT_S:g} s")

    def stop(self) -> None:
        """Terminate gpsd (and kill it if it does not go), once."""
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._log.close()

    def how_to_connect(self) -> list[str]:
        return [f"gpsd (on a copy of the GPS port):    tcp://{self.address}",
                f"  e.g. gpspipe -w {self.address}   or   cgps {self.address}"]
