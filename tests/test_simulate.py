"""`sisa simulate` end to end: the flight log holds what a real flight would, and the sync log
is right against the simulation truth."""

import numpy as np
import pytest

from acquisition.lfsr import Lfsr
from emulators.scenario import scenario_from_table
from emulators.truth import read_truth_csv
from recorder.columns import read_columns
from recorder.messages import SyncForward, SyncModeSwitch, SyncPps, SyncSession, Topic
from recorder.reader import read_messages
from sisa.core.timescale import NS_PER_S
from sisa.wiring.acqconfig import acquisition_config
from sisa.wiring.simulation import simulate


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    scn = scenario_from_table({"base": "bench", "block": {"strip_length_m": 1500.0},
                               "flight": {"static_alignment_s": 40.0}})
    out = tmp_path_factory.mktemp("sim")
    simulate(scn, out, images=False)
    return scn, out


def test_lfsr_pattern_is_the_maximal_length_sequence(run):
    scn, out = run
    pps = [p for p in read_messages(out / "flight.mcap", SyncPps) if p.lfsr_bit >= 0]
    bits = [p.lfsr_bit for p in pps]
    period = 2**scn.sisa.lfsr_bits - 1
    assert len(bits) > 5 * period
    reference = Lfsr.maximal(scn.sisa.lfsr_bits, 1).sequence(period)
    text = "".join(map(str, reference * 2))
    first = "".join(map(str, bits[:period]))
    assert first in text  # one full period of the logged bits is a rotation of the m-sequence
    assert all(bits[i] == bits[i + period] for i in range(len(bits) - period))
    assert sum(bits[:period]) == 2 ** (scn.sisa.lfsr_bits - 1)
    mode1 = [p for p in pps if p.mode == 1]
    assert all(p.forwarded == bool(p.lfsr_bit) for p in mode1)
    assert all(p.gps_second_ns % NS_PER_S == 0 for p in pps if p.gps_second_ns >= 0)


def test_every_forwarded_frame_has_its_counter_and_a_ttt_tag(run):
    _, out = run
    fwd = [f for f in read_messages(out / "flight.mcap", SyncForward) if f.mode == 2]
    frames = read_truth_csv(out / "truth" / "frames.csv")
    events = read_truth_csv(out / "truth" / "events.csv")
    assert len(fwd) > 20
    known = [f for f in fwd if f.frame_counter >= 0]
    assert len(known) == len(fwd)
    assert {f.frame_counter_source for f in fwd} <= {"header", "inferred"}
    ttt = read_columns(out / "flight.mcap", Topic.GPS_TIME_TAG)
    ttt_gps = np.sort(ttt["t_gps_ns"][ttt["kind"] == "TTT"])
    # the frame each forward names was exposed at a time the GPS receiver tagged (±1 µs gate)
    for f in known:
        t_mid = frames["t_mid_gps_ns"][frames["frame_counter"] == f.frame_counter]
        dist = np.min(np.abs(ttt_gps[:, None] - t_mid[None, :]))
        assert dist <= 1_100, f"frame {f.frame_counter} has no TTT tag at its exposure"
    assert int(events["accepted"].sum()) == len(ttt_gps)


def test_mode_switches_only_at_scanner_on_and_off(run):
    _, out = run
    switches = list(read_messages(out / "flight.mcap", SyncModeSwitch))
    sessions = list(read_messages(out / "flight.mcap", SyncSession))
    assert len(sessions) == 1
    assert [(s.from_mode, s.to_mode) for s in switches] == [(1, 2), (2, 1)] * 2
    frames = read_truth_csv(out / "truth" / "frames.csv")
    headers = read_columns(out / "flight.mcap", Topic.SCANNER_HEADER)
    assert len(headers["frame_counter"]) == int((frames["dropped"] == 0).sum())


def test_gps_health_expects_the_sentences_each_sync_mode_brings(run):
    """A TTT comes for every pulse on the receiver's event input: 1 of n frame pulses in mode 2,
    none in mode 1 (by default), so the expected sentence rate follows the mode."""
    scn, out = run
    config = acquisition_config(scn)
    mode1_hz = 2 * scn.gps.nmea_rate_hz + 2  # GGA + RMC per epoch, ZDA and PTT per second
    mode2_hz = mode1_hz + config.line_rate_hz / config.sync.one_of_n
    health = read_columns(out / "flight.mcap", Topic.HEALTH)
    gps = (health["stream"] == "gps") & (health["event"] == "")
    rate, expected = health["rate_hz"][gps][1:], health["expected_hz"][gps][1:]  # 1st: partial
    assert set(np.round(expected, 9)) == {round(mode1_hz, 9), round(mode2_hz, 9)}
    assert abs(rate.sum() - expected.sum()) < 0.02 * expected.sum()
    for mode_hz in (mode1_hz, mode2_hz):
        assert abs(rate[np.isclose(expected, mode_hz)].mean() - mode_hz) < 0.1
