"""What an error quotes of its input is cut (issue 39, item 5): a 100 MB key in a scenario
gave a "one-line" error of 104 857 680 bytes and took 784 MB of memory."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from sisa.cli import main

LONG = 500_000  # characters: a key or value under the settings files' size bound


def _error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err[:300]
    return err


def test_a_100_mb_key_is_a_short_line_in_bounded_memory(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = tmp_path / "huge-key.toml"
    with scenario.open("w") as fh:
        fh.write('base = "bench"\n"')
        for _ in range(100):
            fh.write("k" * 2**20)
        fh.write('" = 1\n')
    tracemalloc.start()
    try:
        err = _error(capsys, ["scenario", "show", str(scenario)])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(err) < 400, len(err)
    assert peak < 32 * 2**20, peak  # the file is not read past its bound


@pytest.mark.parametrize(("what", "text"), [
    ("unknown key", '"{k}" = 1\n'),
    ("unknown key in a table", '[block]\n"{k}" = 1\n'),
    ("unknown key with a newline", '"\\n{k}" = 1\n'),
    ("a bad value under a long key", '[block]\nstrip_length_m = "{k}"\n'),
    ("an unknown preset", 'base = "{k}"\n'),
])
def test_a_long_key_or_value_in_a_scenario_is_cut(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str],
                                                  what: str, text: str) -> None:
    scenario = tmp_path / "long.toml"
    body = text.replace("{k}", "k" * LONG)
    scenario.write_text(body if body.startswith("base") else 'base = "bench"\n' + body)
    err = _error(capsys, ["scenario", "show", str(scenario)])
    assert len(err) < 400, (what, len(err))
    assert "kkkk" in err  # what it is, shown in part


def test_a_long_key_in_a_sensor_file_is_cut(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    sensor = tmp_path / "long.toml"
    sensor.write_text('name = "x"\n[mounting]\n"' + "k" * LONG + '" = [1, 2, 3]\n')
    (tmp_path / "scanner").mkdir()
    for name in ("flight.mcap", "d.tif"):  # there: the sensor file is what is wrong
        (tmp_path / name).write_bytes(b"")
    err = _error(capsys, ["georef", str(tmp_path / "flight.mcap"), "--scanner",
                          str(tmp_path / "scanner"), "--dem", str(tmp_path / "d.tif"),
                          "--sensor", str(sensor), "--out", str(tmp_path / "g")])
    assert len(err) < 400 + len(str(sensor)), len(err)
    assert "unknown field" in err
