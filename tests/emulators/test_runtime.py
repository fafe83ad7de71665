"""The event loop: time order, feedback edges acting at their own timestamp, real-time pacing."""

import threading
import time

from acquisition.pulses import Edge, PulseLine
from emulators.runtime import Device, Output, Port, Runner


class Ticker(Device):
    """Emits a PPS edge every `period_ns` and remembers the sync edges it was given."""

    input_lines = (PulseLine.INS_SYNC,)

    def __init__(self, period_ns, count):
        self.period_ns, self.left, self.t = period_ns, count, 0
        self.inputs = []

    def next_time_ns(self):
        return self.t if self.left else None

    def emit(self, t_ns):
        self.left -= 1
        self.t += self.period_ns
        return [Output(t_ns, Port.PULSES, Edge(PulseLine.PPS, 0, t_ns))]

    def on_edge(self, edge):
        self.inputs.append(edge)


def test_outputs_in_time_order_and_feedback_delivered():
    a, b = Ticker(300, 10), Ticker(700, 5)
    seen = []

    def sink(out):
        seen.append(out.t_ns)
        return [Edge(PulseLine.INS_SYNC, 0, out.t_ns + 5)]

    Runner([a, b], sink).run()
    assert seen == sorted(seen)
    assert len(seen) == 15
    assert [e.t_ns for e in a.inputs] == [t + 5 for t in seen]


class Echo(Device):
    """Like the GPS receiver's event input: an edge schedules an output 30 ns after it; its own
    outputs come every 1000 ns."""

    input_lines = (PulseLine.GPS_EVENT,)

    def __init__(self):
        self.own, self.replies = 0, []

    def next_time_ns(self):
        times = [*self.replies[:1], *([self.own] if self.own <= 3000 else [])]
        return min(times) if times else None

    def emit(self, t_ns):
        if self.replies and self.replies[0] <= t_ns:
            self.replies.pop(0)
            return [Output(t_ns, Port.GPS_SERIAL, b"TTT")]
        self.own += 1000
        return [Output(t_ns, Port.GPS_SERIAL, b"PPS")]

    def on_edge(self, edge):
        self.replies.append(edge.t_ns + 30)


def test_an_edge_that_moves_a_device_earlier_is_acted_on_in_time():
    """The receiver's TTT for an event waited for the receiver's next planned output (the next
    PPS, up to a second later): fast event trains reached the log in bursts once a second, and
    their host times pulled the host clock map off by ~850 ppm (issue 32). An edge's device is
    asked for its next time again."""
    ticks, echo = Ticker(300, 8), Echo()
    seen = []

    def sink(out):
        seen.append((out.t_ns, out.payload))
        if out.port is Port.PULSES:
            return [Edge(PulseLine.GPS_EVENT, 0, out.t_ns + 5)]
        return []

    Runner([ticks, echo], sink).run()
    assert [t for t, _ in seen] == sorted(t for t, _ in seen)
    assert [t for t, p in seen if p == b"TTT"] == [300 * k + 35 for k in range(8)]
    assert [t for t, p in seen if p == b"PPS"] == [0, 1000, 2000, 3000]


def test_real_time_pacing_and_speed():
    dev = Ticker(20_000_000, 6)  # 6 outputs 20 ms apart = 100 ms of emulation
    stamps = []
    runner = Runner([dev], lambda out: stamps.append(time.perf_counter()) or [], speed=2.0)
    runner.run()
    elapsed = stamps[-1] - stamps[0]
    assert 0.045 < elapsed < 0.12  # 100 ms of emulation at 2x real time (slack for a busy CI)
    assert runner.late_ns_max < 5_000_000


def test_until_stops_early():
    dev = Ticker(10, 100)
    seen = []
    Runner([dev], lambda o: seen.append(o.t_ns) or []).run(until_ns=95)
    assert seen[-1] == 90


def test_skip_until_runs_devices_silently_then_paces():
    dev = Ticker(10_000_000, 20)  # 200 ms of emulation
    seen = []
    stamps = []

    def sink(out):
        seen.append(out.t_ns)
        stamps.append(time.perf_counter())
        return []

    Runner([dev], sink, speed=1.0).run(skip_until_ns=150_000_000)
    assert seen == list(range(150_000_000, 200_000_000, 10_000_000))
    assert stamps[-1] - stamps[0] < 0.1  # only the last 50 ms were paced (not 200 ms)


def test_a_stop_is_heard_while_waiting_for_a_far_emission():
    """At --speed 0.001 the next emission can be seconds away; the runner waited for it
    whole before asking whether to stop (Ctrl-C ~16 s late). It now asks between slices."""
    dev = Ticker(1_000_000_000, 2)  # the second output 1 s later: 1000 s at speed 0.001
    seen = []
    t0 = time.perf_counter()

    def stop():
        return time.perf_counter() - t0 > 0.3

    runner = Runner([dev], lambda o: seen.append(o.t_ns) or [], speed=0.001)
    worker = threading.Thread(target=runner.run, kwargs={"should_stop": stop}, daemon=True)
    worker.start()
    worker.join(3.0)  # (a daemon: a runner that does not hear the stop fails, not hangs)
    assert not worker.is_alive()
    assert seen == [0]


class Tagger(Device):
    """A receiver: answers a pulse on its event input 30 ns later; otherwise talks every 1000."""

    input_lines = (PulseLine.GPS_EVENT,)

    def __init__(self):
        self.scheduled = [1000, 2000, 3000]
        self.emitted = []

    def next_time_ns(self):
        return min(self.scheduled) if self.scheduled else None

    def emit(self, t_ns):
        self.scheduled.remove(t_ns)
        self.emitted.append(t_ns)
        return []

    def on_edge(self, edge):
        self.scheduled.append(edge.t_ns + 30)


def test_an_input_edge_brings_a_devices_next_output_forward():
    """Issue 32, item 1: the receiver's TTT waited for its next scheduled output (its next
    second) and went out then; it goes out when it is due."""
    pulses, tagger = Ticker(300, 3), Tagger()

    def sink(out):
        return [Edge(PulseLine.GPS_EVENT, 0, out.t_ns + 5)] if out.port is Port.PULSES else []

    Runner([pulses, tagger], sink).run()
    assert tagger.emitted == [35, 335, 635, 1000, 2000, 3000]
