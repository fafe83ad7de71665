"""A whole flight in virtual time, in one process: emulators → acquisition → recorder.

The wiring adds what the wires and the logging computer would: serial transmission time and USB
latency before bytes reach the host, a host clock that is not GPS time, a timing board with its
own drift. The flight log gets exactly what a real flight would record; the truth goes beside it.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import can
import numpy as np

from acquisition.clocks import SimulatedHostClock, TimingBoard
from acquisition.pulses import Edge
from acquisition.runner import Acquisition
from acquisition.scanner_header import HEADER_BYTES
from emulators.gps import wire_time_ns
from emulators.runtime import Output, Port, Runner
from emulators.scenario import Scenario
from emulators.system import EmulatedSystem
from emulators.terrain import Terrain, ground_points, write_ground_points_csv
from recorder.messages import LoggedMessage, Topic
from recorder.writer import FlightRecorder
from sisa.core.errors import ConfigError
from sisa.core.timescale import NS_PER_S
from sisa.wiring.acqconfig import acquisition_config, recording_settings

SERIAL_BAUD = 115_200  # the scanner's and the camera's ports (the GPS receiver's: gps.serial_baud)
USB_LATENCY_NS = (200_000, 1_500_000)  # uniform range of the host's read latency
CAN_LATENCY_NS = (100_000, 400_000)
TICK_NS = 100_000_000
Deliver = Callable[[int, Any], None]  # an Acquisition input: (host receive time, payload)


def header_transit_ms() -> tuple[float, float]:
    """A frame header's bytes from the scanner's port to the host: the wire at SERIAL_BAUD plus
    the USB latency, shortest and longest (the read interval comes on top)."""
    wire_ms = wire_time_ns(HEADER_BYTES, SERIAL_BAUD) / 1e6
    return wire_ms + USB_LATENCY_NS[0] / 1e6, wire_ms + USB_LATENCY_NS[1] / 1e6


class Steps(Protocol):
    """What a long run tells whoever shows its progress (sisa.commands.progress.Progress)."""

    def step(self, label: str, total: float | None = None, unit: str = "") -> None: ...

    def update(self, *, completed: float | None = None, note: str | None = None) -> None: ...


class VirtualWiring:
    """The sink of a virtual-time run: delivers device outputs to the acquisition as the host
    would receive them, and the acquisition's output pulses back to the devices.

    Serial messages and CAN frames reach the host when their last byte has crossed the wire
    and the host read them (`gps.serial_baud`, SERIAL_BAUD, the USB and CAN latencies): they are
    handed to the acquisition then, in arrival order with the edges and ticks, never at the
    moment the device began sending. (Handed over at the start, a message's late receive time
    held every event after it back to it, the host being one reader: at 9600 baud a fix takes
    85 ms, and the pulse edges behind it were logged late.)"""

    def __init__(self, system: EmulatedSystem, acq_log: FlightRecorder, seed: int,
                 on_time: Callable[[int], None] | None = None) -> None:
        """`on_time`: told the flight time reached (ns since the start), every tick."""
        scn = system.scn
        self._on_time = on_time
        self.system = system
        self.rng = np.random.default_rng([seed, 99])
        self.host = SimulatedHostClock(scn.block.leap_seconds, t_ref_ns=system.traj.t_start_ns)
        self.recorder = acq_log
        self._pending: list[Edge] = []
        self.acq = Acquisition(acquisition_config(scn), self._log, self._pending.append,
                               TimingBoard())
        self._next_tick_ns = system.traj.t_start_ns
        self._restarts = sorted(
            (system.traj.t_start_ns + round(f.at_s * NS_PER_S), round(f.duration_s * NS_PER_S))
            for f in scn.faults.sync_restarts)
        self._last_t_host_ns = 0
        # (t, seq, deliver, payload): deliver(host receive time, payload)
        self._arrivals: list[tuple[int, int, Deliver, Any]] = []
        self._arrived = 0
        self._port_last: dict[Port, int] = {}
        self._integers = self.rng.integers
        acq = self.acq
        gps_baud = scn.gps.serial_baud
        # port → (deliver, baud): the serial ports
        self._serial: dict[Port, tuple[Deliver, int]] = {
            Port.GPS_SERIAL: (acq.on_gps_bytes, gps_baud),
            Port.CAMERA_SERIAL: (acq.on_camera_bytes, SERIAL_BAUD)}

    def _log(self, msg: LoggedMessage, topic: Topic | None) -> None:
        self.recorder.write(msg, topic)

    def _latency(self, lo_hi: tuple[int, int]) -> int:
        return int(self._integers(lo_hi[0], lo_hi[1]))

    def __call__(self, out: Output) -> Sequence[Edge]:
        t_ns = out.t_ns
        if self._restarts and self._restarts[0][0] <= t_ns:
            self._maybe_crash(t_ns)
        self._run_until(t_ns)
        payload = out.payload
        if isinstance(payload, can.Message):  # (most outputs: seven frames an INS record)
            self._arrive(out.port, t_ns + self._latency(CAN_LATENCY_NS), self.acq.on_can_frame,
                         payload)
        elif isinstance(payload, Edge):
            self.acq.on_edge(self._host(t_ns + 50_000), payload)
        else:
            deliver, baud = self._serial.get(out.port, (self.acq.on_scanner_bytes, SERIAL_BAUD))
            at = t_ns + wire_time_ns(len(payload), baud) + self._latency(USB_LATENCY_NS)
            self._arrive(out.port, at, deliver, payload)
        if not self._pending:
            return ()
        edges, self._pending[:] = list(self._pending), []
        return edges

    def _arrive(self, port: Port, t_ns: int, deliver: Deliver, payload: Any) -> None:
        """Hand `deliver` its host receive time and `payload` once the emulation reaches
        `t_ns`, or what came before it on the same port has arrived (a port delivers in
        order)."""
        last = self._port_last.get(port, t_ns)
        if last > t_ns:
            t_ns = last
        self._port_last[port] = t_ns
        self._arrived += 1
        heapq.heappush(self._arrivals, (t_ns, self._arrived, deliver, payload))

    def _run_until(self, t_ns: int | None) -> None:
        """Ticks and arrivals up to `t_ns` (None: every arrival left), in time order."""
        arrivals = self._arrivals
        while arrivals or (t_ns is not None and self._next_tick_ns <= t_ns):
            arrival = arrivals[0][0] if arrivals else None
            limit = t_ns if t_ns is not None else arrival
            if arrival is not None and arrival < self._next_tick_ns and (
                    limit is None or arrival <= limit):
                _, _, deliver, payload = heapq.heappop(arrivals)
                deliver(self._host(arrival), payload)
            elif limit is not None and self._next_tick_ns <= limit:
                self.acq.tick(self._host(self._next_tick_ns), self._next_tick_ns)
                self._next_tick_ns += TICK_NS
                if self._on_time is not None:
                    self._on_time(self._next_tick_ns - self.system.traj.t_start_ns)
            else:
                break

    def _host(self, t_ns: int) -> int:
        """Host receive time; never earlier than the previous receive (one reader thread)."""
        t_host = max(self.host.now_ns(t_ns), self._last_t_host_ns)
        self._last_t_host_ns = t_host
        return t_host

    def _maybe_crash(self, t_ns: int) -> None:
        while self._restarts and self._restarts[0][0] <= t_ns:
            at, down = self._restarts.pop(0)
            self.acq.crash_filter(self.acq.board.counter_ns(at + down))
            self.system.faults.append(t_gps_ns=at, kind="sync_restart", target="sisa",
                                      detail=f"down {down / NS_PER_S:g} s")

    def finish(self) -> None:
        self._run_until(None)
        self.acq.finish(self._last_t_host_ns)


def write_survey_data(scn: Scenario, terrain: Terrain, folder: Path) -> None:
    """The DEM (ellipsoidal heights, GeoTIFF) and the surveyed ground points: inputs a real
    survey has before it flies, not simulation truth."""
    folder.mkdir(parents=True, exist_ok=True)
    terrain.write_dem(folder / "dem.tif")
    try:
        points = ground_points(scn, terrain)
    except ConfigError as exc:  # a block too small for its points: fly it without them
        (folder / "ground_points.txt").write_text(f"no ground points: {exc}\n", encoding="utf-8")
        return
    write_ground_points_csv(folder / "ground_points.csv", points, utm_epsg=terrain.epsg)


def simulate(scn: Scenario, run: Path, *, images: bool = True, steps: Steps | None = None
             ) -> VirtualWiring:
    """Run the scenario's whole flight into `run` (a fresh folder): flight.mcap, scanner/,
    terrain/ (the DEM and surveyed ground points a survey would have), truth/. `steps` is
    told each step and the flight time reached."""
    if steps is not None:
        steps.step("terrain, DEM and ground points")
    terrain = Terrain.from_scenario(scn)
    write_survey_data(scn, terrain, run / "terrain")
    if steps is not None:
        steps.step("trajectory and scene" if images else "trajectory")
    system = EmulatedSystem(scn, run / "scanner" if images else None, terrain=terrain)
    meta = {"scenario": scn.block.name, **recording_settings(acquisition_config(scn))}
    on_time = None
    if steps is not None:
        steps.step("flight", (system.traj.t_end_ns - system.traj.t_start_ns) / NS_PER_S, "s")
        flight_steps = steps

        def on_time(t_ns: int) -> None:
            flight_steps.update(completed=t_ns / NS_PER_S)

    with FlightRecorder(run / "flight.mcap", metadata=meta) as rec:
        wiring = VirtualWiring(system, rec, scn.seed, on_time)
        Runner(system.devices, system.faulty(wiring)).run()
        wiring.finish()
    if steps is not None:
        steps.step("truth tables")
    system.write_truth(run / "truth")
    return wiring
