"""``semmap build``: a recorded tour → a cleaned semantic map folder."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from ._progress import console, progress_bar


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "build", parents=[common],
        help="build the cleaned semantic map of a recorded tour (the main job)",
        description="Paint every LiDAR scan with the camera's segmentation, register the scans "
                    "(KISS-ICP + wheel odometry), fuse them into a semantic occupancy grid, and write "
                    "the cleaned map folder: map.yaml/map.pgm for map_server, semantic.png, the "
                    "semi-static layer, the full grid, the trajectory and a report.",
    )
    p.add_argument("tour", nargs="?", type=Path, metavar="TOUR",
                   help="a ROS1 .bag, a ROS2 bag folder, or a folder holding one (e.g. from semmap simulate)")
    p.add_argument("--demo", action="store_true", help="simulate the built-in demo tour and build its map")
    p.add_argument("--config", type=Path, metavar="FILE", help="build configuration YAML (topics, frames, ...)")
    p.add_argument("--calibration", type=Path, metavar="FILE",
                   help="calibration file (default: the config's, or calibration.yaml beside the bag)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="map folder to write (must not exist)")
    p.add_argument("--force", action="store_true", help="replace DIR if it exists")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..errors import ConfigError

    if args.demo == (args.tour is not None):
        raise ConfigError("give either a TOUR or --demo")
    if args.demo:
        from ..sim.tour import simulate

        with tempfile.TemporaryDirectory(prefix="semmap-demo-") as tmp:
            with progress_bar("simulating the demo tour", enabled=not args.quiet) as progress:
                tour = simulate("demo", Path(tmp) / "demo", progress=progress)
            result = _build(args, tour.out)
    else:
        result = _build(args, args.tour)
    if not args.quiet:
        _print_summary(result)
    return 0


def _build(args: argparse.Namespace, tour: Path):
    from ..pipeline import build

    with progress_bar("building the map", enabled=not args.quiet) as progress:
        return build(tour, args.out, config=args.config, calibration=args.calibration, force=args.force,
                     progress=progress)


def _print_summary(result) -> None:
    from ..mapfolder.report import camera_line, consistency_line, loops_line, registration_line

    s = result.summary.model_dump(mode="json")
    m, th = s["map"], s["throughput"]
    out = console()
    out.print(f"[bold]semmap build[/bold]: {s['tour']['bag']} → {result.out}")
    occ = s["painting"].get("occlusion_filter") or {}
    hidden = (f", {occ['points_relabelled']} points hidden from the camera made unknown"
              if occ.get("on") and s["painting"]["scans_painted"] else "")
    out.print(f"  scans      {s['counts']['scans']} ({s['painting']['scans_painted']} with an image{hidden})")
    if s["painting"].get("frame_selection"):
        out.print(f"  camera     {camera_line(s)}")
    out.print(f"  poses      {registration_line(s['registration'])}")
    if (loops := loops_line(s["registration"])) is not None:
        out.print(f"  loops      {loops}")
    if s.get("consistency"):
        out.print(f"  agreement  {consistency_line(s['consistency'])}")
    out.print(f"  map        {m['size_m'][0]} m × {m['size_m'][1]} m at {m['resolution']} m: "
              f"{m['occupied_cells']} occupied, {m['semi_static_cells']} semi-static, "
              f"{m['dynamic_cells_removed']} dynamic removed, {m['semi_static_objects']} movable objects")
    out.print(f"  for robots {result.out / 'map.yaml'}")
    out.print(f"  to look at {result.out / 'semantic.png'}, {result.out / 'report.md'}")
    out.print(f"  speed      {th['scans_per_s']} scans/s ({th['real_time_factor']}× real time), "
              f"took {result.elapsed_s:.1f} s")
    if s.get("warnings"):
        out.print(f"  warnings   {len(s['warnings'])}, listed in {result.out / 'report.md'}")
