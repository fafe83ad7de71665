"""Bad input at the command line, as a user meets it: missing files, files of the wrong kind (a
text file as a flight log, a PNG as a scenario, empty files, folders), a run folder that is not
one, an output that already exists, bad device and bus arguments.

Every case must end with ONE line on stderr that says what is wrong and where (the path, or the
argument), exit code 2, nothing on stdout, and nothing written: no output folder, no partial
file, no hidden scratch folder. Also: the emulators listen on loopback only, and no package code
unpickles or evaluates anything.
"""

from __future__ import annotations

import ast
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from sisa.cli import main

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sisa", "emulators", "acquisition", "recorder", "postproc")
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\x00\x00\x00\x01\x08\x02\x00\x00\x00"


@pytest.fixture(scope="module")
def valid_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.recorder import write_sample_log

    path = tmp_path_factory.mktemp("log") / "flight.mcap"
    write_sample_log(path)
    return path


@pytest.fixture
def inputs(tmp_path: Path, valid_log: Path) -> Path:
    """A folder of wrong things: text, PNG, empty files, an ordinary folder, an existing output."""
    (tmp_path / "notes.txt").write_text("these are my notes\n")
    (tmp_path / "picture.png").write_bytes(PNG)
    (tmp_path / "empty.mcap").write_bytes(b"")
    (tmp_path / "truncated.mcap").write_bytes(b"\x89MCA")
    (tmp_path / "folder").mkdir()
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("mine\n")
    (tmp_path / "flight.mcap").write_bytes(valid_log.read_bytes())
    (tmp_path / "stale_001.mcap").write_bytes(b"")  # a part left from another recording
    log = valid_log.read_bytes()
    (tmp_path / "copy_cut.mcap").write_bytes(log[:len(log) // 2])  # a copy that stopped
    return tmp_path


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else b"<dir>")
            for p in sorted(folder.rglob("*"))}


@dataclass(frozen=True)
class Case:
    argv: tuple[str, ...]  # "{d}" is the inputs folder
    says: tuple[str, ...]  # what the one line must contain ("{d}" expanded)

    @property
    def id(self) -> str:
        return " ".join(self.argv).replace("{d}/", "")


def _case(argv: str, *says: str) -> Case:
    return Case(tuple(argv.split()), says)


IN_PROCESS = [
    _case("scenario show {d}/missing.toml", "{d}/missing.toml", "no preset or scenario file"),
    _case("scenario show {d}/picture.png", "{d}/picture.png", "not a readable TOML file"),
    _case("scenario show {d}/notes.txt", "{d}/notes.txt", "not a readable TOML file"),
    _case("scenario show {d}/folder", "{d}/folder", "no preset or scenario file"),
    _case("scenario show nosuchpreset", "nosuchpreset", "presets"),
    _case("truth --scenario {d}/picture.png --out {d}/run", "{d}/picture.png"),
    _case("truth --scenario {d}/missing.toml --out {d}/run", "{d}/missing.toml"),
    _case("truth --preset bench --out {d}/taken", "{d}/taken", "already exists"),
    _case("simulate --scenario {d}/picture.png --out {d}/run", "{d}/picture.png"),
    _case("simulate --preset nope --out {d}/run", "'nope'"),
    _case("simulate --preset bench --out {d}/taken", "{d}/taken", "already exists"),
    _case("sync {d}/notes.txt --out {d}/sync", "{d}/notes.txt", "not an MCAP file"),
    _case("sync {d}/empty.mcap --out {d}/sync", "{d}/empty.mcap", "not an MCAP file (empty)"),
    _case("sync {d}/picture.png --out {d}/sync", "{d}/picture.png", "not an MCAP file"),
    _case("sync {d}/missing.mcap --out {d}/sync", "{d}/missing.mcap", "no such file"),
    _case("sync {d}/folder --out {d}/sync", "{d}/folder", "cannot read"),
    _case("sync {d}/flight.mcap {d}/truncated.mcap --out {d}/sync", "{d}/truncated.mcap"),
    _case("sync {d}/flight.mcap --out {d}/taken", "{d}/taken", "already exists"),
    _case("sync {d}/flight.mcap --scanner {d}/missing --out {d}/sync", "{d}/missing",
          "scanner folder"),
    _case("sync {d}/flight.mcap --scanner {d}/notes.txt --out {d}/sync", "{d}/notes.txt"),
    _case("log info {d}/notes.txt", "{d}/notes.txt", "not an MCAP file"),
    _case("log info {d}/empty.mcap", "{d}/empty.mcap", "empty"),
    _case("log info {d}/missing.mcap", "{d}/missing.mcap", "no such file"),
    _case("log info {d}/folder", "{d}/folder"),
    _case("log info {d}/flight.mcap {d}/picture.png", "{d}/picture.png", "not an MCAP file"),
    _case("log recover {d}/notes.txt {d}/out.mcap", "{d}/notes.txt", "not an MCAP file"),
    _case("log recover {d}/empty.mcap {d}/out.mcap", "{d}/empty.mcap"),
    _case("log recover {d}/missing.mcap {d}/out.mcap", "{d}/missing.mcap"),
    _case("log recover {d}/flight.mcap {d}/notes.txt", "{d}/notes.txt", "already exists"),
    _case("log recover {d}/flight.mcap {d}/taken", "{d}/taken", "already exists"),
    _case("log recover {d}/flight.mcap {d}/nowhere/out.mcap", "{d}/nowhere", "not a folder"),
    _case("process {d}/folder", "{d}/folder", "not a run folder"),
    _case("process {d}/missing", "{d}/missing: no such folder"),
    _case("process {d}/notes.txt", "{d}/notes.txt", "not a run folder"),
    # a run of `simulate --no-images` (here: a folder with a log only) said "no such scanner
    # folder" (found by a bad-input sweep)
    _case("process {d}", "{d}: no scanner/ folder", "--no-images"),
]

IN_A_CHILD = [  # what changes the process (signal handlers, switch interval) runs apart
    _case("record --out {d}/rec.mcap", "nothing to record"),
    _case("record --gps {d}/nodev --out {d}/rec.mcap", "{d}/nodev", "cannot open"),
    _case("record --gps {d}/notes.txt --out {d}/rec.mcap", "{d}/notes.txt", "cannot open"),
    _case("record --ins bogus --out {d}/rec.mcap", "'bogus'", "INTERFACE:CHANNEL"),
    _case("record --ins nosuch:chan --out {d}/rec.mcap", "nosuch:chan"),
    _case("record --pulses http://example.org:80 --out {d}/rec.mcap", "http://example.org:80",
          "loopback"),
    _case("record --pulses tcp://10.1.2.3:4000 --out {d}/rec.mcap", "tcp://10.1.2.3:4000",
          "loopback"),
    _case("record --pulses tcp://127.0.0.1:1 --out {d}/rec.mcap", "tcp://127.0.0.1:1"),
    _case("record --gps {d}/notes.txt --out {d}/flight.mcap", "{d}/flight.mcap",
          "already exists"),
    _case("record --gps {d}/nodev --scenario {d}/picture.png --out {d}/rec.mcap",
          "{d}/picture.png"),
    _case("emulate --can bogus --out {d}/emu", "'bogus'", "INTERFACE:CHANNEL"),
    _case("emulate --speed 0 --out {d}/emu", "--speed"),
    _case("emulate --speed -2 --out {d}/emu", "--speed"),
    _case("emulate --out {d}/taken", "{d}/taken", "already exists"),
    _case("emulate --scenario {d}/picture.png --out {d}/emu", "{d}/picture.png"),
]

FOUND_BY_THIS_SUITE = [  # were bugs; fixed
    # tracebacks (socket.bind, int(nan)), or a bench run at infinite speed
    _case("emulate --pulses-port 70000 --out {d}/emu", "--pulses-port 70000", "0 to 65535"),
    _case("replay {d}/flight.mcap --pulses-port -1 --once", "--pulses-port -1"),
    _case("emulate --speed nan --out {d}/emu", "--speed nan", "finite"),
    _case("bench --speed inf --out {d}/run", "--speed inf", "finite"),
    _case("calibrate {d}/folder --out {d}/cal --sim-delay-ms nan", "--sim-delay-ms nan"),
    _case("simulate --seed -1 --no-images --out {d}/sim", "--seed -1"),  # numpy's traceback
    _case("simulate --seed 4294967296 --no-images --out {d}/sim", "--seed 4294967296"),
    # ran silently through the flight and recorded nothing
    _case("emulate --start 600 --out {d}/emu", "--start 600 s", "the bench flight lasts 549"),
    _case("emulate --start -1 --out {d}/emu", "--start -1 s"),
    _case("emulate --duration 0 --out {d}/emu", "--duration"),
    _case("bench --start 600 --out {d}/run", "--start 600 s", "the bench flight lasts 549"),
    _case("bench --duration -5 --out {d}/run", "--duration"),
    _case("bench --speed 0 --out {d}/run", "--speed"),
    _case("emulate --can nosuch:chan --out {d}/emu", "nosuch:chan"),
    _case("georef {d}/flight.mcap --scanner {d}/folder --dem {d}/picture.png --out {d}/geo",
          "{d}/picture.png"),
    # recorded nothing with exit 0, split after every message, or named an internal field
    _case("record --gps {d}/notes.txt --duration 0 --out {d}/rec.mcap", "--duration 0"),
    _case("record --gps {d}/notes.txt --duration -3 --out {d}/rec.mcap", "--duration -3"),
    _case("record --gps {d}/notes.txt --split-minutes 0 --out {d}/rec.mcap", "--split-minutes 0"),
    _case("record --gps {d}/notes.txt --split-minutes 1e-9 --out {d}/rec.mcap",
          "--split-minutes 1e-09"),
    _case("record --gps {d}/notes.txt --split-mb -1 --out {d}/rec.mcap", "--split-mb -1"),
    _case("record --gps {d}/notes.txt --scanner {d}/notes.txt --out {d}/rec.mcap",
          "--gps and --scanner", "same device"),
    # recorded nothing with exit 0: a new pty that nothing writes to
    _case("record --gps /dev/ptmx --out {d}/rec.mcap", "--gps /dev/ptmx: the pty multiplexer"),
    _case("record --ins slcan:/dev/pts/ptmx --out {d}/rec.mcap",
          "--ins slcan:/dev/pts/ptmx: the pty multiplexer"),
    # a traceback from the scratch folder's mkdir
    _case("sync {d}/flight.mcap --out /proc/sisa-out", "cannot write in /proc"),
    # wrote a log beside a stale part that readers then joined to it
    _case("log recover {d}/flight.mcap {d}/stale.mcap", "{d}/stale_001.mcap already exists"),
    # counted every message twice
    _case("log info {d}/flight.mcap {d}/flight.mcap", "{d}/flight.mcap is given twice"),
    _case("sync {d}/flight.mcap {d}/folder/../flight.mcap --out {d}/s", "is given twice"),
    # a log and a (cut) copy of it were read as one flight with an INS reboot between
    _case("log info {d}/flight.mcap {d}/copy_cut.mcap",
          "{d}/copy_cut.mcap starts with the same data as {d}/flight.mcap (a copy of it?)"),
    _case("sync {d}/copy_cut.mcap {d}/flight.mcap --out {d}/s",
          "{d}/flight.mcap starts with the same data as {d}/copy_cut.mcap"),
    # a traceback after the ports were up (emulate), or ports opened before the error (replay)
    _case("emulate --endpoints {d}/nodir/ep.json --out {d}/emu", "--endpoints", "{d}/nodir"),
    _case("emulate --endpoints {d}/folder --out {d}/emu", "--endpoints", "is a folder"),
    _case("replay {d}/flight.mcap --once --endpoints {d}/nodir/ep.json", "--endpoints",
          "{d}/nodir"),
    # an OverflowError traceback (1e308 s in nanoseconds); a replay that would never end
    _case("replay {d}/flight.mcap --once --no-wait --start 1e308", "--start 1e+308 s",
          "beyond the end of the log"),
    _case("replay {d}/flight.mcap --once --no-wait --rate 1e-300", "--rate 1e-300",
          "at least 0.001"),
]


def _expand(case: Case, d: Path) -> tuple[list[str], list[str]]:
    return ([a.replace("{d}", str(d)) for a in case.argv],
            [s.replace("{d}", str(d)) for s in case.says])


def _check(code: int, out: str, err: str, command: str, says: list[str]) -> None:
    lines = err.splitlines()
    assert code == 2, f"exit {code}; stderr: {err[-2000:]}"
    assert len(lines) == 1, f"not one line: {err!r}"
    assert lines[0].startswith(f"sisa {command}: error: "), lines[0]
    for text in says:
        assert text in lines[0], f"{text!r} not in {lines[0]!r}"
    assert "Traceback" not in err
    assert out == ""


@pytest.mark.parametrize("case", IN_PROCESS, ids=[c.id for c in IN_PROCESS])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(case: Case, inputs: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    argv, says = _expand(case, inputs)
    before = _tree(inputs)
    code = main(argv)
    captured = capsys.readouterr()
    _check(code, captured.out, captured.err, argv[0], says)
    assert _tree(inputs) == before, "something was written (or changed) on bad input"


def _run_child(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "sisa.cli", *argv], capture_output=True,
                          text=True, timeout=120, check=False, cwd=cwd, env=env)


@pytest.mark.parametrize("case", [*IN_A_CHILD, *FOUND_BY_THIS_SUITE],
                         ids=[c.id for c in IN_A_CHILD]
                         + [f"found: {c.id}" for c in FOUND_BY_THIS_SUITE])
def test_bad_arguments_in_a_child_process(case: Case, inputs: Path) -> None:
    argv, says = _expand(case, inputs)
    before = _tree(inputs)
    proc = _run_child(argv, inputs)
    _check(proc.returncode, proc.stdout, proc.stderr, argv[0], says)
    assert _tree(inputs) == before, "something was written (or changed) on bad input"


def test_the_sisa_entry_point_itself_says_one_line(inputs: Path) -> None:
    """The installed `sisa` script, not only `python -m sisa.cli`."""
    sisa = Path(sys.executable).with_name("sisa")
    assert sisa.is_file()
    proc = subprocess.run([str(sisa), "log", "info", str(inputs / "picture.png")],
                          capture_output=True, text=True, timeout=60, check=False)
    _check(proc.returncode, proc.stdout, proc.stderr, "log",
           [str(inputs / "picture.png"), "not an MCAP file"])


def test_a_log_that_does_not_match_its_schema_names_the_file_and_topic(
        inputs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A damaged but readable log: the message that does not decode is skipped, never fatal
    (issue 39, item 4), and a warning names the file, the topic and why; the error then says
    what the log lacks, naming the file."""
    from mcap.writer import CompressionType, Writer

    from recorder.writer import SCHEMAS

    path = inputs / "bad-values.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh, compression=CompressionType.NONE)
        writer.start()
        schema = writer.register_schema("sisa.InsRecord", "jsonschema",
                                        json.dumps(SCHEMAS["sisa.InsRecord"]).encode())
        channel = writer.register_channel("/ins/record", "json", schema)
        writer.add_message(channel, 1, b'{"t_host_ns": 1, "counter": 1e400}', 1)
        writer.finish()
    before = _tree(inputs)
    from recorder.stats import DamagedLogWarning

    with pytest.warns(DamagedLogWarning, match=f"^{re.escape(str(path))}: 1 message that does "
                      "not decode skipped: /ins/record at log time 1: "):
        code = main(["sync", str(path), "--out", str(inputs / "sync")])
    captured = capsys.readouterr()
    _check(code, captured.out, captured.err, "sync", [str(path), "no INS records"])
    assert _tree(inputs) == before


@pytest.fixture(scope="module")
def two_flights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding parts 0, 1, 3 of one split flight and part 2 of another, all named
    flight*.mcap (as after copying two flights' cards into one folder), and a scanner folder."""
    from recorder.messages import RawBytes, Topic
    from recorder.writer import FlightRecorder, split_parts
    from tests.recorder import T0_NS

    root = tmp_path_factory.mktemp("flights")
    parts = []
    for name, t0_ns in (("a", T0_NS), ("b", T0_NS + 100 * 10**9)):
        (root / name).mkdir()
        with FlightRecorder(root / name / "flight.mcap", split_duration_s=10.0) as rec:
            for i in range(4000):
                rec.write(RawBytes(t0_ns + i * 10**7, "gps", b"$GPZDA\r\n"), Topic.GPS_RAW)
        parts.append(split_parts(root / name / "flight.mcap"))
    mixed = root / "mixed"
    (mixed / "scanner").mkdir(parents=True)
    (mixed / "dem.tif").write_bytes(b"")  # there (a missing input is said first), never read
    for src in (parts[0][0], parts[0][1], parts[1][2], parts[0][3]):
        (mixed / src.name).write_bytes(src.read_bytes())
    return mixed


MIXED_FLIGHTS = [  # found by a bad-input sweep: merged silently, exit 0 (georef: 10 minutes of
    # work, wrong products)
    "log info {d}/flight.mcap",
    "log info {d}/flight_003.mcap {d}/flight_002.mcap {d}/flight_001.mcap {d}/flight.mcap",
    "sync {d}/flight.mcap --out {d}/sync",
    "georef {d}/flight.mcap --scanner {d}/scanner --dem {d}/dem.tif --out {d}/geo",
    "replay {d}/flight.mcap --once --no-wait",
]


@pytest.mark.parametrize("argv", MIXED_FLIGHTS)
def test_a_part_of_another_flight_is_one_line_exit_2(argv: str, two_flights: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    args = argv.replace("{d}", str(two_flights)).split()
    before = _tree(two_flights)
    code = main(args)
    captured = capsys.readouterr()
    _check(code, captured.out, captured.err, args[0],
           [f"{two_flights}/flight_002.mcap is part 2 of another recording (id ",
            f"than {two_flights}/flight.mcap (id ", "each flight's parts are read together"])
    assert _tree(two_flights) == before


# --- the network: loopback only -----------------------------------------------------------------

def _socket_inodes(pid: int) -> set[str]:
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with_target = os.readlink(fd) if fd.is_symlink() else ""
        if with_target.startswith("socket:["):
            inodes.add(with_target[len("socket:["):-1])
    return inodes


def _address(hex_addr: str) -> str:
    """/proc/net/* local address (little-endian hex words) as text, without the port."""
    host = hex_addr.split(":")[0]
    words = [bytes.fromhex(host[i:i + 8])[::-1] for i in range(0, len(host), 8)]
    raw = b"".join(words)
    if len(raw) == 4:
        return ".".join(str(b) for b in raw)
    if raw[:12] == b"\x00" * 10 + b"\xff\xff":  # IPv4-mapped
        return ".".join(str(b) for b in raw[12:])
    return ":".join(raw[i:i + 2].hex() for i in range(0, 16, 2))


def bound_sockets(pid: int) -> list[tuple[str, str, str]]:
    """(protocol, local address, state) of every TCP listener and UDP socket of a process."""
    inodes = _socket_inodes(pid)
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        table = Path(f"/proc/{pid}/net/{proto}")
        if not table.exists():
            continue
        for line in table.read_text().splitlines()[1:]:
            cols = line.split()
            local, state, inode = cols[1], cols[3], cols[9]
            listening = proto.startswith("udp") or state == "0A"
            if inode in inodes and listening:
                found.append((proto, _address(local), state))
    return found


LOOPBACK = ("127.0.0.1", "0000:0000:0000:0000:0000:0000:0000:0001")


def test_address_parsing_knows_loopback_from_any() -> None:
    assert _address("0100007F:1F90") == "127.0.0.1"
    assert _address("00000000:1F90") == "0.0.0.0"
    assert _address("00000000000000000000000001000000:0035") in LOOPBACK
    assert _address("0000000000000000FFFF00000100007F:0035") == "127.0.0.1"
    assert _address("00000000000000000000000000000000:0035") not in LOOPBACK


def test_sisa_emulate_listens_on_loopback_only(tmp_path: Path) -> None:
    endpoints = tmp_path / "endpoints.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "sisa.cli", "emulate", "--preset", "bench",
                             "--no-images", "--duration", "60", "--out", str(tmp_path / "run"),
                             "--endpoints", str(endpoints)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    try:
        deadline = time.monotonic() + 60
        while not (endpoints.exists() and endpoints.stat().st_size):
            assert proc.poll() is None, f"sisa emulate died: {proc.stderr.read()[-2000:]}"
            assert time.monotonic() < deadline, "sisa emulate did not start"
            time.sleep(0.05)
        sockets = bound_sockets(proc.pid)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert sockets, "the pulse endpoint should be a listening socket"
    for proto, address, _state in sockets:
        assert address in LOOPBACK, f"sisa emulate listens on {proto} {address}"


# --- no unpickling, no eval ---------------------------------------------------------------------

FORBIDDEN_CALLS = {"eval", "exec", "compile", "__import__"}
FORBIDDEN_ATTRIBUTES = {("pickle", "load"), ("pickle", "loads"), ("pickle", "Unpickler"),
                        ("marshal", "load"), ("marshal", "loads"), ("shelve", "open"),
                        ("dill", "load"), ("dill", "loads"), ("torch", "load"),
                        ("yaml", "load"), ("yaml", "unsafe_load"), ("jsonpickle", "decode")}
FORBIDDEN_MODULES = {"pickle", "cPickle", "_pickle", "marshal", "shelve", "dill", "jsonpickle"}
ALLOWED: set[tuple[str, int]] = set()  # (file, line) reviewed and accepted: none so far


def forbidden_uses(source: str) -> list[tuple[int, str]]:
    """Calls that run or unpickle data: eval/exec/compile, pickle & co., allow_pickle=True."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import | ast.ImportFrom):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""]
            found += [(node.lineno, f"import {n}") for n in names
                      if n.split(".")[0] in FORBIDDEN_MODULES]
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        if isinstance(func, ast.Name) and func.id in FORBIDDEN_CALLS:
            found.append((node.lineno, f"{func.id}()"))
        if (isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name)
                and (func.value.id, func.attr) in FORBIDDEN_ATTRIBUTES):
            found.append((node.lineno, f"{func.value.id}.{func.attr}()"))
        for kw in node.keywords:
            if (kw.arg == "allow_pickle" and isinstance(kw.value, ast.Constant)
                    and kw.value.value is True):
                found.append((node.lineno, "allow_pickle=True"))
    return found


def test_the_checker_finds_what_it_looks_for() -> None:
    source = ("import pickle\nfrom marshal import loads\nx = eval('1')\nexec('y = 2')\n"
              "pickle.loads(b'')\nnp.load('a.npy', allow_pickle=True)\n"
              "ast.literal_eval('1')\nmodel.evaluate(1)\n")
    assert [line for line, _ in forbidden_uses(source)] == [1, 2, 3, 4, 5, 6]


def test_no_package_code_unpickles_or_evaluates_input() -> None:
    files = [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]
    assert len(files) > 20
    bad = [f"{path.relative_to(ROOT)}:{line}: {what}"
           for path in files for line, what in forbidden_uses(path.read_text("utf-8"))
           if (str(path.relative_to(ROOT)), line) not in ALLOWED]
    assert not bad, "\n".join(bad)


HEAVY_MODULES = ("numpy", "scipy", "rasterio", "pyproj", "numba", "matplotlib", "mcap")
SLOW_TO_FAIL = [  # a missing input said only after ~1.5 s of imports (issue 33, item 8)
    ("process {d}/missing", "{d}/missing: no such folder"),
    ("georef {d}/missing.mcap --scanner {d}/folder --dem {d}/dem.tif --out {d}/geo",
     "{d}/missing.mcap: no such file"),
    ("georef {d}/flight.mcap --scanner {d}/noscanner --dem {d}/dem.tif --out {d}/geo",
     "--scanner {d}/noscanner: no such folder"),
    ("georef {d}/flight.mcap --scanner {d}/folder --dem {d}/nodem.tif --out {d}/geo",
     "--dem {d}/nodem.tif: no such file"),
    ("calibrate {d}/missing --out {d}/cal", "{d}/missing: no such file or folder"),
    ("calibrate {d}/folder --gcp {d}/missing.csv --out {d}/cal", "--gcp {d}/missing.csv"),
    ("process {d}/folder --sensor {d}/missing.toml", "--sensor {d}/missing.toml: no such file"),
]


@pytest.mark.parametrize(("argv", "says"), SLOW_TO_FAIL, ids=[a for a, _ in SLOW_TO_FAIL])
def test_a_missing_input_is_said_before_any_heavy_import(argv: str, says: str,
                                                         inputs: Path) -> None:
    """Arguments are checked first: the command fails in the time Python takes to start,
    without importing numpy, GDAL, PROJ, numba or the georeferencing."""
    words = [a.replace("{d}", str(inputs)) for a in argv.split()]
    code = ("import sys\nfrom sisa.cli import main\ncode = main(sys.argv[1:])\n"
            f"print(sorted(m for m in {HEAVY_MODULES!r} if m in sys.modules))\n"
            "sys.exit(code)")
    proc = subprocess.run([sys.executable, "-c", code, *words], capture_output=True, text=True,
                          timeout=60, check=False, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    _check(proc.returncode, "", proc.stderr, words[0], [says.replace("{d}", str(inputs))])
    assert proc.stdout.strip() == "[]", f"imported before failing: {proc.stdout}"
