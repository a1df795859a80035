"""``semmap paint``: the painted scans of a tour, with and without the occlusion filter."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console, progress_bar


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "paint", parents=[common],
        help="export the painted LiDAR points of a tour (with and without the occlusion filter), draw one camera image",
        description="Paint every LiDAR scan of a tour with the camera's segmentation, as semmap build does, "
                    "once without and once with the occlusion filter, and write one row per beam: stamp_ns, "
                    "beam, x, y (LiDAR frame, m), class_raw, mobility_raw (without the filter), class, mobility "
                    "(with it). --picture draws one camera image: the masks, the points without the filter, "
                    "and with it.",
    )
    p.add_argument("tour", type=Path, metavar="TOUR",
                   help="a ROS1 .bag, a ROS2 bag folder, or a folder holding one (e.g. from semmap simulate)")
    p.add_argument("--out", type=Path, metavar="FILE.csv|FILE.npz",
                   help="the per-beam table to write; the suffix picks the format")
    p.add_argument("--config", type=Path, metavar="FILE", help="build configuration YAML (topics, frames, paint)")
    p.add_argument("--calibration", type=Path, metavar="FILE",
                   help="calibration file (default: the config's, or calibration.yaml beside the bag)")
    p.add_argument("--picture", type=Path, metavar="PNG",
                   help="also draw one camera image (default: the scan the filter relabelled most points of)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--at", type=int, metavar="STAMP_NS",
                       help="with --picture: the scan with this stamp (the table's stamp_ns), or the nearest")
    which.add_argument("--image", "--frame", dest="image", type=int, metavar="N",
                       help="with --picture: the N-th camera image the scans were painted with (0-based)")
    p.add_argument("--force", action="store_true", help="replace FILE and PNG if they exist")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..errors import ConfigError, OutputExistsError
    from ..paint.export import export_painted, iter_painted
    from ..paint.figure import ImagePicker, draw_picked

    if args.out is None and args.picture is None:
        raise ConfigError("give --out FILE.csv|FILE.npz, --picture PNG, or both")
    if args.picture is None and (args.at is not None or args.image is not None):
        raise ConfigError("--at and --image choose the scan --picture draws; give --picture PNG")
    if args.image is not None and args.image < 0:
        raise ConfigError(f"--image must be 0 or more, got {args.image}")
    if args.picture is not None:
        if args.picture.suffix.lower() != ".png":
            raise ConfigError(f"{args.picture}: the picture is a PNG; name it .png")
        if args.picture.exists() and not args.force:
            raise OutputExistsError(f"{args.picture}: exists (use --force to replace it)")
        if not args.picture.parent.is_dir():
            raise ConfigError(f"{args.picture.parent}: no such folder")
    picker = ImagePicker(args.at, args.image) if args.picture is not None else None

    result = None
    with progress_bar("painting the scans", enabled=not args.quiet) as progress:
        if args.out is not None:
            result = export_painted(args.tour, args.out, config=args.config, calibration=args.calibration,
                                    force=args.force, progress=progress, on_pair=picker)
        else:
            assert picker is not None
            for pair in iter_painted(args.tour, args.config, args.calibration, progress=progress):
                picker.offer(pair)
    pic = None
    if picker is not None:
        pic = draw_picked(picker, args.tour, args.picture, args.config, args.calibration)
    if args.quiet:
        return 0
    out = console()
    out.print(f"[bold]semmap paint[/bold]: {args.tour}")
    if result is not None:
        out.print(f"  table      {result.out} ({result.format}): {result.scans} scans, {result.beams} beams, "
                  f"{result.scans_painted} scans with an image")
        out.print(f"  filter     relabelled {result.relabelled} points unknown "
                  f"(at most {result.relabelled_max_per_scan} in one scan)")
    if pic is not None:
        src = "over the RGB image" if pic.rgb else "over the label masks (no RGB topic)"
        out.print(f"  picture    {pic.out}: scan {pic.scan_stamp_ns}, image {pic.image_stamp_ns}, "
                  f"{pic.points_in_view} points in view, {pic.relabelled} relabelled ({src})")
    return 0
