"""Bad input to `sisa log`, `scenario`, `truth`, `simulate`, `emulate`, `record` and `bench`,
found by a third bad-input sweep: each was a traceback, a hang, an exit 0 on input that could not
work, a file left where it should not be, or a message that did not say what was wrong.

As everywhere: one line `sisa COMMAND: error: ...`, exit 2, nothing written.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import NonSeekingReader

from recorder.messages import RawBytes, Topic
from recorder.writer import FlightRecorder
from sisa.cli import main
from sisa.commands.bench import Ended, failure
from tests.recorder import T0_NS, write_sample_log

ROOT = Path(__file__).resolve().parents[2]
LONG = "n" * 300  # longer than a file name can be (255 bytes)
LONGEST = "m" * 250  # a name the file system takes, with no room for a suffix


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("log") / "flight.mcap"
    write_sample_log(path)
    return path


def _tree(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.lstat().st_size
            for p in sorted(folder.rglob("*")) if not p.is_dir()} | {
        str(p.relative_to(folder)) + "/": -1 for p in folder.rglob("*") if p.is_dir()}


def _one_line(code: int, err: str, command: str, *says: str) -> str:
    lines = err.splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"sisa {command}: error: "), lines[0]
    for text in says:
        assert text in lines[0], lines[0]
    return lines[0]


def _fails(argv: list[str], capsys: pytest.CaptureFixture[str], folder: Path, *says: str
           ) -> None:
    before = _tree(folder)
    code = main(argv)
    captured = capsys.readouterr()
    _one_line(code, captured.err, argv[0], *says)
    assert captured.out == ""
    assert _tree(folder) == before, "something was written on bad input"


def _child(argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "sisa.cli", *argv], capture_output=True,
                          text=True, timeout=timeout, check=False, env=env)


# --- sisa log ----------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [["log", "info", "{fifo}"],
                                  ["log", "recover", "{fifo}", "{d}/out.mcap"]])
def test_a_fifo_as_the_log_is_refused_not_waited_on(argv: list[str], tmp_path: Path) -> None:
    """open() of a FIFO waits for a writer: the command hung until killed."""
    fifo = tmp_path / "flight.mcap"
    os.mkfifo(fifo)
    args = [a.format(fifo=fifo, d=tmp_path) for a in argv]
    proc = _child(args, timeout=30)  # TimeoutExpired without the fix
    _one_line(proc.returncode, proc.stderr, "log", f"{fifo}: not an MCAP file",
              "not a regular file: a FIFO")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.mcap"]


def test_a_character_device_is_not_read_as_a_log(capsys: pytest.CaptureFixture[str],
                                                 tmp_path: Path) -> None:
    _fails(["log", "info", "/dev/zero"], capsys, tmp_path, "/dev/zero",
           "not a regular file: a character device")


def test_recover_to_a_name_too_long_is_one_line(log: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Path.exists raised ENAMETOOLONG: a traceback."""
    _fails(["log", "recover", str(log), str(tmp_path / f"{LONG}.mcap")], capsys, tmp_path,
           "cannot be used as a name: File name too long")


def test_recover_to_the_longest_name_works_and_leaves_nothing_else(
        log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The hidden scratch file took the whole name plus a suffix: over the limit, a traceback
    (from removing the scratch file that could not be made)."""
    out = tmp_path / f"{LONGEST}.mcap"
    assert main(["log", "recover", str(log), str(out)]) == 0
    with log.open("rb") as fh:  # every message of the log, counted by the mcap package
        written = sum(1 for _ in NonSeekingReader(fh).iter_messages(log_time_order=False))
    assert f"{written} messages" in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_recover_to_a_name_ending_in_a_slash_is_refused(log: Path, tmp_path: Path) -> None:
    """`OUT/` made a file named OUT."""
    proc = _child(["log", "recover", str(log), f"{tmp_path}/recovered/"])
    _one_line(proc.returncode, proc.stderr, "log recover", "ends in '/'", "not a folder")
    assert list(tmp_path.iterdir()) == []


def test_recover_to_a_numbered_name_beside_its_log_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """flight_001.mcap beside flight.mcap is read as its part 1: the recovered copy made the
    log itself unreadable ('part 0 of the recording, as is ...')."""
    log = tmp_path / "flight.mcap"
    with FlightRecorder(log) as rec:
        rec.write(RawBytes(T0_NS, "gps", b"$GPZDA\r\n"), Topic.GPS_RAW)
    _fails(["log", "recover", str(log), str(tmp_path / "flight_001.mcap")], capsys, tmp_path,
           f"{tmp_path}/flight_001.mcap would be read as part 1 of {log}")
    assert main(["log", "info", str(log)]) == 0


def test_recover_of_a_log_without_messages_warns(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """An empty 'recovered' log and exit 0, the reason only in `log info`."""
    src = tmp_path / "huge.mcap"
    src.write_bytes(b"\x89MCAP0\r\n\x06" + (2**40).to_bytes(8, "little") + b"x" * 50)
    out = tmp_path / "out.mcap"
    assert main(["log", "recover", str(src), str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"sisa log: warning: no readable messages in {src} (unreadable record after byte 8: a "
        f"record (opcode 0x06) of {2**40} bytes exceeds limit 268435456): {out} holds none"]


def test_log_info_refuses_a_negative_gap_count(log: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    _fails(["log", "info", str(log), "--gaps", "-1"], capsys, tmp_path, "--gaps -1")


# --- scenario, truth, simulate -------------------------------------------------------------------

@pytest.mark.parametrize("argv", [
    ["scenario", "show", LONG],
    ["truth", "--scenario", LONG, "--out", "{d}/t"],
    ["truth", "--out", "{d}/" + LONG],
    ["simulate", "--no-images", "--out", "{d}/" + LONG],
], ids=["scenario show", "truth --scenario", "truth --out", "simulate --out"])
def test_a_name_too_long_is_one_line(argv: list[str], tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    args = [a.format(d=tmp_path) for a in argv]
    _fails(args, capsys, tmp_path, LONG, "cannot be used as a name: File name too long")


def test_truth_into_the_longest_name_works(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """The scratch folder's name (`.NAME.partial-PID`) was over the limit: 'cannot write in'
    the parent, which could be written in."""
    out = tmp_path / LONGEST
    assert main(["truth", "--out", str(out)]) == 0
    capsys.readouterr()
    assert [p.name for p in tmp_path.iterdir()] == [LONGEST]
    assert (out / "truth" / "trajectory.csv").is_file()


# --- emulate, bench ----------------------------------------------------------------------------

@pytest.mark.parametrize(("out", "says"), [
    ("{d}/afile/emu", "cannot create {d}/afile/emu: Not a directory"),
    ("/proc/sisa-emu", "cannot create /proc/sisa-emu"),
    ("{d}/" + LONG, "cannot be used as a name"),
])
def test_emulate_out_that_cannot_be_made_is_one_line(out: str, says: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """mkdir's OSError, or Path.exists's, was a traceback."""
    (tmp_path / "afile").write_text("mine\n")
    _fails(["emulate", "--no-images", "--duration", "1", "--out", out.format(d=tmp_path)],
           capsys, tmp_path, says.format(d=tmp_path))


def test_emulate_endpoints_name_too_long_is_one_line(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    _fails(["emulate", "--out", str(tmp_path / "emu"), "--endpoints", str(tmp_path / LONG)],
           capsys, tmp_path, "--endpoints", "cannot be used as a name")


@pytest.mark.parametrize("command", ["emulate", "bench"])
def test_a_speed_too_slow_to_end_is_refused(command: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """--speed 1e-300: an OverflowError traceback once pacing began (in bench, the emulator's);
    1e-9 ran forever."""
    _fails([command, "--speed", "1e-300", "--out", str(tmp_path / "run")], capsys, tmp_path,
           "--speed 1e-300: at least 0.001")


def test_emulate_duration_beyond_any_flight_runs_to_the_end(tmp_path: Path) -> None:
    """--duration 1e308 was an OverflowError (nanoseconds) after the ports were up."""
    proc = _child(["emulate", "--no-images", "--start", "548", "--duration", "1e308",
                   "--out", str(tmp_path / "emu")], timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert (tmp_path / "emu" / "truth").is_dir()


@pytest.mark.parametrize(("args", "plays"), [(["--speed", "1000", "--duration", "40"], "0.04 s"),
                                         (["--duration", "1"], "1 s"),
                                         (["--speed", "1e308"], "5.5e-306 s")])
def test_bench_too_short_in_real_time_is_refused(args: list[str], plays: str, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Over before `sisa record` had started: 'sisa record exited 143' (or -15), or, by chance,
    exit 0 with nothing recorded."""
    _fails(["bench", "--no-images", *args, "--out", str(tmp_path / "run")], capsys, tmp_path,
           f"this run plays {plays} of real time", "at least 2 s")


def test_bench_says_why_a_recorder_stopped_while_starting() -> None:
    ok, started = Ended(0, "", ""), Ended(143, "", "")
    killed = Ended(-signal.SIGTERM, "", "")
    assert failure(ok, ok, 5.0, stopped_early=False) is None
    for rec in (started, killed):
        said = failure(ok, rec, 1.5, stopped_early=False)
        assert said is not None
        assert said.startswith("the emulated run was over (1.5 s of real time) before sisa "
                               "record had started")
    assert failure(ok, started, 1.5, stopped_early=True) == \
        "sisa emulate exited 0, sisa record exited 143"
    assert failure(Ended(1, "", ""), ok, 9.0, stopped_early=False) == \
        "sisa emulate exited 1, sisa record exited 0"


# --- record ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("endpoint", "says"), [
    ("tcp://127.0.0.1:99999", "the port is a number from 1 to 65535"),  # 'connection refused'
    ("tcp://127.0.0.1:-1", "the port is a number from 1 to 65535"),  # 'servname not supported'
    ("tcp://127.0.0.1:0", "the port is a number from 1 to 65535"),
    ("tcp://127.0.0.1:4000/x", "the port is a number from 1 to 65535"),  # 'no port number'
    ("tcp://127.0.0.1", "no port number"),  # 'only loopback addresses are allowed'
])
def test_record_pulse_endpoint_port_is_checked(endpoint: str, says: str, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    _fails(["record", "--pulses", endpoint, "--out", str(tmp_path / "r.mcap")], capsys,
           tmp_path, f"--pulses {endpoint}: {says}")


def test_record_pulse_endpoint_may_bracket_ipv6_loopback(tmp_path: Path) -> None:
    """tcp://[::1]:PORT was refused as 'only loopback addresses are allowed'."""
    import socket

    with socket.socket(socket.AF_INET6) as sock:  # a port nothing listens on
        sock.bind(("::1", 0))
        port = sock.getsockname()[1]
    proc = _child(["record", "--pulses", f"tcp://[::1]:{port}", "--out", str(tmp_path / "r.mcap")])
    _one_line(proc.returncode, proc.stderr, "record",
              f"cannot connect to pulse endpoint tcp://::1:{port}")


def test_record_pulse_endpoint_anywhere_on_loopback(tmp_path: Path) -> None:
    """127.0.0.2 is loopback as much as 127.0.0.1; it was refused as not."""
    proc = _child(["record", "--pulses", "tcp://127.0.0.2:9", "--out", str(tmp_path / "r.mcap")])
    _one_line(proc.returncode, proc.stderr, "record",
              "cannot connect to pulse endpoint tcp://127.0.0.2:9")


@pytest.mark.parametrize("host", ["10.0.0.2", "::2", "[::2]", "example.org", "127.0.0.1.nip.io"])
def test_record_pulse_endpoint_off_loopback_is_refused(host: str, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    _fails(["record", "--pulses", f"tcp://{host}:4000", "--out", str(tmp_path / "r.mcap")],
           capsys, tmp_path, "only loopback addresses are allowed")


@pytest.mark.parametrize(("option", "value", "says"), [
    ("--split-minutes", "1e300", "--split-minutes 1e+300: at most 100000"),
    ("--split-mb", "1e308", "--split-mb 1e+308: at most 1e+09"),
])
def test_record_split_too_large_is_refused(option: str, value: str, says: str, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """An OverflowError traceback (int of an infinity), the bus left open."""
    _fails(["record", "--ins", "virtual:sweep3", option, value, "--out",
            str(tmp_path / "r.mcap")], capsys, tmp_path, says)


def test_record_out_name_too_long_is_one_line(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    _fails(["record", "--ins", "virtual:sweep3", "--duration", "1", "--out",
            str(tmp_path / f"{LONG}.mcap")], capsys, tmp_path, "--out", "cannot be used as a name")


def test_record_out_ending_in_a_slash_is_refused(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """`--out runs/x/` recorded into a file named `x`."""
    with pytest.raises(SystemExit) as ended:
        main(["record", "--ins", "virtual:sweep3", "--duration", "1", "--out",
              f"{tmp_path}/recording/"])
    _one_line(int(str(ended.value.code)), capsys.readouterr().err, "record", "argument --out",
              "ends in '/'")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["record", "--ins"], ["emulate", "--can"]])
def test_socketcand_is_refused_before_python_can_fails_on_it(command: list[str], tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]
                                                             ) -> None:
    """python-can's socketcand needs host and port: a TypeError traceback."""
    _fails([*command, "socketcand:can0", "--duration", "1", "--out", str(tmp_path / "x")],
           capsys, tmp_path, "'socketcand:can0'", "host and port")


def test_a_log_under_the_longest_name_is_recorded(tmp_path: Path) -> None:
    """A 255-byte file name is one the file system takes; the recorder's hidden scratch name
    for it (the name plus '.partial-PID-...') was longer: 'cannot create'. Every scratch name
    is now made by sisa.core.outdir.partial_path, which shortens the name inside it."""
    path = tmp_path / ("m" * 250 + ".mcap")
    write_sample_log(path)
    assert path.is_file()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


@pytest.mark.parametrize("argv", [["emulate", "--preset", "bench", "--can", "kvaser:0"],
                                  ["record", "--ins", "kvaser:0"]])
def test_a_can_plugin_that_fails_in_its_own_code_is_one_line(
        argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """python-can's kvaser plugin without its library raised a NameError on opening: a
    traceback. A bus that cannot be opened, whatever its plugin raises, is one line."""
    out = tmp_path / ("run" if argv[0] == "emulate" else "flight.mcap")
    code = main([*argv, "--out", str(out)])
    last = capsys.readouterr().err.splitlines()[-1]  # (python-can logs its own warning first)
    assert code == 2
    assert last.startswith(f"sisa {argv[0]}: error: cannot open CAN kvaser:0: "), last
    assert list(tmp_path.iterdir()) == []


def test_emulate_does_not_replace_a_file_that_is_no_endpoints_file(
        tmp_path: Path, log: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--endpoints naming an existing flight log (a typo) replaced it with a few lines of JSON;
    an endpoints file left by an earlier run may still be reused."""
    victim = tmp_path / "flight.mcap"
    victim.write_bytes(log.read_bytes())
    _fails(["emulate", "--preset", "bench", "--out", str(tmp_path / "emu"), "--endpoints",
            str(victim)], capsys, tmp_path, "--endpoints", "is not an endpoints file")
    assert victim.read_bytes() == log.read_bytes()
    from sisa.commands import check_endpoints_path

    earlier = tmp_path / "ep.json"
    earlier.write_text('{"gps": "/dev/pts/3", "pulses": "tcp://127.0.0.1:4000"}\n')
    check_endpoints_path(earlier)  # no error: reused
