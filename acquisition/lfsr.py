"""The sync unit's pseudorandom gate: a maximal-length Fibonacci linear feedback shift register.

Why a maximal-length register: its output (an m-sequence) has period 2^n − 1 and every window of n
consecutive output bits occurs exactly once per period, so the pattern of forwarded PPS found in
the INS records pins each pulse to one GPS second within a block of 2^n − 1 s (seed §3.5.2: 15 s
with n = 4).

Convention. The state is an int whose bit k − 1 holds stage k (k = 1..n). One step:
- the output bit is stage n (the bit shifted out);
- the feedback bit is the XOR of the tapped stages;
- the state shifts towards stage n and the feedback bit enters stage 1.
So the output sequence obeys a(t) = XOR over taps k of a(t − k). Taps (4, 3) are written as the
polynomial x^4 + x^3 + 1 (tap k ↔ x^k, plus the constant 1); the register is maximal exactly when
that polynomial is primitive over GF(2).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Final

from sisa.core.errors import ConfigError

MIN_BITS: Final = 2
MAX_BITS: Final = 32

# Primitive feedback polynomials, one per length (a standard table; each entry is checked by the
# tests both algebraically and by brute-force period).
MAXIMAL_TAPS: Final = MappingProxyType({
    2: (2, 1),
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 11, 10, 4),
    13: (13, 12, 11, 8),
    14: (14, 13, 12, 2),
    15: (15, 14),
    16: (16, 15, 13, 4),
})


def default_taps(bits: int) -> tuple[int, ...]:
    """The table's maximal-length taps for a register of `bits` stages."""
    try:
        return MAXIMAL_TAPS[bits]
    except KeyError:
        raise ConfigError(f"no default LFSR taps for {bits} bits (table covers "
                          f"{min(MAXIMAL_TAPS)}..{max(MAXIMAL_TAPS)})") from None


def check_taps(bits: int, taps: Iterable[int]) -> tuple[int, ...]:
    """Taps as a sorted tuple (largest first); ConfigError unless they make an n-stage register."""
    if not MIN_BITS <= bits <= MAX_BITS:
        raise ConfigError(f"LFSR length {bits} outside {MIN_BITS}..{MAX_BITS}")
    out = tuple(sorted(set(taps), reverse=True))
    if not out or out[0] != bits or out[-1] < 1:
        raise ConfigError(f"LFSR taps {out} must lie in 1..{bits} and include {bits}")
    return out


# --- GF(2) polynomials as ints (bit k = coefficient of x^k) -----------------------------------


def _mulmod(a: int, b: int, mod: int) -> int:
    degree = mod.bit_length() - 1
    out = 0
    while b:
        if b & 1:
            out ^= a
        b >>= 1
        a <<= 1
        if a >> degree & 1:
            a ^= mod
    return out


def _powmod_x(exponent: int, mod: int) -> int:
    """x^exponent modulo `mod`."""
    result, base = 1, 0b10
    while exponent:
        if exponent & 1:
            result = _mulmod(result, base, mod)
        base = _mulmod(base, base, mod)
        exponent >>= 1
    return result


def _prime_factors(n: int) -> list[int]:
    factors, p = [], 2
    while p * p <= n:
        if n % p == 0:
            factors.append(p)
            while n % p == 0:
                n //= p
        p += 1
    if n > 1:
        factors.append(n)
    return factors


def feedback_polynomial(bits: int, taps: Iterable[int]) -> int:
    """1 + Σ x^tap as an int (bit k = coefficient of x^k)."""
    poly = 1
    for tap in check_taps(bits, taps):
        poly ^= 1 << tap
    return poly


def is_maximal(bits: int, taps: Iterable[int]) -> bool:
    """True if the register has period 2^bits − 1, i.e. its polynomial is primitive.

    Algebraic test (no stepping): x has multiplicative order exactly 2^n − 1 modulo the
    polynomial; that forces the quotient ring to be a field, so the polynomial is primitive.
    """
    poly = feedback_polynomial(bits, taps)
    order = (1 << bits) - 1
    if _powmod_x(order, poly) != 1:
        return False
    return all(_powmod_x(order // q, poly) != 1 for q in _prime_factors(order))


# --- the register ------------------------------------------------------------------------------


@dataclass
class Lfsr:
    """A Fibonacci LFSR; `step()` advances it once and returns the output bit."""

    bits: int
    taps: tuple[int, ...]
    state: int = 1
    _mask: int = field(init=False, repr=False)
    _tap_mask: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.taps = check_taps(self.bits, self.taps)
        self._mask = (1 << self.bits) - 1
        self._tap_mask = sum(1 << (t - 1) for t in self.taps)
        if not 0 < self.state <= self._mask:
            raise ConfigError(f"LFSR state {self.state} must be in 1..{self._mask} "
                              "(the all-zero state never leaves itself)")

    @classmethod
    def maximal(cls, bits: int, state: int = 1) -> Lfsr:
        """A register with the table's taps for this length."""
        return cls(bits, default_taps(bits), state)

    def step(self) -> int:
        """Output bit (stage n), then shift in the feedback bit."""
        out = self.state >> (self.bits - 1) & 1
        feedback = (self.state & self._tap_mask).bit_count() & 1
        self.state = (self.state << 1 | feedback) & self._mask
        return out

    def sequence(self, n: int) -> list[int]:
        """The next n output bits, without advancing this register."""
        twin = Lfsr(self.bits, self.taps, self.state)
        return [twin.step() for _ in range(n)]

    def period(self) -> int:
        """Steps until the state comes back (2^n − 1 when maximal); by stepping a copy."""
        twin = Lfsr(self.bits, self.taps, self.state)
        twin.step()
        steps = 1
        while twin.state != self.state:
            twin.step()
            steps += 1
        return steps
