"""Scenario model: presets, validation messages and the seed's figures."""

import itertools

import pytest

from emulators.block import block_extent_en_m, block_figures, strip_lines
from emulators.scenario import PRESETS, FaultProfile, load_scenario, scenario_from_table
from sisa.core.errors import ConfigError


@pytest.mark.parametrize("name", PRESETS)
def test_presets_load(name):
    scn = load_scenario(name)
    assert scn.block.name == name
    assert scn.faults.empty


def test_garrotxa_reproduces_table_1():
    scn = load_scenario("garrotxa")
    fig = block_figures(scn)
    assert abs(fig.gsd_across_nadir_m / 3.5 - 1) < 0.10
    assert abs(fig.line_spacing_along_m / 3.5 - 1) < 0.10
    assert fig.strip_spacing_m == pytest.approx(fig.swath_width_m * 0.5)
    assert len(strip_lines(scn)) == 14
    headings = [s.heading_deg for s in strip_lines(scn)]
    assert headings[:4] == [180.0, 0.0, 180.0, 0.0]  # alternately N→S and S→N
    assert scn.flight.static_alignment_s == 600.0
    assert fig.forwarded_event_rate_hz <= scn.gps.max_event_rate_hz


def test_bellmunt_reports_the_square_and_the_non_square_pixel():
    scn = load_scenario("bellmunt")
    fig = block_figures(scn)
    assert abs(fig.gsd_across_nadir_m / 1.0 - 1) < 0.10
    assert fig.line_spacing_along_m == pytest.approx(426 / 3.6 * 0.016)  # 1.89 m, not 1 m
    kinds = [s.kind.value for s in strip_lines(scn)]
    assert kinds.count("main") == 5
    assert kinds.count("transversal") == 2


def test_strips_are_evenly_spaced_and_inside_the_extent():
    scn = load_scenario("garrotxa")
    lines = strip_lines(scn)
    xs = sorted(s.start_en_m[0] for s in lines)
    gaps = {round(b - a, 6) for a, b in itertools.pairwise(xs)}
    assert len(gaps) == 1
    e0, n0, e1, n1 = block_extent_en_m(scn)
    for s in lines:
        for e, n in (s.start_en_m, s.end_en_m):
            assert e0 < e < e1
            assert n0 <= n <= n1


def test_base_preset_with_overrides():
    scn = scenario_from_table({"base": "garrotxa", "block": {"strips": 3}})
    assert scn.block.strips == 3
    assert scn.block.flying_height_agl_m == 2160.0


def test_one_of_n_keeps_the_forwarded_rate_below_the_receiver_limit():
    for period_ms in (5.0, 16.0, 48.0, 50.0, 100.0, 1000.0, 2000.0):
        scn = scenario_from_table({"scanner": {"line_period_ms": period_ms,
                                               "integration_time_ms": 1.0}})
        fig = block_figures(scn)
        assert fig.forwarded_event_rate_hz * (1 + 1e-4) < scn.gps.max_event_rate_hz


@pytest.mark.parametrize(
    ("table", "expected"),
    [
        ({"block": {"ground_speed_kmh": -10}},
         "block.ground_speed_kmh: Input should be greater than 0"),
        ({"block": {"side_overlap_pct": 100}},
         "block.side_overlap_pct: Input should be less than 100"),
        ({"block": {"wingspan": 3}}, "unknown field 'block.wingspan'"),
        ({"colour": "red"}, "unknown field 'colour'"),
        ({"scanner": {"integration_time_ms": 60, "line_period_ms": 48}},
         "integration_time_ms = 60.0 must be ≤ line_period_ms"),
        ({"sisa": {"lfsr_bits": 4, "lfsr_taps": [5]}}, "lfsr_taps must lie in 1..lfsr_bits"),
        ({"block": {"start_gps": "tomorrow"}}, "start_gps"),
        ({"base": "atlantis"}, "unknown preset 'atlantis'"),
    ],
)
def test_invalid_values_give_one_line_naming_the_field(table, expected):
    with pytest.raises(ConfigError) as err:
        scenario_from_table(table, source="s.toml")
    text = str(err.value)
    assert expected in text
    assert text.startswith("s.toml")
    assert "\n" not in text


def test_faults_default_empty_and_timed_faults_parse():
    assert FaultProfile().empty
    scn = scenario_from_table({"faults": {"pps_outages": [{"at_s": 100, "duration_s": 60}]}})
    assert scn.faults.pps_outages[0].duration_s == 60
    assert not scn.faults.empty


def test_missing_or_broken_files(tmp_path):
    with pytest.raises(ConfigError, match="no preset or scenario file"):
        load_scenario(tmp_path / "nope.toml")
    with pytest.raises(ConfigError,
                       match=r"\(presets: bench, garrotxa, bellmunt, bench_camera\)$"):
        load_scenario("nope")  # the presets named as a user types them
    bad = tmp_path / "bad.toml"
    bad.write_text("[block\nstrips = 2")
    with pytest.raises(ConfigError, match="not a readable TOML file"):
        load_scenario(bad)
