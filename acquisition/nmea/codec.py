"""One sentence: framing, checksum, encode and decode."""

from __future__ import annotations

import re
from collections.abc import Sequence
from enum import StrEnum
from typing import Any

from acquisition.nmea.sentences import (
    _MAX_HEADER_TOKENS,
    _SPEC_BY_HEADER,
    _SPEC_BY_TYPE,
    NmeaMessage,
    UnknownSentence,
)
from acquisition.nmea.tables import SentenceSpec, _decode_tokens, _encode_tokens
from sisa.errors import DecodeError, EncodeError
from sisa.nmea import checksum

# proprietary sentences ($PASHR,POS) run past 100, so the cap leaves room while still bounding
# what garbage can make the stream decoder hold.
MAX_SENTENCE_BYTES = 128
SENTENCE_START_BYTE = b"$"
SENTENCE_START = SENTENCE_START_BYTE[0]
LINE_FEED = ord("\n")
LINE_END = "\r\n"
CHECKSUM_DELIMITER = "*"
FIELD_SEPARATOR = ","
CHECKSUM_DIGITS = 2
_PRINTABLE_ASCII = re.compile(rb"[\x20-\x7e]*")
_HEX_PAIR = re.compile(rb"[0-9A-Fa-f]{2}")
_ADDRESS = re.compile(r"[A-Z0-9]+")
_LINE_BREAK_BYTES = b"\r\n"


class ChecksumError(DecodeError):
    """The `*hh` checksum does not match the sentence: counted apart from framing errors."""


class ErrorKind(StrEnum):
    """The two error counters of `DecodeStats`."""

    CHECKSUM = "checksum"
    FRAMING = "framing"


# ---------------------------------------------------------------------------------------------
# Sentences: checksum, encode, decode.


def _tokens_of(message: NmeaMessage) -> list[str]:
    if isinstance(message, UnknownSentence):
        return [message.address, *message.fields]
    return _encode_tokens(_SPEC_BY_TYPE[type(message)], message)


def encode(message: NmeaMessage) -> bytes:
    """The complete sentence, `$...*hh` and CRLF."""
    body = FIELD_SEPARATOR.join(_tokens_of(message)).encode("ascii")
    sentence = b"%s%s%s%02X%s" % (SENTENCE_START_BYTE, body, CHECKSUM_DELIMITER.encode(),
                                   checksum(body), LINE_END.encode())
    if len(sentence) > MAX_SENTENCE_BYTES:
        raise EncodeError(f"sentence of {len(sentence)} bytes exceeds {MAX_SENTENCE_BYTES}")
    return sentence


def _verified_body(raw: bytes) -> str:
    """The text between `$` and `*` of a sentence whose framing and checksum are right."""
    text = raw.removesuffix(b"\n").removesuffix(b"\r")
    if not text.startswith(SENTENCE_START_BYTE):
        raise DecodeError("sentence does not start with '$'", raw=raw)
    if _PRINTABLE_ASCII.fullmatch(text) is None:
        raise DecodeError("non-printable or non-ASCII byte in sentence", raw=raw)
    star = text.rfind(CHECKSUM_DELIMITER.encode())
    digits = text[star + 1:]
    if star < 0 or _HEX_PAIR.fullmatch(digits) is None:
        raise DecodeError("no '*hh' checksum at the end of the sentence", raw=raw)
    body = text[1:star]
    if SENTENCE_START_BYTE in body or CHECKSUM_DELIMITER.encode() in body:
        raise DecodeError("reserved character '$' or '*' inside the sentence", raw=raw)
    if int(digits, 16) != checksum(body):
        raise ChecksumError(f"checksum {digits.decode()} != {checksum(body):02X}", raw=raw)
    return body.decode("ascii")


def _find_spec(tokens: Sequence[str]) -> SentenceSpec[Any] | None:
    for count in range(1, _MAX_HEADER_TOKENS + 1):
        spec = _SPEC_BY_HEADER.get(tuple(tokens[:count]))
        if spec is not None:
            return spec
    return None


def decode_sentence(raw: bytes) -> NmeaMessage:
    """Decode one sentence (`$...*hh`, line end optional). Raises DecodeError, or its subclass
    ChecksumError when only the checksum is wrong."""
    tokens = _verified_body(raw).split(FIELD_SEPARATOR)
    spec = _find_spec(tokens)
    if spec is None:
        if _ADDRESS.fullmatch(tokens[0]) is None:
            raise DecodeError(f"not a sentence address: {tokens[0]!r}", raw=raw)
        return UnknownSentence(tokens[0], tuple(tokens[1:]))
    try:
        message: NmeaMessage = _decode_tokens(spec, tokens[len(spec.header):])
    except DecodeError as err:
        raise DecodeError(str(err), raw=raw) from err
    return message

