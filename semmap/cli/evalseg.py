"""``semmap eval-seg``: Table I-style comparison of segmentation backends on a COCO-seg dataset."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._progress import console, progress_bar
from ._segopts import add_segmentation_options, segmentation_config


def add_parser(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = sub.add_parser(
        "eval-seg", parents=[common],
        help="score segmentation backends on a COCO-seg dataset (mIoU, mDice per class, FPS)",
        description="Evaluate one or more backends on a dataset in YOLO polygon format (e.g. "
                    "../shared/data/coco128-seg): IoU and Dice per class and overall, and images per "
                    "second. Prints a table and writes table.md, metrics.csv and chart.png. The protocol "
                    "is in docs/segmentation.md.",
    )
    p.add_argument("dataset", type=Path, metavar="DATASET", help="dataset folder (images/ and labels/)")
    p.add_argument("--backend", action="append", required=True, metavar="BACKEND[:MODEL]",
                   help="a backend to score; repeat to compare several side by side "
                        "(e.g. --backend onnx:yolo11n-seg.onnx --backend mediapipe-selfie)")
    p.add_argument("--out", type=Path, metavar="DIR", help="write table.md, metrics.csv, chart.png here")
    p.add_argument("--limit", type=int, metavar="N", help="use the first N images only")
    p.add_argument("--dataset-classes", default="coco", metavar="NAME",
                   help="class list naming the dataset's class ids (default coco)")
    add_segmentation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..segment.evaluate import evaluate_segmentation, write_eval_outputs

    cfgs = [segmentation_config(args, spec) for spec in args.backend]
    with progress_bar("evaluating", enabled=not args.quiet) as progress:
        res = evaluate_segmentation(args.dataset, cfgs, limit=args.limit, class_list=args.dataset_classes,
                                    progress=progress)
    paths = write_eval_outputs(res, args.out, _machine()) if args.out else {}
    if not args.quiet:
        out = console()
        out.print(f"[bold]semmap eval-seg[/bold]: {res.dataset} ({res.images} images)")
        out.print(res.table())
        for b in res.backends:
            best = sorted(b.classes, key=lambda c: -c.images)[:5]
            out.print(f"  {b.label}: " + ", ".join(f"{c.name} {c.iou:.2f} ({c.images} img)" for c in best))
        for k, v in paths.items():
            out.print(f"  {k:<6} {v}")
    return 0


def _machine() -> str:
    import os
    import platform

    return f"{platform.machine()}, {os.cpu_count()} cores"
