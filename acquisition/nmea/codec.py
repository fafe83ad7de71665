"""One sentence: `$`, address, fields, `*hh` checksum and line end, to and from bytes.

Encoding writes upper-case checksum digits and CRLF, in the NMEA version asked for
(`DEFAULT_VERSION`, 2.3, is what the emulated Ashtech Z-12 writes). Decoding takes any talker
for a standard sentence (two letters and the formatter: `GNGGA`, `GBRMC`, `INZDA`), checksum
digits in either case, and any line end (CRLF, LF or CR, or none). Every refusal is a
`RefusedError` naming its `Refusal` reason; a sentence without a checksum is refused
(`Refusal.NO_CHECKSUM`) unless the caller accepts it explicitly.
"""

from __future__ import annotations

import re

from acquisition.codec import ErrorKind, RefusedError
from acquisition.nmea.sentences import SPEC_BY_TYPE, SPECS, NmeaMessage, UnknownSentence
from acquisition.nmea.tables import NmeaVersion, Refusal, decode_fields, encode_fields
from sisa.core.errors import EncodeError
from sisa.core.nmea import checksum

# Framing. NMEA 0183 caps a sentence at 82 bytes; our 7-decimal GGA reaches 96 and real Ashtech
# proprietary sentences ($PASHR,POS) run past 100, so the cap leaves room while still bounding
# what garbage can make the stream decoder hold.
MAX_SENTENCE_BYTES = 128
SENTENCE_START_BYTE = b"$"
SENTENCE_START = SENTENCE_START_BYTE[0]
LINE_END = b"\r\n"
CHECKSUM_DELIMITER = b"*"
FIELD_SEPARATOR = ","
PROPRIETARY_PREFIX = "P"
TALKER_CHARS = 2
DEFAULT_VERSION = NmeaVersion.V2_3
_PRINTABLE_ASCII = re.compile(rb"[\x20-\x7e]*")
_HEX_PAIR = re.compile(rb"[0-9A-Fa-f]{2}")
_ADDRESS = re.compile(r"[A-Z0-9]+")
_TALKER = re.compile(r"[A-Z][A-Z0-9]")

_STANDARD = {spec.header[0]: spec for spec in SPECS if not spec.proprietary}
_PROPRIETARY = {spec.header: spec for spec in SPECS if spec.proprietary}
_MAX_HEADER_TOKENS = max(len(header) for header in _PROPRIETARY)


class ChecksumError(RefusedError):
    """The `*hh` checksum does not match the sentence: counted apart from framing errors."""

    def __init__(self, message: str, *, raw: bytes = b"") -> None:
        super().__init__(Refusal.CHECKSUM, message, kind=ErrorKind.CHECKSUM, raw=raw)


def _tokens_of(message: NmeaMessage, version: NmeaVersion) -> list[str]:
    if isinstance(message, UnknownSentence):
        return [message.address, *message.fields]
    spec = SPEC_BY_TYPE[type(message)]
    if spec.proprietary:
        address = list(spec.header)
    else:
        talker = getattr(message, "talker", "")
        if _TALKER.fullmatch(talker) is None or talker.startswith(PROPRIETARY_PREFIX):
            raise EncodeError(f"{spec.kind}: talker {talker!r} is not two capitals or digits")
        address = [talker + spec.header[0]]
    return address + encode_fields(spec, message, version)


def encode(message: NmeaMessage, version: NmeaVersion = DEFAULT_VERSION) -> bytes:
    """The complete sentence, `$...*hh` and CRLF, as NMEA `version` has it."""
    body = FIELD_SEPARATOR.join(_tokens_of(message, version)).encode("ascii")
    sentence = b"%s%s%s%02X%s" % (SENTENCE_START_BYTE, body, CHECKSUM_DELIMITER,
                                   checksum(body), LINE_END)
    if len(sentence) > MAX_SENTENCE_BYTES:
        raise EncodeError(f"sentence of {len(sentence)} bytes exceeds {MAX_SENTENCE_BYTES}")
    return sentence


def _verified_body(raw: bytes, accept_missing_checksum: bool) -> str:
    """The text between `$` and `*` of a sentence whose framing and checksum are right."""
    text = raw.removesuffix(b"\n").removesuffix(b"\r")
    if not text.startswith(SENTENCE_START_BYTE):
        raise RefusedError(Refusal.MALFORMED, "sentence does not start with '$'", raw=raw)
    if _PRINTABLE_ASCII.fullmatch(text) is None:
        raise RefusedError(Refusal.MALFORMED, "non-printable or non-ASCII byte in sentence",
                           raw=raw)
    star = text.rfind(CHECKSUM_DELIMITER)
    if star < 0:
        if not accept_missing_checksum:
            raise RefusedError(Refusal.NO_CHECKSUM, "sentence without '*hh' checksum", raw=raw)
        body = text[1:]
    else:
        digits = text[star + 1:]
        if _HEX_PAIR.fullmatch(digits) is None:
            raise RefusedError(Refusal.MALFORMED, "no two hex digits after the '*'", raw=raw)
        body = text[1:star]
    if SENTENCE_START_BYTE in body or CHECKSUM_DELIMITER in body:
        raise RefusedError(Refusal.MALFORMED, "reserved character '$' or '*' inside the sentence",
                           raw=raw)
    if star >= 0 and int(text[star + 1:], 16) != checksum(body):
        raise ChecksumError(f"checksum {text[star + 1:].decode()} != {checksum(body):02X}",
                            raw=raw)
    return body.decode("ascii")


def decode_sentence(raw: bytes, *, accept_missing_checksum: bool = False) -> NmeaMessage:
    """Decode one sentence (`$...*hh`, line end optional). Raises `RefusedError` (a DecodeError)
    naming the reason, or its subclass ChecksumError when only the checksum is wrong. A
    sentence without checksum is refused unless `accept_missing_checksum`."""
    tokens = _verified_body(raw, accept_missing_checksum).split(FIELD_SEPARATOR)
    address = tokens[0]
    if _ADDRESS.fullmatch(address) is None:
        raise RefusedError(Refusal.MALFORMED, f"not a sentence address: {address!r}", raw=raw)
    try:
        if address.startswith(PROPRIETARY_PREFIX):
            for count in range(1, _MAX_HEADER_TOKENS + 1):
                spec = _PROPRIETARY.get(tuple(tokens[:count]))
                if spec is not None:
                    message: NmeaMessage = decode_fields(spec, tokens[count:], "")
                    return message
        else:
            talker, formatter = address[:TALKER_CHARS], address[TALKER_CHARS:]
            spec = _STANDARD.get(formatter)
            if spec is not None and _TALKER.fullmatch(talker) is not None:
                message = decode_fields(spec, tokens[1:], talker)
                return message
    except RefusedError as err:
        raise RefusedError(err.reason, str(err), kind=err.kind, raw=raw) from err
    return UnknownSentence(address, tuple(tokens[1:]))


_CHECKED_SENTENCE = re.compile(rb"\$([\x20-\x23\x25-\x7e]{1,%d}?)\*([0-9A-Fa-f]{2})\r?\n"
                               % (MAX_SENTENCE_BYTES - 6))


def first_checked_sentence(data: bytes) -> int:
    """Where in `data` the first whole sentence whose `*hh` checksum holds begins, or -1 (any
    sentence, known to the decoder or not): how a port proves it is a receiver speaking
    NMEA before anything of it is recorded."""
    for match in _CHECKED_SENTENCE.finditer(data):
        if checksum(match[1]) == int(match[2], 16):
            return match.start()
    return -1
