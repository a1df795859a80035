"""``semmap segment``: label images and overlays of a bag's camera topic or an image folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console, progress_bar
from ._segopts import add_segmentation_options, segmentation_config


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "segment", parents=[common],
        help="segment a bag's camera images or an image folder: label PNGs plus overlays",
        description="Run a segmentation backend over every image of a bag's camera topic (or of an "
                    "image folder) and write uint16 label PNGs, overlays, classes.json and summary.json. "
                    "The labels folder can be fed back with the 'folder' backend.",
    )
    p.add_argument("source", type=Path, metavar="SOURCE", help="a bag, a tour folder, an image folder or an image")
    p.add_argument("--backend", default=None, metavar="BACKEND[:MODEL]",
                   help="onnx:M.onnx, ultralytics:M.pt, sam3:FOLDER, mediapipe-selfie[:M.tflite], folder, topic "
                        "(default: the config's)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (must not exist)")
    p.add_argument("--force", action="store_true", help="replace DIR if it exists")
    p.add_argument("--topic", metavar="TOPIC", help="the image topic (default: the only camera topic)")
    p.add_argument("--no-overlays", action="store_true", help="write label images only")
    p.add_argument("--limit", type=int, metavar="N", help="segment at most N images")
    add_segmentation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..segment.run import segment_source

    cfg = segmentation_config(args, args.backend)
    with progress_bar(f"segmenting ({cfg.backend})", enabled=not args.quiet) as progress:
        res = segment_source(args.source, args.out, cfg, topic=args.topic, overlays=not args.no_overlays,
                             limit=args.limit, force=args.force, progress=progress)
    if not args.quiet:
        out = console()
        out.print(f"[bold]semmap segment[/bold]: {args.source} → {res.out} ({cfg.backend})")
        out.print(f"  images  {res.images} segmented, {res.bad_images} skipped, {res.fps:.1f} images/s")
        top = ", ".join(f"{k} {100 * v:.0f}%" for k, v in list(res.pixel_share.items())[:6]) or "no objects"
        out.print(f"  classes {top}")
        out.print(f"  labels  {res.out / 'labels'}   overlays {res.out / 'overlays'}")
    return 0
