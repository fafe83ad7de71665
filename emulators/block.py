"""Block geometry derived from the scenario: the figures a flight planner works with, and the
strip lines in a local east-north plane centred on the block.

Planning uses the nominal focal length (what the operator knows); the true focal length
(nominal + δf) is reported beside it because it is what the emulated scanner images with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # annotations only: the scenario's own checks use this module
    from emulators.scenario import Scenario

STANDARD_GRAVITY_MPS2 = 9.80665


class StripKind(StrEnum):
    MAIN = "main"
    TRANSVERSAL = "transversal"


@dataclass(frozen=True)
class StripLine:
    """One strip as flown: start and end in the local plane (east, north metres), true heading."""

    index: int
    kind: StripKind
    start_en_m: tuple[float, float]
    end_en_m: tuple[float, float]
    heading_deg: float

    @property
    def length_m(self) -> float:
        return math.dist(self.start_en_m, self.end_en_m)


@dataclass(frozen=True)
class BlockFigures:
    """Derived planning figures (flat terrain at the mean height, level flight)."""

    gsd_across_nadir_m: float
    gsd_across_nadir_true_m: float
    line_spacing_along_m: float
    fov_deg: float
    ifov_arcmin: float
    swath_width_m: float
    strip_spacing_m: float
    block_width_m: float
    block_length_m: float
    strip_duration_s: float
    lines_per_strip: int
    line_rate_hz: float
    one_of_n: int
    forwarded_event_rate_hz: float
    lfsr_period_s: int
    turn_radius_m: float


def resolve_one_of_n(scn: Scenario) -> int:
    """n for mode 2: the configured one, or the smallest n whose forwarded rate stays ≥ 1 %
    below the receiver's maximum event rate (the scanner clock drifts)."""
    if scn.sisa.one_of_n != "auto":
        return scn.sisa.one_of_n
    line_rate_hz = 1000.0 / scn.scanner.line_period_ms
    return max(1, math.ceil(line_rate_hz * 1.01 / scn.gps.max_event_rate_hz))


def block_figures(scn: Scenario) -> BlockFigures:
    sc, blk = scn.scanner, scn.block
    gsd = blk.flying_height_agl_m * sc.pixel_pitch_um * 1e-3 / sc.focal_length_mm
    gsd_true = (blk.flying_height_agl_m * sc.pixel_pitch_um * 1e-3
                / (sc.focal_length_mm + sc.delta_focal_mm))
    swath = sc.pixels * gsd
    spacing = swath * (1.0 - blk.side_overlap_pct / 100.0)
    speed = blk.ground_speed_mps
    line_rate = 1000.0 / sc.line_period_ms
    n = resolve_one_of_n(scn)
    bank = math.radians(scn.flight.turn_bank_deg)
    return BlockFigures(
        gsd_across_nadir_m=gsd,
        gsd_across_nadir_true_m=gsd_true,
        line_spacing_along_m=speed * sc.line_period_ms / 1000.0,
        fov_deg=sc.fov_deg,
        ifov_arcmin=math.degrees(sc.ifov_rad) * 60.0,
        swath_width_m=swath,
        strip_spacing_m=spacing,
        block_width_m=(blk.strips - 1) * spacing + swath,
        block_length_m=blk.strip_length_m,
        strip_duration_s=blk.strip_length_m / speed,
        lines_per_strip=math.ceil(blk.strip_length_m / speed * line_rate),
        line_rate_hz=line_rate,
        one_of_n=n,
        forwarded_event_rate_hz=line_rate / n,
        lfsr_period_s=2**scn.sisa.lfsr_bits - 1,
        turn_radius_m=speed**2 / (STANDARD_GRAVITY_MPS2 * math.tan(bank)),
    )


def _unit(heading_deg: float) -> tuple[float, float]:
    h = math.radians(heading_deg)
    return math.sin(h), math.cos(h)


def strip_lines(scn: Scenario) -> tuple[StripLine, ...]:
    """Strips in flying order: main strips across the block (right-hand edge first, seen along
    the first heading), then transversal strips along it; directions alternate if configured."""
    blk, fig = scn.block, block_figures(scn)
    along = _unit(blk.first_strip_heading_deg)
    across = (along[1], -along[0])  # to the right of the first heading
    strips: list[StripLine] = []

    def add(kind: StripKind, centre_off: float, axis: tuple[float, float],
            normal: tuple[float, float], half_len: float, heading: float, flip: bool) -> None:
        mid = (normal[0] * centre_off, normal[1] * centre_off)
        a = (mid[0] - axis[0] * half_len, mid[1] - axis[1] * half_len)
        b = (mid[0] + axis[0] * half_len, mid[1] + axis[1] * half_len)
        if flip:
            a, b, heading = b, a, (heading + 180.0) % 360.0
        strips.append(StripLine(len(strips), kind, a, b, heading))

    n = blk.strips
    for i in range(n):
        offset = ((n - 1) / 2.0 - i) * fig.strip_spacing_m  # right-hand edge first
        add(StripKind.MAIN, offset, along, across, blk.strip_length_m / 2.0,
            blk.first_strip_heading_deg, blk.alternate_directions and i % 2 == 1)
    m = blk.transversal_strips
    t_heading = (blk.first_strip_heading_deg + 90.0) % 360.0
    t_axis = _unit(t_heading)
    for k in range(m):
        offset = ((k + 1) / (m + 1) - 0.5) * blk.strip_length_m
        add(StripKind.TRANSVERSAL, offset, t_axis, along, fig.block_width_m / 2.0, t_heading,
            blk.alternate_directions and (n + k) % 2 == 1)
    return tuple(strips)


def block_extent_en_m(scn: Scenario) -> tuple[float, float, float, float]:
    """(east_min, north_min, east_max, north_max) of every strip's swath, in the local plane."""
    half_swath = block_figures(scn).swath_width_m / 2.0
    es = [p[0] for s in strip_lines(scn) for p in (s.start_en_m, s.end_en_m)]
    ns = [p[1] for s in strip_lines(scn) for p in (s.start_en_m, s.end_en_m)]
    return (min(es) - half_swath, min(ns) - half_swath, max(es) + half_swath, max(ns) + half_swath)
