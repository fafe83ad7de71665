"""`sisa log info`'s recorder health: the totals of the periodic `sisa.StreamHealth` reports over
a recording, runs of a restarted recorder added up, device events not counted twice, reports
without the schema's fields skipped and counted."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from recorder.health import COUNTERS, HealthTotals
from recorder.messages import StreamHealth
from recorder.reader import scan_log
from recorder.writer import FlightRecorder
from sisa.cli import main


def _report(stream: str, messages: int, event: str = "", **counts: int) -> dict[str, Any]:
    return {"stream": stream, "messages": messages, "event": event,
            **dict.fromkeys(COUNTERS, 0), **counts}


def test_the_last_report_of_a_run_holds_its_totals() -> None:
    health = HealthTotals()
    for n, drops in ((10, 0), (20, 1), (30, 3)):
        health.add(_report("ins", n, drops=drops, checksum_errors=n // 10))
    (ins,) = health.ordered()
    assert (ins.reports, ins.messages, ins.counts["drops"], ins.decode_errors) == (3, 30, 3, 3)
    assert health.problems() == ["3 decode errors", "3 drops"]


def test_a_restarted_recorder_adds_its_run() -> None:
    health = HealthTotals()
    for n, bad in ((100, 2), (200, 5), (50, 1), (80, 4)):  # counters from zero again at 50
        health.add(_report("gps", n, framing_errors=bad))
    (gps,) = health.ordered()
    assert (gps.messages, gps.counts["framing_errors"]) == (280, 9)


def test_events_are_not_counted_again_and_bad_reports_are_counted() -> None:
    health = HealthTotals()
    health.add(_report("pps", 10, disconnects=1))
    health.add(_report("ppf", 90, disconnects=1))  # the same pulse link: counted once
    health.add(_report("pulses", 100, event="link_lost", disconnects=1))
    health.add(_report("gps", 5, drops=-1))
    health.add({"stream": "gps", "messages": "many"})
    health.add(_report("gps", 5, drops=True))  # a JSON true is no count
    assert [t.stream for t in health.ordered()] == ["pps", "ppf"]
    assert health.unreadable == 3
    assert health.problems() == ["1 disconnect"]


def test_refusals_by_reason_add_up_over_runs_and_damaged_ones_are_counted() -> None:
    health = HealthTotals()
    for n, reasons, counts in ((100, ["nmea.checksum"], [2]),
                               (200, ["nmea.checksum", "nmea.no_checksum"], [3, 1]),
                               (50, ["junk"], [1])):  # a restarted recorder
        health.add({**_report("gps", n), "refused_reasons": reasons, "refused_counts": counts})
    health.add({**_report("gps", 60), "refused_reasons": ["junk"], "refused_counts": [-1]})
    health.add({**_report("gps", 60), "refused_reasons": ["a", "b"], "refused_counts": [1]})
    (gps,) = health.ordered()
    assert gps.refused == {"junk": 1, "nmea.checksum": 3, "nmea.no_checksum": 1}
    assert health.unreadable == 2


def test_a_log_from_before_the_link_counters_is_read() -> None:
    health = HealthTotals()
    old = _report("ins", 7, drops=2)
    del old["disconnects"], old["reconnects"], old["event"]
    health.add(old)
    assert health.unreadable == 0
    assert health.ordered()[0].counts["drops"] == 2


def _log_with_reports(path: Path, reports: list[StreamHealth]) -> None:
    with FlightRecorder(path) as rec:
        for r in reports:
            rec.write(r, None)


def _health(t_s: int, stream: str, messages: int, refused: dict[str, int] | None = None,
            **counts: int) -> StreamHealth:
    values = {**dict.fromkeys(COUNTERS, 0), **counts}
    refused = refused or {}
    return StreamHealth(t_s * 10**9, stream, messages, 1.0, 1.0, 0, values["checksum_errors"],
                        values["framing_errors"], values["bytes_skipped"], values["drops"],
                        values["deadline_misses"], disconnects=values["disconnects"],
                        reconnects=values["reconnects"], refused_reasons=list(refused),
                        refused_counts=list(refused.values()))


def test_log_info_shows_the_totals(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "flight.mcap"
    _log_with_reports(path, [_health(1, "gps", 4), _health(1, "ins", 64),
                             _health(2, "gps", 9, {"nmea.checksum": 2}, checksum_errors=2,
                                     bytes_skipped=37),
                             _health(2, "ins", 128, deadline_misses=1)])
    assert scan_log(path).health.problems() == ["2 decode errors", "1 late edge"]
    assert main(["log", "info", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    at = out.index("recorder health (its own counters, totals over the recording): "
                   "2 decode errors, 1 late edge")
    assert out[at + 1].split() == ["stream", "messages", "checksum", "framing", "bytes_skipped",
                                   "drops", "late", "disconnects", "reconnects"]
    assert out[at + 2].split() == ["gps", "9", "2", "0", "37", "0", "0", "0", "0"]
    assert out[at + 3].split() == ["ins", "128", "0", "0", "0", "0", "1", "0", "0"]
    assert out[at + 4] == "  gps refused by reason: nmea.checksum 2"
    assert main(["log", "info", "--json", str(path)]) == 0
    health = json.loads(capsys.readouterr().out)["health"]
    assert health["problems"] == ["2 decode errors", "1 late edge"]
    assert health["streams"]["gps"] == {"reports": 2, "messages": 9, "checksum_errors": 2,
                                        "framing_errors": 0, "bytes_skipped": 37, "drops": 0,
                                        "deadline_misses": 0, "disconnects": 0, "reconnects": 0,
                                        "refused_by_reason": {"nmea.checksum": 2}}


def test_log_info_says_nothing_of_health_without_reports(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from tests.recorder import sample_messages

    with FlightRecorder(tmp_path / "flight.mcap") as rec:
        for msg, topic in sample_messages():
            if not isinstance(msg, StreamHealth):
                rec.write(msg, topic)
    assert main(["log", "info", str(tmp_path / "flight.mcap")]) == 0
    assert "recorder health" not in capsys.readouterr().out
