"""One hostile file must not stop the tools (issue 39, item 4): a scenario or sensor TOML nested
10 000 levels deep is one line and exit 2; one CRC-valid flight-log message of JSON nested as
deep is counted and skipped by every reader (sync, replay), named by `log info`, and left out by
`log recover --drop-undecodable`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.records import Message

from recorder.columns import read_topics
from recorder.messages import Topic
from recorder.reader import scan_log
from recorder.recover import recover
from recorder.replay import ScheduleStats, iter_schedule
from recorder.stats import DamagedLogWarning
from recorder.writer import FlightRecorder
from sisa.cli import main
from tests.mcaplog import rewrite_log
from tests.recorder import sample_messages

DEEP = 10_000
DEEP_TOML = {
    "array": "x = " + "[" * DEEP + "]" * DEEP + "\n",
    "inline table": "x = " + "{a=" * DEEP + "1" + "}" * DEEP + "\n",
    "dotted keys": ".".join(["a"] * DEEP) + " = 1\n",
    "table header": "[" + ".".join(["a"] * DEEP) + "]\n",
}
DEEP_JSON = b'{"t_host_ns": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"


def _one_line_exit_2(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize("kind", DEEP_TOML)
def test_a_deep_scenario_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     kind: str) -> None:
    scenario = tmp_path / "deep.toml"
    scenario.write_text('base = "bench"\n' + DEEP_TOML[kind])
    err = _one_line_exit_2(capsys, ["scenario", "show", str(scenario)])
    assert "nested deeper than 64 levels" in err
    _one_line_exit_2(capsys, ["simulate", "--scenario", str(scenario), "--out",
                              str(tmp_path / "run")])
    run = tmp_path / "fake-run"
    (run / "scanner").mkdir(parents=True)
    (run / "flight.mcap").touch()
    (run / "scenario.toml").write_text(scenario.read_text())
    _one_line_exit_2(capsys, ["process", str(run)])
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("kind", DEEP_TOML)
def test_a_deep_sensor_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        kind: str) -> None:
    sensor = tmp_path / "deep.toml"
    sensor.write_text('name = "x"\n' + DEEP_TOML[kind])
    (tmp_path / "scanner").mkdir()
    for name in ("flight.mcap", "d.tif"):  # there: the sensor file is what is wrong
        (tmp_path / name).write_bytes(b"")
    err = _one_line_exit_2(capsys, ["georef", str(tmp_path / "flight.mcap"), "--scanner",
                                    str(tmp_path / "scanner"), "--dem", str(tmp_path / "d.tif"),
                                    "--sensor", str(sensor), "--out", str(tmp_path / "g")])
    assert "not a TOML sensor file: nested deeper than" in err


def test_a_settings_file_is_read_only_to_its_bound(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    scenario = tmp_path / "huge.toml"
    with scenario.open("w") as fh:
        fh.write('base = "bench"\nnote = "')
        fh.write("x" * (4 << 20))
        fh.write('"\n')
    err = _one_line_exit_2(capsys, ["scenario", "show", str(scenario)])
    assert "larger than 1 MiB" in err


def test_the_bounded_parsers() -> None:
    from sisa.core.bounded import MAX_NESTING, NestingError, json_loads, nesting_depth, toml_loads

    assert json_loads(b'{"a": [1, {"b": []}]}') == {"a": [1, {"b": []}]}
    assert nesting_depth({"a": [1, {"b": []}]}) == 4
    assert json_loads("[" * MAX_NESTING + "]" * MAX_NESTING)  # the bound itself passes
    for text in ("[" * (MAX_NESTING + 1) + "]" * (MAX_NESTING + 1), DEEP_JSON.decode()):
        with pytest.raises(NestingError):
            json_loads(text)
    assert json_loads('"[[[[' + "[" * 100 + '"') == "[[[[" + "[" * 100  # in a string: text
    with pytest.raises(ValueError, match="nested deeper"):
        toml_loads(DEEP_TOML["dotted keys"])


# --- a flight log with one hostile message -------------------------------------------------------

def _log_with_hostile(folder: Path, topic: Topic, data: bytes = DEEP_JSON) -> Path:
    """A recording of every message type, and a copy with one CRC-valid message of `data` on
    `topic` after its first (the chunk's CRC and the summary are the writer's own)."""
    clean = folder / "clean.mcap"
    with FlightRecorder(clean) as rec:
        for round_ in range(3):
            for msg, t in sample_messages(1_700_000_000 * 10**9 + round_ * 10**9):
                rec.write(msg, t)
    hostile = folder / "hostile.mcap"
    added = False

    def edit(on: str, msg: Message) -> list[tuple[int, bytes]]:
        nonlocal added
        out = [(msg.log_time, msg.data)]
        if on == topic and not added:
            out.append((msg.log_time + 1, data))
            added = True
        return out

    rewrite_log(clean, hostile, edit)
    assert added
    return hostile


def test_sync_reads_a_log_with_a_hostile_message(tmp_path: Path) -> None:
    """It refused the whole flight (a RecursionError in one batch of /ins/record)."""
    log = _log_with_hostile(tmp_path, Topic.INS_RECORD)
    with pytest.warns(DamagedLogWarning, match="1 message that does not decode skipped: "
                      "/ins/record at log time .*nested deeper than"):
        cols = read_topics(log, {Topic.INS_RECORD: ["counter"], Topic.SYNC_PPS: None})
    assert len(cols[Topic.INS_RECORD]["counter"]) == 3  # the three real records


@pytest.mark.parametrize("data", [DEEP_JSON, b"[1, 2]", b'{"t_host_ns": "x"}', b"{", b"7"])
def test_any_bad_message_is_skipped_not_fatal(tmp_path: Path, data: bytes) -> None:
    log = _log_with_hostile(tmp_path, Topic.SYNC_PPS, data)
    with pytest.warns(DamagedLogWarning, match="1 message that does not decode"):
        cols = read_topics(log, {Topic.SYNC_PPS: None})
    assert len(cols[Topic.SYNC_PPS]["log_time_ns"]) == 3


@pytest.mark.parametrize("topic", [Topic.GPS_RAW, Topic.INS_RAW, Topic.PULSE_IN])
def test_replay_skips_a_hostile_raw_message(tmp_path: Path, topic: Topic) -> None:
    """`sisa replay` crashed: a RecursionError escaped its ValueError handler."""
    log = _log_with_hostile(tmp_path, topic)
    stats = ScheduleStats()
    items = list(iter_schedule(log, stats=stats))
    assert stats.undecodable == 1
    assert items


def test_log_info_names_the_message_and_recover_can_drop_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`log info` reported nothing wrong and `log recover` copied it over: the flight could not
    be salvaged with SISA's own tools."""
    log = _log_with_hostile(tmp_path, Topic.HEALTH)
    stats = scan_log(log)
    assert stats.undecodable == 1
    assert stats.bad[0].topic == Topic.HEALTH
    assert main(["log", "info", str(log)]) == 0
    out = capsys.readouterr().out
    assert "1 message could not be decoded" in out
    assert "/sisa/health at +" in out
    assert "nested deeper than" in out
    assert main(["log", "info", "--json", str(log)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["undecodable"] == 1
    assert doc["undecodable_first"][0]["topic"] == "/sisa/health"

    kept = recover(log, tmp_path / "kept.mcap")
    assert kept.undecodable == 1
    assert "copied as it is" in kept.summary()
    assert scan_log(tmp_path / "kept.mcap").undecodable == 1
    assert main(["log", "recover", "--drop-undecodable", str(log),
                 str(tmp_path / "clean-copy.mcap")]) == 0
    said = capsys.readouterr().out
    assert "1 message that does not decode left out" in said
    copy = scan_log(tmp_path / "clean-copy.mcap")
    assert copy.undecodable == 0
    assert copy.messages == stats.messages - 1
    assert copy.topics[Topic.HEALTH].count == stats.topics[Topic.HEALTH].count - 1
