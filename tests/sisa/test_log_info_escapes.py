"""`sisa log info` shows every string a log holds escaped (issue 39, item 6): a crafted log's
topic names, schema names and health stream names reached the terminal raw (an OSC title-set,
a clear-screen, CR/LF); only the metadata values were escaped."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.writer import Writer

from recorder.messages import StreamHealth
from recorder.writer import MESSAGE_ENCODING, SCHEMA_BYTES, SCHEMA_ENCODING
from sisa.cli import main

TITLE = "\x1b]0;pwned\x07"
CLEAR = "\x1b[2J\x1b[H"
T0 = 1_700_000_000 * 10**9


def _crafted_log(path: Path) -> Path:
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start(profile="", library=f"crafted{CLEAR}")
        schema = writer.register_schema(f"x{TITLE}schema{CLEAR}", SCHEMA_ENCODING, b"{}")
        topic = writer.register_channel(f"/t{TITLE}\r\nfake line{CLEAR}", MESSAGE_ENCODING,
                                        schema)
        for i, t in enumerate([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 60, 61, 62]):  # one gap
            writer.add_message(topic, T0 + t * 10**9, b"{}", T0 + t * 10**9, sequence=i)
        health = writer.register_schema(StreamHealth.schema_name, SCHEMA_ENCODING,
                                        SCHEMA_BYTES[StreamHealth.schema_name])
        reports = writer.register_channel("/sisa/health", MESSAGE_ENCODING, health)
        report = {"t_host_ns": T0, "stream": f"gps{TITLE}\r\n{CLEAR}", "messages": 5,
                  "rate_hz": 1.0, "expected_hz": 1.0, "gaps": 0, "checksum_errors": 1,
                  "framing_errors": 0, "bytes_skipped": 0, "drops": 0, "deadline_misses": 0}
        writer.add_message(reports, T0, json.dumps(report).encode(), T0)
        writer.finish()
    return path


def test_log_info_escapes_every_name_from_the_file(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    log = _crafted_log(tmp_path / "crafted.mcap")
    assert main(["log", "info", str(log)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out
    assert "\x07" not in out
    assert "\r" not in out
    assert not any(line.startswith("fake line") for line in out.splitlines())
    assert "\\x1b]0;pwned\\x07" in out  # shown, escaped: the topic, its schema, the stream
    table_rows = [line for line in out.splitlines() if "pwned" in line]
    assert len(table_rows) == 3, out  # the topic row, the health row, the gap row
    assert main(["log", "info", "--json", str(log)]) == 0
    doc = capsys.readouterr().out
    assert "\x1b" not in doc
    assert json.loads(doc)["health"]["streams"]  # the names are JSON-escaped, whole
