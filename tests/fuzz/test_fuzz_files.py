"""Fuzzing the files SISA reads: flight logs (MCAP), scenario files and sensor files (TOML); and
the replay of the regression corpus (`tests/fuzz/corpus/`, every input that ever failed).

MCAP seeds are real recordings made by `FlightRecorder` (every message type, NaN and infinities,
small chunks), then cut, bit-flipped and damaged where it hurts: record lengths and inner length
fields set to 0, 2^32-1, 2^63, 2^64-1, chunk CRCs zeroed so damaged chunk contents get parsed,
opcodes changed, spans deleted or repeated. Every reader (`scan_log`, `read_log`, `read_messages`,
`read_topics` with what synchronisation reads, `recover`) may only fail with a SisaError, must
not hang, must not allocate more than a bounded amount for a small file, and `recover` must copy
exactly what the reader reads into a complete file. A cut file reads a prefix of the messages.

Scenario and sensor files: arbitrary bytes, damaged presets, and TOML documents with the models'
own keys and hostile values (huge integers, NaN, infinities, dates, wrong types, deep tables).
Only ConfigError / InputError, as one line naming the file.

Corpus file names say what they are: `nmea-*`, `scanner-*`, `pulses-*` (byte streams), `ins-*`
(CAN frames, one `ID#HEX` per line, 8-digit IDs extended, `#R` remote), `mcap-*`, `scenario-*`,
`sensor-*`.
"""

from __future__ import annotations

import functools
import io
import math
import shutil
import struct
import tempfile
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import strategies as st

from emulators.scenario import PRESETS, Scenario, load_scenario
from postproc.georef import SensorModel
from recorder.columns import read_topics
from recorder.messages import InsRecordLog
from recorder.reader import LogReader, read_log, read_messages, scan_log
from recorder.recover import recover
from recorder.writer import FlightRecorder
from sisa.core.errors import ConfigError, InputError, SisaError
from tests.fuzz import CORPUS, Fuzzer, ci_settings, run_fuzzer, time_limit
from tests.fuzz.test_fuzz_codecs import NMEA, PULSES, SCANNER, check_any_bytes, check_can_frames
from tests.recorder import T0_NS, sample_messages

MCAP_MAGIC = b"\x89MCAP0\r\n"
PEAK_BYTES_LIMIT = 48 * 2**20  # reading a file of ~40 kB may use a few MB, never hundreds
INTERESTING_U64 = (0, 1, 7, 8, 9, 22, 255, 2**16, 2**31, 2**32 - 1, 2**32, 2**62, 2**63,
                   2**63 - 1, 2**64 - 1)
CHUNK = 0x06

# fuzzed logs are damaged by design: the reader's warning saying so is expected
pytestmark = pytest.mark.filterwarnings("ignore::recorder.stats.DamagedLogWarning")



# --- MCAP seeds: real recordings ----------------------------------------------------------------

_WORKDIRS: list[tempfile.TemporaryDirectory[str]] = []  # removed when the process ends


def _workdir() -> Path:
    if not _WORKDIRS:
        _WORKDIRS.append(tempfile.TemporaryDirectory(prefix="sisa-fuzz-"))
    return Path(_WORKDIRS[0].name)


@functools.cache
def mcap_seeds() -> tuple[bytes, ...]:
    """A complete recording in small chunks, and one with a summary-less crash tail."""
    folder = _workdir() / "seeds"
    folder.mkdir()
    seeds = []
    for name, rounds in (("complete.mcap", 12), ("big-chunks.mcap", 4)):
        path = folder / name
        with FlightRecorder(path, chunk_size=1024 if rounds > 4 else 64 * 1024,
                            metadata={"scenario": "fuzz", "note": "é ünïcode"}) as rec:
            for k in range(rounds):
                for msg, topic in sample_messages(T0_NS + k * 50_000_000):
                    rec.write(msg, topic)
        seeds.append(path.read_bytes())
    complete = seeds[0]
    seeds.append(complete[:_summary_start(complete)])  # a crash: every chunk, no summary
    return tuple(seeds)


def _summary_start(data: bytes) -> int:
    """Offset of the Data End record (after the last chunk)."""
    return next(off for off, op, _ in records_of(data) if op == 0x0F)


def records_of(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the top-level records, as far as they parse."""
    out, pos = [], len(MCAP_MAGIC)
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        out.append((pos, op, length))
        if length > len(data):
            break
        pos += 9 + length
    return out


@dataclass(frozen=True)
class McapCase:
    seed: int
    data: bytes
    only_cut: bool  # the seed cut short and nothing else: must read a prefix


def _mutate_mcap(draw: st.DrawFn, data: bytearray) -> None:
    recs = records_of(bytes(data))
    op = draw(st.sampled_from(("length", "inner", "zero_crc", "opcode", "flip", "delete",
                               "duplicate", "insert")))
    at = draw(st.integers(0, max(0, len(data) - 1)))
    if op in ("length", "inner", "opcode", "zero_crc") and recs:
        off, opcode, length = draw(st.sampled_from(recs))
        if op == "length":
            struct.pack_into("<Q", data, off + 1, draw(st.sampled_from(INTERESTING_U64)))
        elif op == "opcode":
            data[off] = draw(st.integers(0, 255))
        elif op == "zero_crc" and opcode == CHUNK and off + 37 <= len(data):
            struct.pack_into("<I", data, off + 33, 0)  # CRC 0: the damaged content is parsed
        elif op == "inner" and length >= 8:
            where = off + 9 + draw(st.integers(0, min(length, len(data) - off - 9) - 8))
            width = draw(st.sampled_from((4, 8)))
            value = draw(st.sampled_from(INTERESTING_U64)) % 2 ** (8 * width)
            data[where:where + width] = value.to_bytes(width, "little")
            if draw(st.booleans()) and opcode == CHUNK:
                struct.pack_into("<I", data, off + 33, 0)
    elif op == "flip" and data:
        data[at] ^= 1 << draw(st.integers(0, 7))
    elif op == "delete":
        del data[at:at + draw(st.integers(1, 64))]
    elif op == "duplicate":
        data[at:at] = data[at:at + draw(st.integers(1, 256))]
    elif op == "insert":
        data[at:at] = draw(st.binary(min_size=1, max_size=16))


@st.composite
def mcap_cases(draw: st.DrawFn) -> McapCase:
    seeds = mcap_seeds()
    k = draw(st.integers(0, len(seeds) - 1))
    data = bytearray(seeds[k])
    n_ops = draw(st.integers(0, 3))
    for _ in range(n_ops):
        _mutate_mcap(draw, data)
    cut = draw(st.none() | st.integers(0, len(data)))
    if cut is not None:
        del data[cut:]
    return McapCase(k, bytes(data), only_cut=n_ops == 0)


def _message_keys(path: Path) -> list[tuple[str, int, int, bytes]]:
    return [(c.topic, m.log_time, m.sequence, m.data) for c, m in LogReader(path).raw()]


def check_mcap(data: bytes, seed: bytes | None = None) -> int:
    """Every reader on one (damaged) file; returns the damaged chunks and undecodable messages
    it counted."""
    folder = Path(tempfile.mkdtemp(dir=_workdir()))
    try:
        path = folder / "input.mcap"
        path.write_bytes(data)
        tracemalloc.start()
        try:
            errors = _read_everything(path, folder)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert peak < PEAK_BYTES_LIMIT, f"reading {len(data)} bytes took {peak / 2**20:.0f} MiB"
        if seed is not None and data_is_mcap(data):  # a cut of a good file: a prefix
            whole = folder / "seed.mcap"
            whole.write_bytes(seed)
            got, want = _message_keys(path), _message_keys(whole)
            assert got == want[:len(got)]
        return errors
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _read_everything(path: Path, folder: Path) -> int:
    try:
        stats = scan_log(path)
    except InputError as exc:
        refused: InputError | None = exc
    else:
        refused = None
    if refused is not None:
        assert "\n" not in str(refused)
        assert not data_is_mcap(path.read_bytes())
        return 1
    fs = stats.files[0]
    assert 0 < fs.bytes_readable <= fs.size_bytes == path.stat().st_size
    assert fs.chunks_read >= 0
    assert fs.chunks_skipped >= 0
    decoded = list(read_log(path))
    reader = LogReader(path)
    assert len(list(reader)) == len(decoded)
    assert len(decoded) + reader.stats.undecodable == stats.messages
    for _topic, _t, obj in decoded:
        assert isinstance(obj, dict)
    _allowed(lambda: list(read_messages(path, InsRecordLog)), SisaError)
    _allowed(lambda: _sync_columns(path), SisaError)
    out = folder / "recovered.mcap"
    report = recover(path, out)
    assert report.messages == stats.messages
    again = scan_log(out)
    assert again.files[0].complete
    assert again.files[0].has_summary
    assert _message_keys(out) == _message_keys(path)
    assert sorted(p.name for p in folder.iterdir()) == ["input.mcap", "recovered.mcap"]
    return fs.chunks_skipped + reader.stats.undecodable


def data_is_mcap(data: bytes) -> bool:
    return data.startswith(MCAP_MAGIC)


def _sync_columns(path: Path) -> Any:
    """What time synchronisation reads from a log (postproc.sync.flightlog.WANTED), streaming."""
    from postproc.sync import WANTED

    return read_topics(path, WANTED)


def _allowed(call: Callable[[], Any], *allowed: type[BaseException]) -> Any:
    try:
        return call()
    except allowed as exc:
        error = exc
    assert "\n" not in str(error), f"a multi-line error: {error!r}"
    return None


def prop_mcap(case: McapCase) -> int:
    return check_mcap(case.data, mcap_seeds()[case.seed] if case.only_cut else None)


@dataclass(frozen=True)
class SeedRecord:
    offset: int
    opcode: int
    length: int
    messages: int  # in this chunk
    declares: frozenset[int]  # channel ids first declared in this chunk
    channels: tuple[int, ...]  # channel of each message in this chunk


@functools.cache
def seed_layout(k: int) -> tuple[SeedRecord, ...]:
    from mcap.records import Channel, Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    data = mcap_seeds()[k]
    out = []
    for off, op, length in records_of(data):
        channels: list[int] = []
        declares: set[int] = set()
        if op == CHUNK:
            raw = data[off:off + 9 + length]
            chunk = next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records)
            assert isinstance(chunk, Chunk)
            for rec in breakup_chunk(chunk):
                if isinstance(rec, Message):
                    channels.append(rec.channel_id)
                elif isinstance(rec, Channel):
                    declares.add(rec.id)
        out.append(SeedRecord(off, op, length, len(channels), frozenset(declares),
                              tuple(channels)))
    return tuple(out)


@dataclass(frozen=True)
class BitFlip:
    seed: int
    record: int  # index in seed_layout
    bit: int  # inside the record's body (after its opcode and length)


@st.composite
def bit_flips(draw: st.DrawFn) -> BitFlip:
    k = draw(st.integers(0, len(mcap_seeds()) - 1))
    layout = seed_layout(k)
    r = draw(st.integers(0, len(layout) - 1).filter(lambda i: layout[i].length > 0))
    return BitFlip(k, r, draw(st.integers(0, 8 * layout[r].length - 1)))


def prop_one_bit_flip_is_contained(case: BitFlip) -> int:
    """A bit flipped inside one record loses at most that record's messages (plus, for a chunk
    of a file without a summary, the later messages on channels that chunk declared, when the
    flip hit the declarations themselves). A length that the flip sends beyond the size limit
    may stop the file, but only there."""
    layout = seed_layout(case.seed)
    hit = layout[case.record]
    data = bytearray(mcap_seeds()[case.seed])
    data[hit.offset + 9 + case.bit // 8] ^= 1 << (case.bit % 8)
    folder = Path(tempfile.mkdtemp(dir=_workdir()))
    try:
        path = folder / "flipped.mcap"
        path.write_bytes(bytes(data))
        stats = scan_log(path)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    total = sum(r.messages for r in layout)
    before = sum(r.messages for r in layout[:case.record])
    summary = any(r.opcode == 0x02 for r in layout)  # a footer: the summary declares them all
    orphaned = 0 if summary else sum(1 for r in layout[case.record + 1:] for c in r.channels
                                     if c in hit.declares)
    stopped = any("exceeds" in p for p in stats.files[0].problems)
    assert stats.messages >= (before if stopped else total - hit.messages - orphaned), \
        f"one flipped bit in a {hit.opcode:#04x} record lost {total - stats.messages} messages"
    return stats.files[0].chunks_skipped


# --- scenario and sensor files ------------------------------------------------------------------

def _model_keys(model: type[Any]) -> dict[str, Any]:
    """Field name → sub-model (or None) of a pydantic model, for hostile documents."""
    out: dict[str, Any] = {}
    for name, info in model.model_fields.items():
        sub = info.annotation
        out[name] = sub if isinstance(sub, type) and hasattr(sub, "model_fields") else None
    return out


_toml_scalar = st.one_of(
    st.integers(-(2**63), 2**63 - 1), st.sampled_from((0, -1, 2**31, 2**63 - 1, -(2**63))),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from((0.0, -0.0, 1e308, 5e-324)),
    st.text(max_size=30), st.sampled_from(("", "bench", "auto", "1998-07-23T08:00:00",
                                           "9999-12-31T23:59:59", "0000-00-00T00:00",
                                           "1998-13-45T25:61:61", "2026-06-15 09:00")),
    st.booleans(), st.dates(), st.datetimes(), st.times())
_toml_value = st.recursive(_toml_scalar, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=8), inner, max_size=3),
                           max_leaves=8)


@st.composite
def model_documents(draw: st.DrawFn, model: type[Any], depth: int = 0) -> dict[str, Any]:
    """A TOML table with the model's own keys (and a few unknown ones), hostile values."""
    keys = _model_keys(model)
    doc: dict[str, Any] = {}
    for name in draw(st.lists(st.sampled_from(sorted(keys)), max_size=6, unique=True)):
        sub = keys[name]
        if sub is not None and depth < 2 and draw(st.booleans()):
            doc[name] = draw(model_documents(sub, depth + 1))
        else:
            doc[name] = draw(_toml_value)
    if draw(st.integers(0, 4)) == 0:  # an unknown key, maybe with a newline in it
        doc[draw(st.text(min_size=1, max_size=8) | st.just("a\nb"))] = draw(_toml_value)
    return doc


@st.composite
def scenario_documents(draw: st.DrawFn) -> bytes:
    doc = draw(model_documents(Scenario))
    if draw(st.booleans()):
        doc["base"] = draw(st.sampled_from(PRESETS) | _toml_scalar)
    return tomli_w.dumps(doc).encode()


@st.composite
def damaged_text(draw: st.DrawFn, texts: tuple[bytes, ...]) -> bytes:
    data = bytearray(draw(st.sampled_from(texts)))
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(data)))
        op = draw(st.sampled_from(("flip", "delete", "insert", "digits")))
        if op == "flip" and at < len(data):
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "delete":
            del data[at:at + draw(st.integers(1, 20))]
        elif op == "digits":  # an integer longer than Python converts by default
            data[at:at] = b"9" * draw(st.sampled_from((5, 400, 4400)))
        else:
            data[at:at] = draw(st.binary(min_size=1, max_size=10) | st.sampled_from(
                (b"[", b"]", b"[[", b"=", b'"', b"\n[block]\n", b"nan", b"inf", b"\x00")))
    return bytes(data)


def _preset_texts() -> tuple[bytes, ...]:
    from importlib import resources

    return tuple(resources.files("emulators.presets").joinpath(f"{p}.toml").read_bytes()
                 for p in PRESETS)


def _finite_everywhere(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite_everywhere(v) for v in value.values())
    if isinstance(value, list | tuple):
        return all(_finite_everywhere(v) for v in value)
    return True


def check_scenario_file(data: bytes) -> int:
    """load_scenario on a file with these bytes: a Scenario with finite numbers, or one
    ConfigError line naming the file."""
    folder = Path(tempfile.mkdtemp(dir=_workdir()))
    try:
        path = folder / "scenario.toml"
        path.write_bytes(data)
        try:
            scn = load_scenario(path)
        except ConfigError as exc:
            text = str(exc)
            assert "\n" not in text, f"a multi-line error: {text!r}"
            assert str(path) in text
            return 1
        assert isinstance(scn, Scenario)
        assert _finite_everywhere(scn.model_dump()), "a scenario with NaN or infinity loaded"
        return 0
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def check_sensor_file(data: bytes) -> int:
    """SensorModel.load: a model with finite numbers, or one InputError line naming the file."""
    folder = Path(tempfile.mkdtemp(dir=_workdir()))
    try:
        path = folder / "sensor.toml"
        path.write_bytes(data)
        try:
            model = SensorModel.load(path)
        except InputError as exc:
            text = str(exc)
            assert "\n" not in text, f"a multi-line error: {text!r}"
            assert str(path) in text
            return 1
        assert _finite_everywhere(model.model_dump()), "a sensor file with NaN or inf loaded"
        return 0
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@st.composite
def sensor_documents(draw: st.DrawFn) -> bytes:
    return tomli_w.dumps(draw(model_documents(SensorModel))).encode()


def _sensor_texts() -> tuple[bytes, ...]:
    return (SensorModel().to_toml().encode(),)


# --- the fuzzers --------------------------------------------------------------------------------

FUZZERS: list[Fuzzer] = [
    Fuzzer("mcap/damaged", mcap_cases(), prop_mcap, examples=60),
    Fuzzer("mcap/one-bit-flip", bit_flips(), prop_one_bit_flip_is_contained, examples=60),
    Fuzzer("mcap/random-bytes", st.binary(max_size=200).map(lambda b: MCAP_MAGIC + b),
           check_mcap, examples=20),
    Fuzzer("scenario/documents", scenario_documents(), check_scenario_file, examples=60),
    Fuzzer("scenario/damaged-presets", st.deferred(lambda: damaged_text(_preset_texts())),
           check_scenario_file, examples=40),
    Fuzzer("scenario/random-bytes", st.binary(max_size=200), check_scenario_file, examples=20),
    Fuzzer("sensor/documents", st.deferred(sensor_documents), check_sensor_file, examples=40),
    Fuzzer("sensor/damaged", st.deferred(lambda: damaged_text(_sensor_texts())),
           check_sensor_file, examples=30),
]


@pytest.mark.parametrize("fuzzer", FUZZERS, ids=[f.name for f in FUZZERS])
def test_fuzz_file_reader(fuzzer: Fuzzer) -> None:
    tally = run_fuzzer(fuzzer, ci_settings(fuzzer.examples))
    assert tally.examples >= 1


def test_the_seed_recordings_read_whole() -> None:
    """The seeds themselves: every message read, nothing counted as damaged."""
    for data in mcap_seeds():
        assert check_mcap(data) == 0


def test_sensor_file_with_a_huge_integer_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "sensor.toml"
    path.write_text("time_delay_ms = " + "9" * 4400 + "\n")
    with pytest.raises(InputError, match=r"sensor\.toml"):
        SensorModel.load(path)


def test_sensor_file_with_nan_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "sensor.toml"
    path.write_text("[mounting]\nlever_arm_m = [nan, 0.0, inf]\n")
    with pytest.raises(InputError, match=r"sensor\.toml"):
        SensorModel.load(path)


def test_one_damaged_index_record_loses_no_message(tmp_path: Path) -> None:
    """Found by fuzzing: one bit of a message index's length made the reader parse the rest of
    the file as index entries (178 of 180 messages lost, reported as a clean truncation)."""
    layout = seed_layout(0)
    index = next(r for r in layout if r.opcode == 0x07)
    data = bytearray(mcap_seeds()[0])
    data[index.offset + 9 + 2 + 3] ^= 0x01  # the high byte of its records length
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(data))
    stats = scan_log(path)
    assert stats.messages == sum(r.messages for r in layout)
    assert any("damaged record" in p for p in stats.files[0].problems)


@pytest.mark.parametrize(("seed", "where"), [
    (0, "end"),  # a complete file: the summary declares the channels again
    (2, "end"),  # cut short (no summary): the declarations before the damage are salvaged
    (0, "start"),  # the damage inside the declarations: the summary still has them
])
def test_a_damaged_chunk_loses_only_its_own_messages(tmp_path: Path, seed: int,
                                                     where: str) -> None:
    layout = seed_layout(seed)
    first = next(r for r in layout if r.opcode == CHUNK)
    assert first.declares, "the first chunk declares the channels of its messages"
    data = bytearray(mcap_seeds()[seed])
    at = first.offset + 9 + (first.length - 5 if where == "end" else 60)
    data[at] ^= 0x10  # inside its records: a CRC mismatch
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    stats = scan_log(path)
    assert stats.files[0].chunks_skipped == 1
    assert stats.messages == sum(r.messages for r in layout) - first.messages


def test_a_damaged_declaration_is_not_salvaged(tmp_path: Path) -> None:
    """Cut short and damaged inside a schema's text: that schema, and so its channel, is not
    trusted; the later messages of its topic are lost (and counted), the others are read."""
    layout = seed_layout(2)
    first = next(r for r in layout if r.opcode == CHUNK)
    data = bytearray(mcap_seeds()[2])
    body = bytes(data[first.offset + 9:first.offset + 9 + first.length])
    at = first.offset + 9 + body.index(b'"properties"') + 3  # inside the first schema's JSON
    data[at] ^= 0x01
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    stats = scan_log(path)
    lost = stats.files[0]
    assert lost.chunks_skipped == 1
    total = sum(r.messages for r in layout)
    assert stats.messages < total - first.messages
    assert any("undeclared channel" in p for p in lost.problems)


def test_sensor_file_key_with_a_newline_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "sensor.toml"
    path.write_text('"lever\\narm" = 0\n')
    with pytest.raises(InputError) as err:
        SensorModel.load(path)
    assert "\n" not in str(err.value)


# --- the regression corpus ----------------------------------------------------------------------

def _can_frames(text: str) -> list[tuple[int, bytes, bool, bool]]:
    frames = []
    for line in text.split("\n"):
        line = line.split(";")[0].strip()
        if not line:
            continue
        ident, _, payload = line.partition("#")
        remote = payload == "R"
        frames.append((int(ident, 16), b"" if remote else bytes.fromhex(payload),
                       len(ident) == 8, remote))
    return frames


def _replay_bytes(codec: Any) -> Callable[[bytes], int]:
    def replay(data: bytes) -> int:
        check_any_bytes(codec, [data[i:i + 1] for i in range(len(data))])
        return check_any_bytes(codec, [data])

    return replay


REPLAY: dict[str, Callable[[bytes], int]] = {
    "nmea": _replay_bytes(NMEA),
    "scanner": _replay_bytes(SCANNER),
    "pulses": _replay_bytes(PULSES),
    "ins": lambda data: check_can_frames(_can_frames(data.decode())),
    "mcap": check_mcap,
    "scenario": check_scenario_file,
    "sensor": check_sensor_file,
}


def corpus_files() -> list[Path]:
    return sorted(p for p in CORPUS.iterdir() if p.is_file())


@pytest.mark.parametrize("path", corpus_files(), ids=lambda p: p.name)
def test_the_regression_corpus_replays_clean(path: Path) -> None:
    kind = path.name.split("-")[0]
    assert kind in REPLAY, f"{path.name}: unknown corpus kind (one of {sorted(REPLAY)})"
    assert path.stat().st_size <= 64 * 1024, "corpus files stay small"
    with time_limit(20.0):
        REPLAY[kind](path.read_bytes())


def test_the_corpus_covers_every_kind() -> None:
    kinds = {p.name.split("-")[0] for p in corpus_files()}
    assert kinds >= set(REPLAY)


def test_an_assembler_corpus_line_parses() -> None:
    frames = _can_frames("100#0102030405060708\n18FECA00#01 ; extended\n101#R\n")
    assert frames == [(0x100, bytes(range(1, 9)), False, False), (0x18FECA00, b"\x01", True, False),
                      (0x101, b"", False, True)]
