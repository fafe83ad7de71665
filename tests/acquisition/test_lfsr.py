import itertools

import pytest

from acquisition.lfsr import MAXIMAL_TAPS, Lfsr, default_taps, is_maximal
from sisa.core.errors import ConfigError


def _brute_force_states(bits, taps, state=1):
    """Independent register: stage k is list element k−1, shifted by hand; the state visits."""
    stages = [(state >> k) & 1 for k in range(bits)]
    seen, order = {}, []
    while True:
        value = sum(b << k for k, b in enumerate(stages))
        if value in seen:
            return order, seen[value]
        seen[value] = len(order)
        order.append(value)
        feedback = 0
        for t in taps:
            feedback ^= stages[t - 1]
        stages = [feedback, *stages[:-1]]


@pytest.mark.parametrize("bits", sorted(MAXIMAL_TAPS))
def test_table_entry_is_maximal_by_brute_force(bits):
    taps = MAXIMAL_TAPS[bits]
    states, loop_start = _brute_force_states(bits, taps)
    assert loop_start == 0
    assert len(states) == 2**bits - 1
    assert sorted(states) == list(range(1, 2**bits))
    assert is_maximal(bits, taps)
    assert Lfsr(bits, taps).period() == 2**bits - 1


@pytest.mark.parametrize("bits", range(2, 11))
def test_is_maximal_agrees_with_brute_force_for_every_tap_set(bits):
    """Every tap set that contains the top stage, up to 10 bits: the algebraic test equals the
    brute-force period."""
    lower = range(1, bits)
    for r in range(len(lower) + 1):
        for extra in itertools.combinations(lower, r):
            taps = (bits, *extra)
            states, loop_start = _brute_force_states(bits, taps)
            period = len(states) - loop_start
            assert is_maximal(bits, taps) == (period == 2**bits - 1), taps


def test_non_maximal_taps_are_detected():
    assert not is_maximal(4, (4, 2))  # x^4 + x^2 + 1 = (x^2 + x + 1)^2
    assert not is_maximal(4, (4, 3, 2, 1))  # period 5
    assert Lfsr(4, (4, 2)).period() < 15
    assert not is_maximal(8, (8, 1))


def test_register_steps_like_the_brute_force_one():
    states, _ = _brute_force_states(5, (5, 3), state=0b10110)
    reg = Lfsr(5, (5, 3), state=0b10110)
    got = [reg.state]
    for _ in range(len(states) - 1):
        reg.step()
        got.append(reg.state)
    assert got == states


def test_output_of_the_4_bit_register_is_an_m_sequence():
    reg = Lfsr.maximal(4)
    bits = reg.sequence(15)
    assert reg.state == 1  # sequence() does not advance
    assert bits.count(1) == 8
    assert bits.count(0) == 7
    runs = _cyclic_runs(bits)
    # m-sequence run distribution for n = 4: half the runs of length 1, a quarter of length 2,
    # one run of each symbol of length 2, then one run of 4 ones and one of 3 zeros
    assert sorted(runs[1]) == [1, 1, 2, 4]
    assert sorted(runs[0]) == [1, 1, 2, 3]
    # one step per call, output period 15
    assert [reg.step() for _ in range(30)] == bits + bits


def _cyclic_runs(bits):
    start = next(i for i in range(len(bits)) if bits[i] != bits[i - 1])
    rotated = bits[start:] + bits[:start]
    runs = {0: [], 1: []}
    for symbol, group in itertools.groupby(rotated):
        runs[symbol].append(len(list(group)))
    return runs


@pytest.mark.parametrize("bits", [3, 4, 7, 10])
def test_every_window_of_n_bits_names_its_position(bits):
    reg = Lfsr.maximal(bits, state=3)
    period = 2**bits - 1
    out = reg.sequence(period)
    cyclic = out + out[: bits - 1]
    windows = [tuple(cyclic[i:i + bits]) for i in range(period)]
    assert len(set(windows)) == period
    assert (0,) * bits not in windows


def test_any_initial_state_gives_the_same_cycle_shifted():
    ref = Lfsr.maximal(4).sequence(15)
    for state in range(1, 16):
        out = Lfsr.maximal(4, state=state).sequence(15)
        assert any(out == ref[k:] + ref[:k] for k in range(15))


@pytest.mark.parametrize(("bits", "taps", "state"), [
    (4, (3, 1), 1),  # top stage not tapped
    (4, (5, 4), 1),  # tap beyond the register
    (4, (4, 3), 0),  # all-zero state never leaves
    (4, (4, 3), 16),
    (1, (1,), 1),
])
def test_bad_register_is_refused(bits, taps, state):
    with pytest.raises(ConfigError):
        Lfsr(bits, taps, state)


def test_default_taps():
    assert default_taps(4) == (4, 3)
    with pytest.raises(ConfigError):
        default_taps(40)
