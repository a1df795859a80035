"""``semmap eval-seg``: segmentation backends scored on a COCO-seg dataset (the research's Table I).

**Dataset.** YOLO polygon format, as Ultralytics ships COCO128-seg: images under
``images/<split>/``, one ``labels/<split>/<stem>.txt`` per image with one object per line,
``class x1 y1 x2 y2 ...`` (normalised to [0, 1]). Class ids follow a named class list
(default ``coco``, the 80 COCO classes in YOLO order). An image without a label file has
no objects.

**Protocol.** For every image and class, the ground-truth mask G is the union of that
class's polygons, rasterised at the image's resolution (OpenCV ``fillPoly``); the predicted
mask P is the pixels the backend labels with that class (matched by name). Then, per class:

* **IoU** = ΣI / ΣU and **Dice** = 2ΣI / (ΣP + ΣG), summing each image's mask intersection
  I = |P ∩ G|, union U = |P ∪ G| and mask sizes over the images whose ground truth contains
  the class (the usual accumulated mIoU of semantic segmentation, restricted to those
  images). Large and small instances weigh by their pixels.
* Images where the class is absent from the ground truth do not enter IoU and Dice; what a
  backend predicts there is counted separately: **false-positive images** (the class is
  predicted but absent) and their predicted pixels, which enter the stricter
  **IoU (FP)** = ΣI / (ΣU + false-positive pixels).
* The mean of per-image IoUs over the same images is reported too (``image_iou`` in the
  CSV): it weighs every image the same, so small, missed instances pull it down.
* **mIoU / mDice / mIoU (FP)** average the per-class figures over the classes the backend
  can name that occur in the ground truth, each class weighing the same. A backend that
  knows one class (the selfie model: ``person``) is scored on that class alone.
* **FPS** is images per second of the backend's ``segment`` call (preprocessing, inference,
  post-processing), after one warm-up image whose time (model loading) is not counted.
  Reading the image from disk and scoring are not timed.
"""

from __future__ import annotations

import csv
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..classes import load_class_table
from ..config import SegmentationConfig
from ..errors import ConfigError, SemmapError
from ..records import Image
from .base import create_segmenter

__all__ = [
    "BackendScore",
    "ClassScore",
    "EvalResult",
    "SegDataset",
    "evaluate_segmentation",
    "load_dataset",
    "rasterize_polygons",
    "write_eval_outputs",
]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")


@dataclass(frozen=True)
class SegDataset:
    """Image files and their YOLO polygon label files (``None``: no objects)."""

    root: Path
    images: tuple[Path, ...]
    labels: tuple[Path | None, ...]
    names: tuple[str, ...]


def load_dataset(root: str | Path, class_list: str = "coco", classes_file: Path | None = None,
                 limit: int | None = None) -> SegDataset:
    """Find the images of a YOLO-seg dataset folder (``images/...`` beside ``labels/...``)."""
    root = Path(root)
    if not root.is_dir():
        raise ConfigError(f"{root}: no such dataset folder")
    if not ((root / "images").is_dir() and (root / "labels").is_dir()):
        raise ConfigError(f"{root}: not a YOLO-seg dataset: expected images/ and labels/ folders in it")
    img_root = root / "images"
    images = sorted(p for p in img_root.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise ConfigError(f"{root}: no images (.jpg/.png) found")
    if limit is not None:
        images = images[:limit]
    labels: list[Path | None] = []
    for p in images:
        parts = list(p.parts)
        idx = max((i for i, s in enumerate(parts) if s == "images"), default=None)
        if idx is None:
            cand = p.with_suffix(".txt")
        else:
            parts[idx] = "labels"
            cand = Path(*parts).with_suffix(".txt")
        labels.append(cand if cand.is_file() else None)
    if not any(labels):
        raise ConfigError(f"{root}: no label files (labels/<split>/<image>.txt) beside the images")
    names = load_class_table(classes_file).names(class_list)
    return SegDataset(root, tuple(images), tuple(labels), names)


def rasterize_polygons(label_file: Path | None, height: int, width: int, n_classes: int
                       ) -> dict[int, NDArray[np.bool_]]:
    """Class id → ground-truth mask (union of that class's polygons) of one image."""
    out: dict[int, NDArray[np.bool_]] = {}
    if label_file is None:
        return out
    for ln, line in enumerate(label_file.read_text().splitlines(), 1):
        vals = line.split()
        if not vals:
            continue
        try:
            cls = int(vals[0])
            xy = np.asarray(vals[1:], np.float64).reshape(-1, 2)
        except ValueError:
            raise ConfigError(f"{label_file}:{ln}: expected 'class x1 y1 x2 y2 ...'") from None
        if not 0 <= cls < n_classes:
            raise ConfigError(f"{label_file}:{ln}: class {cls} outside 0..{n_classes - 1}")
        if xy.shape[0] < 3:
            continue
        pts = np.round(xy * [width, height] - 0.5).astype(np.int32)  # normalised → pixel centres
        m = out.get(cls)
        canvas = np.zeros((height, width), np.uint8) if m is None else m.view(np.uint8)
        cv2.fillPoly(canvas, [pts], 1)
        out[cls] = canvas.view(bool)
    return out


@dataclass(frozen=True)
class ClassScore:
    name: str
    images: int  # images whose ground truth contains the class
    iou: float  # ΣI / ΣU over those images
    dice: float  # 2ΣI / (ΣP + ΣG) over those images
    fp_images: int  # images where the class is predicted but absent from the ground truth
    iou_fp: float  # ΣI / (ΣU + predicted pixels in those false-positive images)
    image_iou: float  # mean of the per-image IoUs over the images containing the class


@dataclass(frozen=True)
class BackendScore:
    label: str  # how the backend is named in tables ("onnx:yolo11n-seg", ...)
    backend: str
    classes: tuple[ClassScore, ...]  # the classes this backend can name that occur in the ground truth
    miou: float
    mdice: float
    miou_fp: float  # mean IoU (FP): false-positive pixels added to the unions
    fps: float
    images: int
    seconds: float
    errors: int = 0

    def per_class(self) -> dict[str, ClassScore]:
        return {c.name: c for c in self.classes}


@dataclass(frozen=True)
class EvalResult:
    dataset: Path
    images: int
    backends: tuple[BackendScore, ...]
    notes: dict[str, str] = field(default_factory=dict)

    def table(self) -> str:
        """The Table I-style comparison, as Markdown."""
        rows = ["| backend | mIoU | mDice | mIoU (FP) | FPS | classes | images |",
                "|---|---|---|---|---|---|---|"]
        for b in self.backends:
            rows.append(f"| {b.label} | {b.miou:.3f} | {b.mdice:.3f} | {b.miou_fp:.3f} | {b.fps:.1f} | "
                        f"{len(b.classes)} | {b.images} |")
        return "\n".join(rows)


def _label_name(cfg: SegmentationConfig) -> str:
    if cfg.weights is not None:
        return f"{cfg.backend}:{Path(cfg.weights).stem}"
    return cfg.backend


ProgressFn = Callable[[int, int], None]


def _score_backend(ds: SegDataset, cfg: SegmentationConfig, label: str, progress: ProgressFn | None,
                   done0: int, total: int) -> BackendScore:
    nc = len(ds.names)
    seg = create_segmenter(cfg)  # cached when the config sets cache_dir
    try:
        pred_names = tuple(seg.names)
        # label value k (names[k-1]) → dataset class id, -1 if the dataset has no such class
        lut = np.full(len(pred_names) + 1, -1, np.int64)
        for k, n in enumerate(pred_names, start=1):
            if n in ds.names:
                lut[k] = ds.names.index(n)
        known = sorted({int(c) for c in lut if c >= 0})
        if not known:
            raise ConfigError(f"{label}: none of its class names ({', '.join(pred_names[:5])}...) is a class of "
                              f"the dataset")
        acc = {c: np.zeros(6, np.int64) for c in known}  # I, U, P, G, fp images, fp pixels
        image_ious: dict[int, list[float]] = {c: [] for c in known}
        seconds, timed, errors = 0.0, 0, 0
        for i, (img_path, lab_path) in enumerate(zip(ds.images, ds.labels)):
            bgr = cv2.imread(str(img_path), cv2.IMREAD_COLOR)
            if bgr is None:
                raise SemmapError(f"{img_path}: cannot read the image")
            rgb = np.ascontiguousarray(bgr[:, :, ::-1])
            stem = img_path.stem
            image = Image(int(stem) if stem.isdigit() else i, "camera", rgb, "rgb8")
            if i == 0:
                seg.segment(image)  # warm-up: loading the model is not counted
            t0 = time.perf_counter()
            try:
                result = seg.segment(image)
            except SemmapError as exc:
                errors += 1
                log.warning("%s: %s on %s: %s", label, type(exc).__name__, img_path.name, exc)
                continue
            seconds += time.perf_counter() - t0
            timed += 1
            h, w = rgb.shape[:2]
            gt = rasterize_polygons(lab_path, h, w, nc)
            cls_img = lut[np.minimum(result.label, len(lut) - 1)]
            counts = np.bincount(cls_img[cls_img >= 0].ravel(), minlength=nc)
            for c in known:
                g = gt.get(c)
                if g is None:
                    if counts[c]:
                        acc[c][4] += 1
                        acc[c][5] += int(counts[c])
                    continue
                p = cls_img == c
                inter = int(np.count_nonzero(p & g))
                ps, gs = int(counts[c]), int(np.count_nonzero(g))
                union = ps + gs - inter
                acc[c][:4] += (inter, union, ps, gs)
                image_ious[c].append(inter / union if union else 1.0)
            if progress is not None:
                progress(done0 + i + 1, total)
    finally:
        seg.close()
    classes = []
    for c in known:
        if not image_ious[c]:
            continue
        i, u, n_pred, n_true, fpi, fpp = (int(v) for v in acc[c])
        classes.append(ClassScore(ds.names[c], len(image_ious[c]), i / u if u else 1.0,
                                  2 * i / (n_pred + n_true) if n_pred + n_true else 1.0, fpi,
                                  i / (u + fpp) if u + fpp else 1.0,
                                  float(np.mean(image_ious[c]))))
    nan = float("nan")
    miou = float(np.mean([c.iou for c in classes])) if classes else nan
    mdice = float(np.mean([c.dice for c in classes])) if classes else nan
    miou_fp = float(np.mean([c.iou_fp for c in classes])) if classes else nan
    return BackendScore(label, cfg.backend, tuple(classes), miou, mdice, miou_fp, timed / seconds if seconds else 0.0,
                        timed, seconds, errors)


def evaluate_segmentation(dataset: str | Path, backends: Sequence[SegmentationConfig], limit: int | None = None,
                          class_list: str = "coco", progress: ProgressFn | None = None,
                          labels: Sequence[str] | None = None) -> EvalResult:
    """Score each backend on the dataset (see the module doc for the protocol); backends run one
    after another, each on every image."""
    if not backends:
        raise ConfigError("eval-seg: name at least one backend")
    ds = load_dataset(dataset, class_list, backends[0].classes_file, limit)
    names = list(labels) if labels else [_label_name(b) for b in backends]
    total = len(ds.images) * len(backends)
    scores = []
    for j, (cfg, label) in enumerate(zip(backends, names)):
        log.info("eval-seg: %s on %d images", label, len(ds.images))
        scores.append(_score_backend(ds, cfg, label, progress, j * len(ds.images), total))
    return EvalResult(ds.root, len(ds.images), tuple(scores))


def write_eval_outputs(result: EvalResult, out: str | Path, machine: str = "") -> dict[str, Path]:
    """Write ``table.md``, ``metrics.csv`` (per backend and class) and ``chart.png`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"table": out / "table.md", "csv": out / "metrics.csv", "chart": out / "chart.png"}
    head = f"Segmentation on {result.dataset} ({result.images} images)"
    if machine:
        head += f", {machine}"
    paths["table"].write_text(f"{head}\n\n{result.table()}\n")
    with open(paths["csv"], "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["backend", "class", "images", "iou", "dice", "iou_fp", "fp_images", "image_iou", "fps"])
        for b in result.backends:
            w.writerow([b.label, "ALL", b.images, f"{b.miou:.4f}", f"{b.mdice:.4f}", f"{b.miou_fp:.4f}", "", "",
                        f"{b.fps:.2f}"])
            for c in b.classes:
                w.writerow([b.label, c.name, c.images, f"{c.iou:.4f}", f"{c.dice:.4f}", f"{c.iou_fp:.4f}",
                            c.fp_images, f"{c.image_iou:.4f}", ""])
    _chart(result, paths["chart"], head)
    return paths


def _chart(result: EvalResult, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bs = result.backends
    classes: list[str] = []
    weight: dict[str, int] = {}
    for b in bs:
        for c in b.classes:
            if c.name not in weight:
                classes.append(c.name)
            weight[c.name] = max(weight.get(c.name, 0), c.images)
    classes.sort(key=lambda n: -weight[n])
    fig = plt.figure(figsize=(max(9.0, 0.22 * len(classes) * max(len(bs), 1) + 4), 7.5), dpi=110)
    gs = fig.add_gridspec(2, 3, height_ratios=[1, 1.3], hspace=0.55, wspace=0.35)
    colors = plt.get_cmap("tab10").colors  # type: ignore[attr-defined]  # a ListedColormap
    x = np.arange(len(bs))
    for k, (attr, lab) in enumerate((("miou", "mIoU"), ("mdice", "mDice"), ("fps", "FPS (images/s)"))):
        ax = fig.add_subplot(gs[0, k])
        vals = [getattr(b, attr) for b in bs]
        ax.bar(x, vals, color=[colors[i % 10] for i in range(len(bs))])
        for xi, v in zip(x, vals):
            ax.text(float(xi), v, f"{v:.2f}" if attr != "fps" else f"{v:.1f}", ha="center", va="bottom", fontsize=8)
        ax.set_xticks(x, [b.label for b in bs], rotation=20, ha="right", fontsize=8)
        ax.set_title(lab, fontsize=10)
        if attr != "fps":
            ax.set_ylim(0, 1)
    ax = fig.add_subplot(gs[1, :])
    width = 0.8 / max(len(bs), 1)
    xc = np.arange(len(classes))
    for i, b in enumerate(bs):
        pc = b.per_class()
        vals = [pc[n].iou if n in pc else np.nan for n in classes]
        ax.bar(xc + (i - (len(bs) - 1) / 2) * width, vals, width, label=b.label, color=colors[i % 10])
    ax.set_xticks(xc, [f"{n} ({weight[n]})" for n in classes], rotation=90, fontsize=7)
    ax.set_ylim(0, 1)
    ax.set_ylabel("IoU")
    ax.set_title("IoU per class, over the images containing it (number of images)", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
