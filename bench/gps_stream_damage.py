"""A long NMEA + UBX stream with damaged messages, fed in random pieces: how many good messages
the decoder loses (it must lose none), and how many errors it counts against how many messages
were damaged.

    .venv/bin/python bench/gps_stream_damage.py                    # 20 000 messages, 5 % damaged
    .venv/bin/python bench/gps_stream_damage.py --messages 100000 --damaged 0.2 --seed 3

Good messages are the sentences of tests/acquisition/corpus/nmea_0183.txt and UBX-TIM-TP /
UBX-TIM-TM2 frames of random instants, half and half; a damaged one has a byte of its body
changed (its checksum then fails) or is cut short. Exit status 1 if a good message is lost,
more errors are counted than messages damaged, or a byte is unaccounted for.
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.ubx import (  # noqa: E402
    NmeaUbxStreamDecoder,
    encode_ubx,
    tim_tm2_from_gps_ns,
    tim_tp_for_pulse,
)
from sisa.core.timescale import NS_PER_S, parse_gps_datetime  # noqa: E402
from tests.acquisition.corpus.nmea_0183 import CORPUS  # noqa: E402

T0 = parse_gps_datetime("2026-06-15T09:00:00")


def _good(rng: random.Random, sentences: list[bytes]) -> bytes:
    if rng.random() < 0.5:
        return rng.choice(sentences)
    t = T0 + rng.randrange(10**6) * NS_PER_S + rng.randrange(NS_PER_S)
    if rng.random() < 0.5:
        return encode_ubx(tim_tp_for_pulse(t // NS_PER_S * NS_PER_S))
    return encode_ubx(tim_tm2_from_gps_ns(t, rng.randrange(65536), 20))


def _damage(rng: random.Random, raw: bytes) -> bytes:
    nmea = raw[:1] == b"$"
    body_end = raw.index(b"*") if nmea else len(raw) - 2
    at = rng.randrange(1 if nmea else 6, body_end)
    if rng.random() < 0.5:
        return raw[:at]
    choices = [b for b in range(0x20, 0x7F) if b not in b"$*"] if nmea else list(range(256))
    return raw[:at] + bytes([rng.choice([b for b in choices if b != raw[at]])]) + raw[at + 1:]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--messages", type=int, default=20_000)
    parser.add_argument("--damaged", type=float, default=0.05, help="share damaged")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    sentences = CORPUS.read_bytes().splitlines(keepends=True)
    pieces, good, damaged = [], [], 0
    for _ in range(args.messages):
        raw = _good(rng, sentences)
        if rng.random() < args.damaged:
            pieces.append(_damage(rng, raw))
            damaged += 1
        else:
            pieces.append(raw)
            good.append(raw)
    pieces.append(sentences[0])
    good.append(sentences[0])
    stream = b"".join(pieces)
    decoder = NmeaUbxStreamDecoder()
    started = time.process_time()
    out, at = [], 0
    while at < len(stream):
        size = rng.randint(1, 512)
        out += decoder.feed(stream[at:at + size])
        at += size
    out += decoder.finish()
    seconds = time.process_time() - started
    got = [d.raw for d in out]
    lost = len(good) - len(got) if got == good[:len(got)] else -1
    accounted = sum(map(len, got)) + decoder.stats.bytes_skipped == len(stream)
    print(f"{args.messages} messages ({len(stream) / 1e6:.2f} MB), {damaged} damaged, "
          f"fed in pieces of 1–512 bytes: {len(got)} decoded in {seconds:.2f} s of CPU "
          f"({len(stream) / 1e6 / seconds:.1f} MB/s)")
    print(f"good messages lost: {lost if lost >= 0 else 'ORDER DIFFERS'}; errors counted "
          f"{decoder.stats.errors} for {damaged} damaged messages "
          f"({decoder.stats.errors / max(damaged, 1):.1%}); every byte accounted for: "
          f"{'yes' if accounted else 'NO'}")
    print("refused by reason: " + ", ".join(f"{r} {n}" for r, n in
                                            sorted(decoder.stats.refused.items())))
    failed = lost != 0 or decoder.stats.errors > damaged or not accounted
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
