"""What a reopened port must show before the recorder takes it for the device it lost
(acquisition.proof): the provers on their own, and a stable udev name."""

from __future__ import annotations

import os
import pty
from pathlib import Path

from acquisition.nmea import encode, zda_from_gps_ns
from acquisition.proof import (
    PROOF_BYTES,
    PROOF_S,
    SLCAN_LISTEN_S,
    SLCAN_REPLY_S,
    VERSION_QUERY,
    ProbePort,
    SlcanProof,
    first_ubx_frame,
    gps_proof,
    scanner_proof,
    stable_serial_path,
)
from acquisition.scanner_header import FrameHeader, ScannerMode, encode_header
from acquisition.slcan_bulk import encode_frame_line

SENTENCE = encode(zda_from_gps_ns(1_400_000_000 * 10**9, 18))
HEADER = encode_header(FrameHeader(7, 1000, ScannerMode.RECORDING, 0, 19))


def _ubx(cls: int, ident: int, payload: bytes) -> bytes:
    body = bytes([cls, ident]) + len(payload).to_bytes(2, "little") + payload
    ck_a = ck_b = 0
    for byte in body:
        ck_a = (ck_a + byte) & 0xFF
        ck_b = (ck_b + ck_a) & 0xFF
    return b"\xb5\x62" + body + bytes([ck_a, ck_b])


def test_a_gps_proves_itself_by_one_sentence_and_its_data_start_there() -> None:
    proof = gps_proof()
    assert not proof.feed(b"user typed: ", 0.0).proven
    verdict = proof.feed(b"secret\r\n" + SENTENCE[:10], 0.1)
    assert not verdict.proven
    assert not verdict.rejected
    verdict = proof.feed(SENTENCE[10:] + SENTENCE, 0.2)
    assert verdict.proven
    assert verdict.data == SENTENCE + SENTENCE  # what came before the sentence is not its data


def test_a_sentence_with_a_wrong_checksum_proves_nothing() -> None:
    bad = SENTENCE[:-4] + (b"00" if SENTENCE[-4:-2] != b"00" else b"11") + b"\r\n"
    proof = gps_proof()
    assert not proof.feed(bad, 0.0).proven
    assert proof.tick(PROOF_S + 0.1).rejected


def test_text_that_is_no_protocol_is_rejected_by_size_or_time_without_being_shown() -> None:
    proof = gps_proof()
    verdict = proof.feed(b"user typed: secret-password\r\n", 0.0)
    assert not verdict.proven
    assert not verdict.rejected
    assert not proof.tick(PROOF_S - 0.1).rejected
    rejected = proof.tick(PROOF_S + 0.1).rejected
    assert "NMEA sentence" in rejected
    assert "secret" not in rejected
    flood = gps_proof()
    assert flood.feed(b"x" * (PROOF_BYTES + 1), 0.0).rejected


def test_a_silent_port_stays_on_probation() -> None:
    proof = gps_proof()
    assert proof.tick(1e6) == proof.feed(b"", 1e6)  # neither proven nor rejected
    assert not proof.tick(1e6).rejected


def test_ubx_frames_prove_a_gps_too() -> None:
    frame = _ubx(0x01, 0x07, bytes(range(92)))
    assert first_ubx_frame(b"\xb5\x62junk" + frame) == 6
    assert first_ubx_frame(frame[:-1] + bytes([frame[-1] ^ 1])) == -1
    assert gps_proof().feed(b"\x00\xff" + frame, 0.0).data == frame


def test_a_scanner_proves_itself_by_a_header_whose_crc_holds() -> None:
    proof = scanner_proof()
    damaged = HEADER[:5] + bytes([HEADER[5] ^ 1]) + HEADER[6:]
    assert not proof.feed(damaged, 0.0).proven
    verdict = proof.feed(b"\xa5" + HEADER, 0.1)
    assert verdict.proven
    assert verdict.data == HEADER


def test_an_open_slcan_adapter_proves_itself_by_its_frames_unasked() -> None:
    proof = SlcanProof(0.0)
    line = encode_frame_line(0x123, False, b"\x01\x02")
    assert not proof.feed(line, 0.01).proven
    verdict = proof.feed(line, 0.02)
    assert verdict.proven
    assert not verdict.write


def test_a_silent_slcan_port_is_asked_the_version_once() -> None:
    proof = SlcanProof(0.0)
    assert not proof.tick(SLCAN_LISTEN_S - 0.01).write
    assert proof.tick(SLCAN_LISTEN_S).write == VERSION_QUERY
    assert not proof.tick(SLCAN_LISTEN_S + 0.1).write  # once
    assert proof.feed(b"V1013\r", SLCAN_LISTEN_S + 0.2).proven
    unanswered = SlcanProof(0.0)
    assert unanswered.tick(SLCAN_LISTEN_S).write == VERSION_QUERY
    assert "version query" in unanswered.tick(SLCAN_LISTEN_S + SLCAN_REPLY_S + 0.1).rejected


def test_anything_but_slcan_rejects_the_port_before_it_is_asked_anything() -> None:
    for typed in (b"secret-password\r", b"\r", b"V1013\r", b"z" * 100):
        verdict = SlcanProof(0.0).feed(typed, 0.01)
        assert verdict.rejected, typed
        assert not verdict.write


def test_a_probe_leaves_a_ptys_settings_alone(tmp_path: Path) -> None:
    """A terminal's pty stays as its program set it (echo on, lines): pyserial would make it
    raw, turning off the echo of whoever types into it."""
    import termios

    master, slave = pty.openpty()
    try:
        before = termios.tcgetattr(slave)
        probe = ProbePort(os.ttyname(slave))
        assert termios.tcgetattr(slave) == before
        assert probe.read() == b""
        probe.close()
    finally:
        os.close(master)
        os.close(slave)


def test_a_serial_port_is_reopened_by_its_udev_name(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    try:
        name = os.ttyname(slave)
        by_id, by_path = tmp_path / "by-id", tmp_path / "by-path"
        by_id.mkdir()
        by_path.mkdir()
        (by_path / "pci-0000:00:14.0-usb-0:2:1.0-port0").symlink_to(name)
        dirs = (str(by_id), str(by_path))
        assert stable_serial_path(name, dirs) == str(by_path / "pci-0000:00:14.0-usb-0:2:1.0-port0")
        (by_id / "usb-FTDI_GPS_A1B2-if00-port0").symlink_to(name)
        assert stable_serial_path(name, dirs) == str(by_id / "usb-FTDI_GPS_A1B2-if00-port0")
        given = str(by_path / "pci-0000:00:14.0-usb-0:2:1.0-port0")
        assert stable_serial_path(given, dirs) == given  # a udev name is kept as given
        assert stable_serial_path(str(tmp_path / "nothing"), dirs) == str(tmp_path / "nothing")
    finally:
        os.close(master)
        os.close(slave)
