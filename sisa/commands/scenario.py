"""`sisa scenario show|schema`: the resolved scenario with its derived figures, and its schema."""

from __future__ import annotations

import argparse
import json
from typing import Any

import tomli_w

from sisa.commands import add_command, load_scenario_arg


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "scenario", "inspect flight scenarios (presets or TOML files)",
                         "sisa scenario show garrotxa")
    inner = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    show = add_command(inner, "show", "print the resolved scenario (TOML) and its derived figures",
                       "sisa scenario show bellmunt   (or: sisa scenario show my-flight.toml)")
    show.add_argument("scenario", metavar="NAME|FILE",
                      help="preset name (bench, garrotxa, bellmunt, bench_camera) or scenario "
                      "TOML file")
    show.set_defaults(handler=_show)
    schema = add_command(inner, "schema", "print the JSON schema of scenario files",
                         "sisa scenario schema > scenario.schema.json")
    schema.set_defaults(handler=_schema)


def scenario_toml(scn: Any) -> str:
    """The resolved scenario as TOML (None values are left out: they mean 'default')."""
    table = scn.model_dump(mode="json", exclude_none=True)
    return tomli_w.dumps(table)


def derived_figures(scn: Any) -> dict[str, Any]:
    """Planning figures plus the flown timeline (units in the names)."""
    from emulators.block import block_figures
    from emulators.scenario import gps_event_rate_hz, gps_serial_load
    from emulators.trajectory import TruthTrajectory
    from sisa.wiring.simulation import header_transit_ms

    fig = block_figures(scn)
    traj = TruthTrajectory.from_scenario(scn)
    imaging_s = sum((s.t_end_ns - s.t_start_ns) for s in traj.strips) / 1e9
    window_lo_ms, window_hi_ms = scn.sisa.header_window_ms
    transit_ms = header_transit_ms()
    return {
        "gsd_across_nadir_m": round(fig.gsd_across_nadir_m, 3),
        "gsd_across_nadir_true_focal_m": round(fig.gsd_across_nadir_true_m, 3),
        "line_spacing_along_m": round(fig.line_spacing_along_m, 3),
        "fov_deg": round(fig.fov_deg, 2),
        "ifov_arcmin": round(fig.ifov_arcmin, 2),
        "swath_width_m": round(fig.swath_width_m, 1),
        "strip_spacing_m": round(fig.strip_spacing_m, 1),
        "block_width_m": round(fig.block_width_m, 1),
        "block_length_m": round(fig.block_length_m, 1),
        "strip_duration_s": round(fig.strip_duration_s, 1),
        "lines_per_strip": fig.lines_per_strip,
        "line_rate_hz": round(fig.line_rate_hz, 3),
        "one_of_n": fig.one_of_n,
        "forwarded_event_rate_hz": round(fig.forwarded_event_rate_hz, 4),
        "lfsr_period_s": fig.lfsr_period_s,
        "turn_radius_m": round(fig.turn_radius_m, 1),
        "strips_flown": len(traj.strips),
        "imaging_time_s": round(imaging_s, 1),
        "flight_duration_s": round((traj.t_end_ns - traj.t_start_ns) / 1e9, 1),
        "header_window_width_ms": round(window_hi_ms - window_lo_ms, 3),
        # after the frame ends: the scanner's own latency, the header's bytes on the wire, the
        # USB read latency and (at the latest) a whole read interval
        "header_early_by_min_ms": round(scn.scanner.header_latency_ms[0] + transit_ms[0], 3),
        "header_late_by_max_ms": round(scn.scanner.header_latency_ms[1] + transit_ms[1]
                                       + scn.sisa.read_interval_ms, 3),
        "gps_event_rate_hz": round(gps_event_rate_hz(scn), 4),
        "gps_serial_load_pct": round(100.0 * gps_serial_load(scn)[1], 1),
        **camera_figures(scn, fig.forwarded_event_rate_hz),
    }


def camera_figures(scn: Any, frame_events_hz: float) -> dict[str, Any]:
    """A frame camera's share of the receiver's event input (docs/sync.md, "Two sensors, one
    event input"): each pulse finds the input taken about (the other's rate) / (the
    receiver's rate) of the time, and is then timed through the timing board instead."""
    cam = scn.camera
    if cam is None:
        return {}
    rate = scn.gps.max_event_rate_hz
    photo_hz = cam.photo_rate_hz(scn.block.ground_speed_mps)
    lo, hi = cam.message_window_ms(scn.sisa.read_interval_ms)
    return {"camera_photo_rate_hz": round(photo_hz, 4),
            "camera_message_window_ms": [round(lo, 3), round(hi, 3)],
            "event_input_rate_hz": round(frame_events_hz + photo_hz, 4),
            "camera_pulses_tagged_pct": round(100.0 * max(0.0, 1.0 - frame_events_hz / rate), 1),
            "frame_pulses_tagged_pct": round(100.0 * max(0.0, 1.0 - photo_hz / rate), 1)}


def header_window_notes(early_ms: float, late_ms: float, window_ms: tuple[float, float],
                        period_ms: float) -> list[str]:
    """Headers that can reach the recorder outside the header window (ms after their frame
    ends): untied if no other frame's pulse is in the window then; tied to the next (or the
    previous) frame's pulse if it is, and then every counter of the stretch agrees with that
    tie and its lines are timed a line period wrong (docs/sync.md, Limits)."""
    lo, hi = window_ms
    span = (f"a frame header reaches the recorder {early_ms}–{late_ms} ms after its frame ends "
            "(scanner.header_latency_ms, its bytes on the wire, the USB latency, "
            "sisa.read_interval_ms)")
    if late_ms - period_ms >= lo or early_ms + period_ms <= hi:
        if late_ms > hi or early_ms < lo:
            return [f"{span}, outside sisa.header_window_ms {list(window_ms)} by up to a line "
                    f"period ({period_ms} ms): a header can be tied to another frame's pulse, "
                    "and the scan lines of its stretch then timed one line period wrong: set the "
                    "window to cover the latencies"]
        return []
    if late_ms > hi or early_ms < lo:
        return [f"{span}, outside sisa.header_window_ms {list(window_ms)}: such headers are not "
                "tied to their pulses (their frames' counters are inferred from neighbours or "
                "left unknown)"]
    return []


def _notes(scn: Any, derived: dict[str, Any]) -> list[str]:
    from emulators.terrain import ground_point_room_problem

    notes = []
    across, along = derived["gsd_across_nadir_m"], derived["line_spacing_along_m"]
    if abs(along / across - 1.0) > 0.10:
        notes.append(f"pixels are not square: {along} m along track (speed x line period) vs "
                     f"{across} m across track at nadir")
    if derived["gsd_across_nadir_true_focal_m"] != across:
        notes.append("the scanner's true focal length (nominal + delta_focal_mm) gives "
                     f"{derived['gsd_across_nadir_true_focal_m']} m across track")
    period_ms = scn.scanner.line_period_ms
    if derived["header_window_width_ms"] >= 0.95 * period_ms:
        notes.append(f"sisa.header_window_ms is {derived['header_window_width_ms']} ms wide, not "
                     f"narrower than a line period ({period_ms} ms): frame headers cannot be "
                     "tied to their pulses and lines will be flagged, not timed")
    notes += header_window_notes(derived["header_early_by_min_ms"],
                                 derived["header_late_by_max_ms"], scn.sisa.header_window_ms,
                                 period_ms)
    from emulators.scenario import GPS_LINK_WARN_LOAD

    load = derived["gps_serial_load_pct"]
    if load > 100 * GPS_LINK_WARN_LOAD:
        notes.append(f"the receiver's serial port is {load}% loaded (gps.serial_baud = "
                     f"{scn.gps.serial_baud}, {derived['gps_event_rate_hz']} TTT tags a second): "
                     "sentences queue behind each other and reach the recorder late")
    line_rate = derived["line_rate_hz"]
    wanted = line_rate / derived["one_of_n"]
    if wanted > scn.gps.max_event_rate_hz * 1.0001:
        notes.append(f"1 of sisa.one_of_n = {derived['one_of_n']} frame pulses at {line_rate} "
                     f"lines/s is {wanted:.3g} a second, more than gps.max_event_rate_hz = "
                     f"{scn.gps.max_event_rate_hz:g}: the sync unit holds them to "
                     f"{scn.gps.max_event_rate_hz:g} a second (not 1 of n)")
    if derived["gps_event_rate_hz"] > scn.ins.rate_hz / 2:
        notes.append(f"{derived['gps_event_rate_hz']} forwarded pulses a second is more than half "
                     f"the INS record rate ({scn.ins.rate_hz:g} Hz): the INS latches one pulse a "
                     "record and loses the others")
    gate_ns = scn.sisa.pps_gate_us * 1e3
    if 6 * scn.gps.pps_jitter_ns > gate_ns:
        notes.append(f"gps.pps_jitter_ns = {scn.gps.pps_jitter_ns:g} is more than a sixth of "
                     f"sisa.pps_gate_us = {scn.sisa.pps_gate_us:g}: the sync unit may never lock "
                     "on the PPS train (it forwards no PPS unlocked) or refuse true edges: a "
                     "wider gate")
    if "event_input_rate_hz" in derived and (
            derived["event_input_rate_hz"] > scn.gps.max_event_rate_hz):
        notes.append(f"the scanner's {derived['forwarded_event_rate_hz']} and the camera's "
                     f"{derived['camera_photo_rate_hz']} pulses a second are more than the "
                     f"receiver's gps.max_event_rate_hz = {scn.gps.max_event_rate_hz:g}: the "
                     "sync unit's event input is taken for many of them, and those are timed "
                     "through its timing board, not tagged (a faster receiver, or a larger "
                     "sisa.one_of_n)")
    if (problem := ground_point_room_problem(scn)) is not None:
        notes.append(f"{problem} (sisa truth and sisa simulate refuse this scenario)")
    return notes


def _show(args: argparse.Namespace) -> int:
    scn = load_scenario_arg(args.scenario)
    derived = derived_figures(scn)
    print(f"# resolved scenario: {args.scenario}")
    print(scenario_toml(scn))
    print("# derived figures (flat terrain at the mean height; planning uses the nominal focal;"
          " computed from the settings above, not read back: edit the settings)")
    for note in _notes(scn, derived):
        print(f"# note: {note}")
    print(tomli_w.dumps({"derived": derived}), end="")
    return 0


def _schema(args: argparse.Namespace) -> int:
    from emulators.scenario import Scenario

    print(json.dumps(Scenario.model_json_schema(), indent=2))
    return 0
