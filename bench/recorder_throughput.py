"""Flight-recorder throughput: small JSON messages per second through `FlightRecorder.write`.

    .venv/bin/python bench/recorder_throughput.py [--messages 300000] [--repeat 3] [--kills]

Prints, per message kind, messages/s and MB/s of the recorder (encoding, channels, timed flush
and fsync included) and, for scale, of mcap's own Writer given the same JSON bytes ready-made.
Target: >= 50k msgs/s of small messages. Best of --repeat runs, into a temporary folder.

--kills also runs the crash tests' plan (tests/recorder/test_crash.py: recorders in child
processes SIGKILLed at seeded moments) and prints how much log time each one lost.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from mcap.writer import CompressionType, Writer

from recorder.messages import InsRecordLog, LoggedMessage, PulseEdgeLog, RawBytes, SyncPps, Topic
from recorder.writer import FlightRecorder, encode_message

T0_NS = 1_700_000_000 * 10**9
Make = Callable[[int], LoggedMessage]
KINDS: dict[str, tuple[Make, Topic | None]] = {
    "pulse edge": (lambda i: PulseEdgeLog(T0_NS + i * 1000, "PPF", i * 997, i), None),
    "sync pps": (lambda i: SyncPps(T0_NS + i * 1000, 0, i * 997, i * 10**9, 1, i % 15,
                                            i % 2, bool(i % 2)), None),
    "raw bytes (32 B)": (lambda i: RawBytes(T0_NS + i * 1000, "gps",
                                                   b"$GPGGA,123519,4807.038,N,011*47\r\n"),
                                Topic.GPS_RAW),
    "ins record": (lambda i: InsRecordLog(T0_NS + i * 1000, i, i * 10, 0.01, -0.02,
                                                   1.5, 1e-4, 2e-4, -3e-4, 60.0, 1.0, -0.5, 0,
                                                   False, 0), None),
}


def _recorder_rate(folder: Path, msgs: list[tuple[LoggedMessage, Topic | None]]) -> float:
    path = folder / f"rec_{time.perf_counter_ns()}.mcap"
    t0 = time.perf_counter()
    with FlightRecorder(path) as rec:
        for msg, topic in msgs:
            rec.write(msg, topic)
    return len(msgs) / (time.perf_counter() - t0)


def _raw_mcap_rate(folder: Path, payloads: list[tuple[int, bytes]]) -> float:
    path = folder / f"raw_{time.perf_counter_ns()}.mcap"
    t0 = time.perf_counter()
    with path.open("wb") as fh:
        writer = Writer(fh, chunk_size=64 * 1024, compression=CompressionType.NONE)
        writer.start()
        channel = writer.register_channel("/x", "json", writer.register_schema("x", "", b""))
        for t_ns, data in payloads:
            writer.add_message(channel, t_ns, data, t_ns)
        writer.finish()  # type: ignore[no-untyped-call]
    return len(payloads) / (time.perf_counter() - t0)


def _kills(folder: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' child helper
    from recorder.reader import scan_log
    from tests.recorder.crash_child import kill_many
    from tests.recorder.test_crash import PLAN

    print("\nSIGKILL at a random moment: log time lost (kill time - last message read)")
    for run in kill_many(folder, PLAN):
        stats = scan_log(run.path)
        fs = stats.files[0]
        lost_ms = (run.kill_ns - stats.end_ns) / 1e6
        print(f"  {run.rate_hz:>6.0f} Hz, killed {run.after_ready_s:.2f} s in: {stats.messages:>5} "
              f"messages in {fs.chunks_read:>2} chunks, lost {lost_ms:6.1f} ms, "
              f"{fs.bytes_unreadable} bytes of a cut record")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--messages", type=int, default=300_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--kills", action="store_true", help="also run the SIGKILL plan")
    args = parser.parse_args()
    print(f"{'kind':<18} {'JSON B':>6} {'recorder msg/s':>15} {'MB/s':>6} {'raw mcap msg/s':>15}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, (make, topic) in KINDS.items():
            msgs = [(make(i), topic) for i in range(args.messages)]
            payloads = [(T0_NS + i, encode_message(m)) for i, (m, _) in enumerate(msgs)]
            size = sum(len(d) for _, d in payloads) / len(payloads)
            rec = max(_recorder_rate(folder, msgs) for _ in range(args.repeat))
            raw = max(_raw_mcap_rate(folder, payloads) for _ in range(args.repeat))
            print(f"{name:<18} {size:>6.0f} {rec:>15,.0f} {rec * size / 1e6:>6.1f} {raw:>15,.0f}")
        if args.kills:
            _kills(folder)


if __name__ == "__main__":
    main()
