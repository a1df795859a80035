"""Options shared by ``semmap segment`` and ``semmap eval-seg``: a backend spec and its settings."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def add_segmentation_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("segmentation (override the config's segmentation: section)")
    g.add_argument("--config", type=Path, metavar="FILE",
                   help="a build configuration YAML; its segmentation: section is the starting point")
    g.add_argument("--device", help="cpu (default), or cuda / cuda:N where the runtime has it")
    g.add_argument("--threads", type=int, metavar="N", help="CPU threads the model may use (0: runtime default)")
    g.add_argument("--conf", type=float, metavar="P", help="keep instances scoring at least this (default 0.25)")
    g.add_argument("--iou", type=float, metavar="T", help="NMS IoU threshold (default 0.7)")
    g.add_argument("--mask-threshold", type=float, metavar="P", help="mask probability threshold (default 0.5)")
    g.add_argument("--imgsz", type=int, metavar="PX", help="model input size (long side, px)")
    g.add_argument("--prompts", metavar="A,B,...", help="sam3: comma-separated class prompts "
                                                        "(default: the class list)")
    g.add_argument("--memory-budget", type=float, metavar="MB", help="sam3: activation memory budget, MB")
    g.add_argument("--class-list", metavar="NAME", help="class list of config/classes.yaml (topic, folder, sam3)")
    g.add_argument("--folder", type=Path, metavar="DIR", help="folder backend: the label PNGs")
    g.add_argument("--cache", type=Path, metavar="DIR", help="mask cache folder (reuse earlier results)")


def parse_backend_spec(spec: str) -> dict[str, Any]:
    """``BACKEND`` or ``BACKEND:MODEL`` → config keys (``onnx:models/yolo11n-seg.onnx``)."""
    name, sep, model = spec.partition(":")
    out: dict[str, Any] = {"backend": name}
    if sep:
        out["model"] = model
    return out


def segmentation_overrides(args: argparse.Namespace) -> dict[str, Any]:
    pairs = {"device": args.device, "threads": args.threads, "conf": args.conf, "iou": args.iou,
             "mask_threshold": args.mask_threshold, "imgsz": args.imgsz, "memory_budget_mb": args.memory_budget,
             "class_list": args.class_list, "folder": str(args.folder) if args.folder else None,
             "cache_dir": str(args.cache) if args.cache else None}
    out = {k: v for k, v in pairs.items() if v is not None}
    if args.prompts:
        out["prompts"] = [s.strip() for s in args.prompts.split(",") if s.strip()]
    return out


def segmentation_config(args: argparse.Namespace, spec: str | None) -> Any:
    """The effective SegmentationConfig: config file, then the backend spec, then the options."""
    from ..io.tour import load_build_config

    over = segmentation_overrides(args)
    if spec is not None:
        over.update(parse_backend_spec(spec))
    cfg, _ = load_build_config(args.config, {"segmentation": over})  # paths in the file: relative to it
    return cfg.segmentation
