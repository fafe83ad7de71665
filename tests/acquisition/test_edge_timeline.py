"""A pulse source that comes back on an earlier timeline (an emulator restarted from the start
of its flight while the recorder kept running): the sync filter's state lay in the future of
the new edges and it forwarded nothing until the board caught up with where it had been."""

from __future__ import annotations

from acquisition.pulses import Edge, PulseLine
from acquisition.runner import Acquisition
from emulators.scenario import load_scenario
from recorder.messages import LoggedMessage, SyncSession, Topic
from sisa.core.timescale import NS_PER_S
from sisa.wiring.acqconfig import acquisition_config

T0_NS = 1_465_549_000 * NS_PER_S  # a whole GPS second
HOST_OFFSET_NS = 315_964_800 * NS_PER_S - 18 * NS_PER_S  # host (Unix) clock of a GPS time
LATENCY_NS = 200_000


def _pps_run(acq: Acquisition, host_from_ns: int, seconds: int) -> int:
    """PPS edges on T0, T0 + 1 s, ...; returns the host time after the last one."""
    for k in range(seconds):
        host_ns = host_from_ns + k * NS_PER_S
        acq.on_edge(host_ns, Edge(PulseLine.PPS, k, T0_NS + k * NS_PER_S))
    return host_from_ns + seconds * NS_PER_S


def test_a_pulse_source_restarted_on_an_earlier_timeline_starts_a_new_session() -> None:
    logged: list[tuple[LoggedMessage, Topic | None]] = []
    sent: list[Edge] = []
    acq = Acquisition(acquisition_config(load_scenario("bench")),
                      lambda m, t: logged.append((m, t)), sent.append)
    host_ns = _pps_run(acq, T0_NS + HOST_OFFSET_NS + LATENCY_NS, 40)
    first = len([e for e in sent if e.line is PulseLine.INS_SYNC])
    # the source is gone for 5 s, then starts again from T0 (board counts go back 45 s)
    _pps_run(acq, host_ns + 5 * NS_PER_S, 40)
    second = len([e for e in sent if e.line is PulseLine.INS_SYNC]) - first
    assert first >= 15  # LFSR-gated PPS: about half the seconds forwarded
    assert abs(second - first) <= 2  # the same again, not held back until the board catches up
    sessions = [m for m, _ in logged if isinstance(m, SyncSession)]
    assert [s.session for s in sessions] == [0, 1]
    assert acq.timeline_restarts == 1
    assert acq.streams["pps"].deadline_misses == 0  # lateness is measured on the new timeline


def test_edges_slightly_out_of_order_are_not_a_restart() -> None:
    logged: list[tuple[LoggedMessage, Topic | None]] = []
    acq = Acquisition(acquisition_config(load_scenario("bench")),
                      lambda m, t: logged.append((m, t)), lambda _e: None)
    host_ns = _pps_run(acq, T0_NS + HOST_OFFSET_NS + LATENCY_NS, 10)
    acq.on_edge(host_ns, Edge(PulseLine.PPF, 0, T0_NS + 10 * NS_PER_S))
    acq.on_edge(host_ns, Edge(PulseLine.PPS, 10, T0_NS + 10 * NS_PER_S - 3_000_000))
    assert acq.timeline_restarts == 0
    assert len([m for m, _ in logged if isinstance(m, SyncSession)]) == 1
