"""``semmap segment``: run a backend over a bag's camera topic or an image folder.

Writes into the output folder (atomically, as every semmap output)::

    labels/<name>.png      uint16 label images (value k = classes.json names[k-1], 0 = none)
    overlays/<name>.jpg    the image with the masks drawn over it and a legend
    classes.json           {"names": [...], "backend": ..., "model": ...}
    summary.json           images, speed, pixel share per class, the effective configuration

``<name>`` is the image's stamp in nanoseconds for bag images, the file stem for image
files. The labels folder is what the ``folder`` backend reads back
(``segmentation: {backend: folder, folder: OUT/labels}``).

The command has no mapping stage, so decoding and inference run in the calling process.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..config import SegmentationConfig
from ..errors import BagError, ConfigError, SemmapError
from ..io.topics import Kind
from ..palette import class_color
from ..records import Image, Segmentation
from .base import backend_consumes, create_segmenter

if TYPE_CHECKING:
    from ..io.bag import OpenBag

__all__ = ["SegmentResult", "draw_overlay", "iter_image_folder", "segment_source"]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")

ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class SegmentResult:
    """What :func:`segment_source` wrote."""

    out: Path
    images: int
    bad_images: int
    seconds: float  # time in the backend's segment calls
    names: tuple[str, ...]
    pixel_share: dict[str, float]  # share of all labelled pixels per class

    @property
    def fps(self) -> float:
        return self.images / self.seconds if self.seconds else 0.0


_IMAGES: tuple[Kind, ...] = ("image",)


def iter_image_folder(folder: Path) -> Iterator[tuple[str, Image]]:
    """(stem, image) of every image file in a folder, sorted by name; stamps as the ``folder``
    backend reads them (all-digit stems are nanoseconds, else the index in sorted order)."""
    files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise ConfigError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    digits = all(p.stem.isdigit() for p in files)
    for i, p in enumerate(files):
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            log.warning("%s: cannot read the image; skipped", p)
            continue
        yield p.stem, Image(int(p.stem) if digits else i, p.stem, np.ascontiguousarray(bgr[:, :, ::-1]), "rgb8")


class _Skipped:
    """Images the segmenter refused: the first few are logged, the rest counted by reason (the
    reason with its numbers taken out, so 'no label image for stamp N' counts as one)."""

    SHOWN = 3

    def __init__(self) -> None:
        self.count = 0
        self.reasons: dict[str, int] = {}
        self.first = ""

    def add(self, name: str, exc: Exception) -> None:
        self.count += 1
        reason = re.sub(r"(?<![\w/.-])\d+(?![\w/.-])", "N", str(exc))  # numbers, not paths
        self.reasons[reason] = self.reasons.get(reason, 0) + 1
        self.first = self.first or str(exc)
        (log.warning if self.count <= self.SHOWN else log.debug)("%s: skipped: %s", name, exc)

    def report(self) -> None:
        if self.count > self.SHOWN:
            log.warning("%d images skipped in all: %s", self.count,
                        "; ".join(f"{v} x {k}" for k, v in sorted(self.reasons.items(), key=lambda kv: -kv[1])))


def _pick_topic(src: OpenBag, source: Path, wanted: str | None, consumes: str) -> str:
    """The camera (or label image) topic, picked as ``semmap build`` picks it (``--topic`` names one)."""
    from ..config import TopicsConfig
    from ..io.topics import pick_topics
    from ..io.tour import read_tour_manifest

    manifest = read_tour_manifest(source)[2]
    settings = TopicsConfig.model_validate({"labels" if consumes == "labels" else "image": wanted})
    topics = pick_topics(src.types, settings, src.path, consumes, manifest, kinds=_IMAGES, required=_IMAGES,
                         options={"image": "--topic", "labels": "--topic"})
    assert topics.image is not None  # required
    return topics.image


def _iter_bag(src: OpenBag, topic: str, stats: dict[str, int]) -> Iterator[tuple[str, Image]]:
    def skipped(topic: str, exc: SemmapError) -> None:  # an image that cannot be decoded is skipped and counted
        stats["bad_images"] += 1
        log.debug("skipped a frame on %s: %s", topic, exc)

    for _, _, img in src.records([topic], skip=skipped):
        yield str(img.stamp_ns), img


def draw_overlay(image: Image, seg: Segmentation, alpha: float = 0.5) -> NDArray[np.uint8]:
    """The image (RGB) with each class's pixels tinted in its colour, outlined, and a legend."""
    if image.encoding == "rgb8":
        base = image.data.astype(np.float32)
    else:
        g = image.data.astype(np.float32)
        g = g * (255.0 / max(float(g.max()), 1.0))
        base = np.repeat(g[:, :, None], 3, axis=2)
    lut = np.zeros((len(seg.names) + 1, 3), np.float32)
    for k, n in enumerate(seg.names, start=1):
        lut[k] = class_color(n)
    lab = seg.label
    on = lab > 0
    mixed = base.copy()
    mixed[on] = (1 - alpha) * base[on] + alpha * lut[lab[on]]
    out = mixed.clip(0, 255).astype(np.uint8)
    edges = cv2.morphologyEx(lab, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    out[edges & on] = lut[lab[edges & on]].astype(np.uint8)
    present = [int(v) for v in np.unique(lab) if v > 0]
    y = 8
    scale = max(0.4, min(out.shape[:2]) / 900)
    for v in present:
        name = seg.names[v - 1]
        share = np.count_nonzero(lab == v) / lab.size
        text = f"{name} {100 * share:.0f}%"
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        cv2.rectangle(out, (6, y), (6 + th + 8 + tw + 6, y + th + 8), (255, 255, 255), -1)
        cv2.rectangle(out, (9, y + 3), (9 + th, y + 3 + th), tuple(int(c) for c in lut[v]), -1)
        cv2.putText(out, text, (9 + th + 6, y + th + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1,
                    cv2.LINE_AA)
        y += th + 12
    return out


def segment_source(source: str | Path, out: str | Path, config: SegmentationConfig, topic: str | None = None,
                   overlays: bool = True, limit: int | None = None, force: bool = False,
                   progress: ProgressFn | None = None) -> SegmentResult:
    """Segment every image of a bag's camera topic (or of an image folder) into ``out``."""
    src = Path(source)
    if not src.exists():
        raise ConfigError(f"{src}: no such file or directory")
    with contextlib.ExitStack() as stack:  # the bag, opened once
        return _segment_source(src, out, config, topic, overlays, limit, force, progress, stack)


def _segment_source(src: Path, out: str | Path, config: SegmentationConfig, topic: str | None, overlays: bool,
                    limit: int | None, force: bool, progress: ProgressFn | None,
                    stack: contextlib.ExitStack) -> SegmentResult:
    from ..io.atomic import atomic_dir
    from ..io.bag import read_bag, resolve_bag_path

    consumes = backend_consumes(config)
    stats = {"bad_images": 0}
    images: Iterator[tuple[str, Image]]
    total = 0
    try:
        bag = resolve_bag_path(src)
    except BagError:
        bag = None
    if bag is not None:
        opened = stack.enter_context(read_bag(bag))
        tname = _pick_topic(opened, src, topic, consumes)
        images = _iter_bag(opened, tname, stats)
        total = opened.count(tname)
        source_desc = {"bag": str(bag), "topic": tname}
    elif src.is_dir():
        images = iter_image_folder(src)
        total = sum(1 for p in src.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        source_desc = {"folder": str(src)}
    elif src.suffix.lower() in IMAGE_SUFFIXES:
        images = iter_image_folder(src.parent)  # keeps stamps consistent with the whole folder
        images = (f for f in images if f[0] == src.stem)
        total = 1
        source_desc = {"image": str(src)}
    else:
        raise ConfigError(f"{src}: neither a bag, an image folder nor an image file")
    if limit is not None:
        total = min(total, limit)
    seg = create_segmenter(config)
    n, seconds = 0, 0.0
    pixels: dict[int, int] = {}
    skipped = _Skipped()
    try:
        with atomic_dir(out, force, marker="summary.json", inputs=[src], what="segmentation folder") as tmp:
            (tmp / "labels").mkdir()
            if overlays:
                (tmp / "overlays").mkdir()
            for name, image in images:
                if limit is not None and n + skipped.count >= limit:  # images tried, segmented or not
                    break
                t0 = time.perf_counter()
                try:
                    result = seg.segment(image)
                except SemmapError as exc:
                    skipped.add(name, exc)
                    continue
                seconds += time.perf_counter() - t0
                n += 1
                if not cv2.imwrite(str(tmp / "labels" / f"{name}.png"), result.label):
                    raise OSError(0, "cannot write the label image", str(tmp / "labels" / f"{name}.png"))
                if overlays:
                    ov = draw_overlay(image, result)
                    cv2.imwrite(str(tmp / "overlays" / f"{name}.jpg"), ov[:, :, ::-1],
                                [cv2.IMWRITE_JPEG_QUALITY, 90])
                counts = np.bincount(result.label.ravel())
                for v in np.nonzero(counts[1:])[0] + 1:
                    pixels[int(v)] = pixels.get(int(v), 0) + int(counts[v])
                if progress is not None:
                    progress(n, max(total, n))
            skipped.report()
            if n == 0:
                why = f" ({skipped.first})" if skipped.first else ""
                raise SemmapError(f"{src}: no image could be segmented{why}")
            stats["bad_images"] += skipped.count
            names = tuple(seg.names)
            all_px = sum(pixels.values()) or 1
            share = {names[v - 1]: round(c / all_px, 4) for v, c in sorted(pixels.items(), key=lambda kv: -kv[1])}
            meta: dict[str, Any] = {"names": list(names), "backend": config.backend,
                                    "model": str(config.weights) if config.weights else None}
            (tmp / "labels" / "classes.json").write_text(json.dumps(meta, indent=1))
            (tmp / "classes.json").write_text(json.dumps(meta, indent=1))
            summary = {"source": source_desc, "images": n, "bad_images": stats["bad_images"],
                       "skipped_because": skipped.reasons,
                       "segment_s": round(seconds, 3), "fps": round(n / seconds, 2) if seconds else None,
                       "pixel_share": share, "segmentation": config.model_dump(mode="json")}
            (tmp / "summary.json").write_text(json.dumps(summary, indent=1))
    finally:
        seg.close()
    return SegmentResult(Path(out), n, stats["bad_images"], seconds, names, share)
