"""The three emulated devices of one scenario, wired together with the fault injector (and,
with a `[camera]` table, the frame camera: its port, its pulses and its truth).

Each device draws from its own random stream derived from the scenario seed, so adding a device or
a fault never changes what another device does.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from enum import IntEnum
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acquisition.pulses import Edge, PulseLine
from emulators.camera import CameraDevice, CameraShots, on_frames, photo_truth, plan_shots
from emulators.faults import SpuriousPulses, WireFaults, fault_table
from emulators.gps import GpsReceiver
from emulators.ins import InsEmulator
from emulators.render import render_on_one_thread
from emulators.runtime import Device, Output, Sink
from emulators.scanner import ScannerEmulator
from emulators.scenario import Scenario
from emulators.terrain import Scene, Terrain
from emulators.trajectory import TruthTrajectory
from emulators.truth import TruthTable
from sisa.core.errors import RecorderError


class Stream(IntEnum):
    """Random-stream tags, one per consumer."""

    GPS = 1
    INS = 2
    SCANNER = 3
    WIRE = 4
    SPURIOUS = 5
    CAMERA = 6
    CAMERA_SPURIOUS = 7
    CAMERA_ON_FRAMES = 8


class EmulatedSystem:
    """GPS receiver, INS and scanner of a scenario, plus wire faults; built once per run."""

    def __init__(self, scn: Scenario, scanner_dir: Path | None, *,
                 traj: TruthTrajectory | None = None, terrain: Terrain | None = None,
                 real_time: bool = False) -> None:
        self.scn = scn
        self.traj = traj or TruthTrajectory.from_scenario(scn)
        self.faults = fault_table()
        # in real time, compute truth in small batches so no batch delays an emission
        chunk_s = {"chunk_s": 0.25} if real_time else {}
        self.gps = GpsReceiver(scn, self.traj, self._rng(Stream.GPS), self.faults, **chunk_s)
        self.ins = InsEmulator(scn, self.traj, self._rng(Stream.INS), self.faults, **chunk_s)
        scene: Scene | None = None
        if scanner_dir is not None:
            terrain = terrain or Terrain.from_scenario(scn)
            scene = Scene.from_scenario(scn, terrain)
            if real_time:
                render_on_one_thread()
        # in real time, render small blocks so a block fits between two frame pulses
        self.scanner = ScannerEmulator(scn, self.traj, terrain, scene, self._rng(Stream.SCANNER),
                                       self.faults, scanner_dir,
                                       block_lines=8 if real_time else 128,
                                       render_ahead=not real_time)
        self.devices: list[Device] = [self.gps, self.ins, self.scanner]
        if scn.faults.spurious_pulse_rate_hz > 0:
            self.devices.append(SpuriousPulses(
                scn.faults.spurious_pulse_rate_hz, (PulseLine.PPS, PulseLine.PPF),
                self.traj.t_start_ns, self.traj.t_end_ns, self._rng(Stream.SPURIOUS),
                self.faults, round(scn.faults.spurious_pps_near_second_ms * 1e6)))
        self.wire = WireFaults(scn.faults, self._rng(Stream.WIRE), self.faults)
        # the frame camera (issue 37), last: the devices before it run as without it
        self.camera_shots: CameraShots | None = None
        self._camera_truth: list[TruthTable] = []
        if scn.camera is not None:
            self._add_camera(scn)

    def _add_camera(self, scn: Scenario) -> None:
        cam = scn.camera
        if cam is None:
            return
        shots = plan_shots(cam, self.traj, self._rng(Stream.CAMERA))
        clock = self.scanner.clock

        def nearest_frame(t_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
            return clock.time_of(np.rint((t_ns - clock.t0_ns) / clock.period_ns))

        shots, moved = on_frames(shots, nearest_frame, cam.faults.on_frame_fraction,
                                 self._rng(Stream.CAMERA_ON_FRAMES))
        for i in moved:
            self.faults.append(t_gps_ns=int(shots.t_mid_ns[i]), kind="camera_on_frame",
                               target="camera", detail=f"photo {int(shots.photo_number[i])}")
        for i in np.flatnonzero(~shots.pulse_sent):
            self.faults.append(t_gps_ns=int(shots.t_mid_ns[i]), kind="camera_lost_pulse",
                               target="camera", detail=f"photo {int(shots.photo_number[i])}")
        for i in np.flatnonzero(~shots.message_sent):
            self.faults.append(t_gps_ns=int(shots.t_mid_ns[i]), kind="camera_lost_message",
                               target="camera", detail=f"photo {int(shots.photo_number[i])}")
        self.camera_shots = shots
        self._camera_truth.append(photo_truth(cam, shots, self.traj))
        self.devices.append(CameraDevice(cam, shots))
        if cam.faults.spurious_pulse_rate_hz > 0:
            self.devices.append(SpuriousPulses(
                cam.faults.spurious_pulse_rate_hz, (PulseLine.CAMERA,), self.traj.t_start_ns,
                self.traj.t_end_ns, self._rng(Stream.CAMERA_SPURIOUS), self.faults))

    def _rng(self, stream: Stream) -> np.random.Generator:
        return np.random.default_rng([self.scn.seed, int(stream)])

    def faulty(self, sink: Sink) -> Sink:
        """`sink` behind the wire faults of the scenario (a no-op when the profile is empty)."""
        if not self.wire.active:
            return sink

        def wrapped(out: Output) -> Sequence[Edge]:
            damaged = self.wire.apply(out)
            return sink(damaged) if damaged is not None else ()

        return wrapped

    def truth_tables(self) -> list[TruthTable]:
        return [*self.gps.tables, *self.ins.tables, *self.scanner.tables, *self._camera_truth,
                self.faults]

    def write_truth(self, folder: Path) -> None:
        """Every truth table into `folder`, each whole or not at all. On a disk error (a full
        disk) every table is still tried, and one RecorderError names the first file that
        failed, the cause, the tables not written and those written (whole); a folder made
        here for none is removed."""
        made = not folder.exists()
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecorderError(f"cannot create {folder}: {exc.strerror or exc}: no truth "
                                "table written") from exc
        tables = self.truth_tables()
        failed: list[str] = []
        first: tuple[Path, OSError] | None = None
        for table in tables:
            try:
                table.write_csv(folder)
            except OSError as exc:
                failed.append(table.name)
                if first is None:
                    first = (folder / f"{table.name}.csv", exc)
        if first is not None:
            path, cause = first
            written = [t.name for t in tables if t.name not in failed]
            if made and not written:  # no empty folder where the truth should be
                with contextlib.suppress(OSError):
                    folder.rmdir()
            raise RecorderError(
                f"cannot write {path}: {cause.strerror or cause}: {len(failed)} of "
                f"{len(tables)} truth tables not written ({', '.join(failed)})"
                + (f"; written whole: {', '.join(written)}" if written else "")) from cause
