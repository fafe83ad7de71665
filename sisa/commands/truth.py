"""`sisa truth`: the ground truth of a scenario, written as files other tools open.

RUN/
  scenario.toml           the resolved scenario
  truth/trajectory.csv    true INS-centre trajectory every 0.1 s (GPS ns, geodetic, NED, attitude)
  truth/strips.csv        when each strip is flown
  truth/phases.csv        static, take-off, climb, figure-eight, turns, strips
  terrain/dem.tif         ellipsoidal-height DEM (GeoTIFF, UTM)
  terrain/scene.tif       scene texture, band mean (GeoTIFF)
  terrain/scene.png       scene quicklook
  terrain/ground_points.csv  control and check points
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from sisa.commands import add_command, add_force_arg, add_scenario_args, scenario_from_args
from sisa.commands.progress import progress
from sisa.core.outdir import staged_output_dir

if TYPE_CHECKING:
    from emulators.trajectory import TruthTrajectory


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = add_command(sub, "truth", "write a scenario's ground truth: trajectory, DEM, scene "
                         "and ground points", "sisa truth --preset bench --out runs/bench-truth")
    add_scenario_args(parser)
    parser.add_argument("--out", type=Path, required=True, help="new folder to create")
    add_force_arg(parser)
    parser.set_defaults(handler=_run)


def write_timeline_csvs(traj: TruthTrajectory, folder: Path) -> None:
    """Strip windows and flight phases as small CSV tables."""
    with (folder / "strips.csv").open("w", encoding="utf-8") as fh:
        fh.write("# strips as flown; times are GPS ns\n")
        fh.write("index,kind,heading_deg,t_start_gps_ns,t_end_gps_ns\n")
        for s in traj.strips:
            fh.write(f"{s.index},{s.kind.value},{s.heading_deg:.6f},{s.t_start_ns},{s.t_end_ns}\n")
    with (folder / "phases.csv").open("w", encoding="utf-8") as fh:
        fh.write("# flight phases; times are GPS ns\nname,t_start_gps_ns,t_end_gps_ns\n")
        for p in traj.phases:
            fh.write(f"{p.name},{p.t_start_ns},{p.t_end_ns}\n")


def _run(args: argparse.Namespace) -> int:
    from emulators.terrain import Scene, Terrain, ground_points, write_ground_points_csv
    from emulators.trajectory import TruthTrajectory
    from sisa.commands.scenario import scenario_toml

    scn = scenario_from_args(args)
    started = time.perf_counter()
    with staged_output_dir(args.out, force=args.force) as run, progress("truth") as bar:
        (run / "scenario.toml").write_text(scenario_toml(scn), encoding="utf-8")
        truth, terrain_dir = run / "truth", run / "terrain"
        truth.mkdir()
        terrain_dir.mkdir()
        bar.step("trajectory")
        traj = TruthTrajectory.from_scenario(scn)
        traj.write_csv(truth / "trajectory.csv")
        write_timeline_csvs(traj, truth)
        bar.step("terrain and DEM")
        terrain = Terrain.from_scenario(scn)
        terrain.write_dem(terrain_dir / "dem.tif")
        points = ground_points(scn, terrain)
        write_ground_points_csv(terrain_dir / "ground_points.csv", points, utm_epsg=terrain.epsg)
        bar.step("scene")
        scene = Scene.from_scenario(scn, terrain, points)
        scene.write_scene_geotiff(terrain_dir / "scene.tif")
        scene.write_scene_quicklook(terrain_dir / "scene.png")
    print(f"{args.out}: {scn.block.name}, {len(traj.strips)} strips, flight "
          f"{traj.duration_s / 60:.1f} min, DEM {terrain.heights.shape[1]}x"
          f"{terrain.heights.shape[0]} cells, {len(points)} ground points "
          f"({time.perf_counter() - started:.1f} s)")
    return 0
