"""``semmap export``: maps, nav2 filter masks and the object list for a robot, from a saved session."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console


def _crop(v: str) -> float:
    try:
        return float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--crop takes a margin in metres, got {v!r}") from None


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "export", parents=[common],
        help="maps for your robot from a saved session: layers, modes, crop, straighten, nav2 masks",
        description="Export a map folder written by semmap build, without rebuilding: the cleaned map, static "
                    "structure only, the raw occupancy, the semi-static mask and per-class layers, as "
                    "map_server maps (trinary, scale or raw) that ROS1 map_server and nav2 load as semmap "
                    "meant them; optionally resampled, cropped and straightened to the walls; with nav2 "
                    "keepout and speed filter masks, the movable objects as GeoJSON, and a preview picture.",
    )
    p.add_argument("session", type=Path, metavar="SESSION_DIR", help="a map folder written by semmap build")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="export folder to write")
    p.add_argument("--layer", action="append", dest="layers", metavar="NAME",
                   help="cleaned, static, raw, semi_static or class:NAME (e.g. class:chair); repeat for more "
                        "(default: the first four)")
    p.add_argument("--mode", choices=("trinary", "scale", "raw"), default="trinary",
                   help="map_server mode (default trinary; scale keeps probabilities and writes PNG)")
    p.add_argument("--occupied-thresh", type=float, default=0.65, metavar="P",
                   help="occupied_thresh written to each YAML (default 0.65)")
    p.add_argument("--free-thresh", type=float, default=0.196, metavar="P",
                   help="free_thresh written to each YAML (default 0.196: unknown grey 205 stays unknown in nav2)")
    p.add_argument("--negate", action="store_true", help="white is occupied (negate: 1)")
    p.add_argument("--format", choices=("pgm", "png"), default=None,
                   help="image format (default pgm; png in scale mode)")
    p.add_argument("--resolution", type=float, default=None, metavar="M", help="resample to this cell size")
    p.add_argument("--crop", type=_crop, nargs="?", const=0.5, default=None, metavar="MARGIN",
                   help="crop to the observed area plus MARGIN metres (default 0.5)")
    p.add_argument("--straighten", action="store_true",
                   help="turn the map so the walls run along the image axes (the turn is in export.json)")
    p.add_argument("--rotate", type=float, default=None, metavar="DEG",
                   help="turn the map by DEG degrees counter-clockwise instead (e.g. to a building's CAD axes)")
    p.add_argument("--no-masks", action="store_true", help="no nav2 keepout and speed masks")
    p.add_argument("--keepout-margin", type=float, default=0.10, metavar="M",
                   help="grow the keepout zones around movable furniture by M (default 0.10)")
    p.add_argument("--speed-near-furniture", type=int, default=50, metavar="PCT",
                   help="speed limit near movable furniture, per cent of max (0: none; default 50)")
    p.add_argument("--speed-near-people", type=int, default=30, metavar="PCT",
                   help="speed limit where people were seen, per cent of max (0: none; default 30)")
    p.add_argument("--speed-margin", type=float, default=0.5, metavar="M",
                   help="speed zones reach M beyond the furniture and people (default 0.5)")
    p.add_argument("--force", action="store_true", help="replace DIR if it holds an earlier export")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..robotmap import BASE_LAYERS, ExportSettings, MapEncoding, MaskSettings, export

    fmt = args.format or ("png" if args.mode == "scale" else "pgm")
    enc = MapEncoding(mode=args.mode, occupied_thresh=args.occupied_thresh, free_thresh=args.free_thresh,
                      negate=args.negate, image_format=fmt)
    masks = MaskSettings(keepout_margin_m=args.keepout_margin, speed_near_furniture=args.speed_near_furniture,
                         speed_near_people=args.speed_near_people, speed_margin_m=args.speed_margin)
    st = ExportSettings(layers=tuple(args.layers) if args.layers else BASE_LAYERS, encoding=enc,
                        resolution=args.resolution, crop_margin=args.crop, straighten=args.straighten,
                        rotate_deg=args.rotate,
                        masks=not args.no_masks, mask_settings=masks)
    r = export(args.session, args.out, st, force=args.force)
    if not args.quiet:
        out = console()
        g = r.spec
        out.print(f"exported {args.session} -> {args.out}/  ({g.width} x {g.height} cells of {g.resolution:g} m, "
                  f"mode {enc.mode}{', negate' if enc.negate else ''})")
        if abs(float(r.T_export_build[2])) > 0:
            import math

            out.print(f"  turned {math.degrees(float(r.T_export_build[2])):+.2f} deg about the map origin"
                      f"{' (to the walls)' if args.straighten else ''}: T_export_build in export.json")
        for name, c in r.counts.items():
            out.print(f"  {name:<14} " + ", ".join(f"{v} {k}" for k, v in c.items()))
        for w in r.warnings:
            out.print(f"  warning: {w}")
        out.print(f"  wrote      {len(r.files)} files in {r.seconds:.1f} s (preview.png, export.json, "
                  f"costmap_filters.yaml for nav2)")
    return 0
