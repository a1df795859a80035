"""YOLO-seg pre- and post-processing in numpy: letterbox, box decoding, NMS, mask assembly.

The ONNX exports of Ultralytics' YOLOv8-seg, YOLO11-seg and YOLO26-seg give two outputs:

* ``output0``, ``[1, 4 + nc + nm, N]``: per candidate the box ``(cx, cy, w, h)`` in input
  pixels, ``nc`` class scores (already sigmoid), and ``nm`` (32) mask coefficients.
  End-to-end exports (YOLO26's default, ``end2end=True``) give ``[1, N, 6 + nm]`` instead:
  ``(x1, y1, x2, y2, score, class)`` and the coefficients, already without duplicates.
* ``output1``, ``[1, nm, h, w]``: the mask prototypes at 1/4 of the input resolution.

An instance's mask is ``sigmoid(coefficients · prototypes)``, cropped to its box, resized to
the image and thresholded. Nothing here imports onnxruntime: the functions take plain arrays,
so they are tested on tensors built by hand.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Detections",
    "Letterbox",
    "decode_detections",
    "instance_masks",
    "letterbox",
    "nms",
    "yolo_seg_postprocess",
]


@dataclass(frozen=True)
class Letterbox:
    """How an image was fitted into the model input: ``input = image * scale + (left, top)``."""

    scale: float
    left: int
    top: int
    input_hw: tuple[int, int]
    image_hw: tuple[int, int]


def letterbox(rgb: NDArray[np.uint8], input_hw: tuple[int, int], color: int = 114
              ) -> tuple[NDArray[np.float32], Letterbox]:
    """Resize keeping the aspect ratio and pad to ``input_hw`` (as Ultralytics does).

    Returns the NCHW ``float32`` tensor in [0, 1] and the geometry to undo it.
    """
    h, w = rgb.shape[:2]
    ih, iw = input_hw
    r = min(ih / h, iw / w)
    nh, nw = int(round(h * r)), int(round(w * r))
    dh, dw = (ih - nh) / 2, (iw - nw) / 2
    top, left = int(round(dh - 0.1)), int(round(dw - 0.1))
    if (nh, nw) != (h, w):
        rgb = np.asarray(cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR), np.uint8)
    canvas = np.full((ih, iw, 3), color, np.uint8)
    canvas[top:top + nh, left:left + nw] = rgb
    x = canvas.transpose(2, 0, 1)[None].astype(np.float32) * np.float32(1 / 255)
    return np.ascontiguousarray(x), Letterbox(r, left, top, (ih, iw), (h, w))


def nms(boxes: NDArray[np.floating], scores: NDArray[np.floating], iou_threshold: float) -> NDArray[np.intp]:
    """Greedy non-maximum suppression on ``(x1, y1, x2, y2)`` boxes; indices kept, best first."""
    order = np.argsort(-np.asarray(scores), kind="stable")
    boxes = np.asarray(boxes, np.float64)
    area = np.clip(boxes[:, 2] - boxes[:, 0], 0, None) * np.clip(boxes[:, 3] - boxes[:, 1], 0, None)
    keep: list[int] = []
    while order.size:
        i = int(order[0])
        keep.append(i)
        rest = order[1:]
        xx1 = np.maximum(boxes[i, 0], boxes[rest, 0])
        yy1 = np.maximum(boxes[i, 1], boxes[rest, 1])
        xx2 = np.minimum(boxes[i, 2], boxes[rest, 2])
        yy2 = np.minimum(boxes[i, 3], boxes[rest, 3])
        inter = np.clip(xx2 - xx1, 0, None) * np.clip(yy2 - yy1, 0, None)
        iou = inter / np.maximum(area[i] + area[rest] - inter, 1e-12)
        order = rest[iou <= iou_threshold]
    return np.asarray(keep, dtype=np.intp)


@dataclass(frozen=True)
class Detections:
    """Instances in model-input pixels, best first."""

    boxes: NDArray[np.float32]  # (n, 4) x1 y1 x2 y2
    scores: NDArray[np.float32]  # (n,)
    classes: NDArray[np.intp]  # (n,) class index (0-based)
    coefficients: NDArray[np.float32]  # (n, nm)

    def __len__(self) -> int:
        return int(self.scores.size)


def decode_detections(output0: NDArray[np.floating], nc: int, nm: int, conf: float, iou: float,
                      max_det: int = 300, agnostic: bool = False) -> Detections:
    """Candidates of ``output0`` (either layout, see the module doc) → thresholded, NMS-ed detections.

    NMS is per class (boxes of different classes never suppress each other) unless ``agnostic``.
    """
    a = np.asarray(output0, np.float32)
    if a.ndim == 3:
        a = a[0]
    if a.ndim != 2:
        raise ValueError(f"output0 must be [1, C, N] or [1, N, C], got shape {np.shape(output0)}")
    if a.shape[0] == 4 + nc + nm:  # [C, N]: raw head, NMS needed
        a = a.T
        cls_scores = a[:, 4:4 + nc]
        cls = cls_scores.argmax(1)
        score = cls_scores[np.arange(a.shape[0]), cls]
        sel = score >= conf
        a, cls, score = a[sel], cls[sel], score[sel]
        cx, cy, w, h = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
        boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1)
        coef = a[:, 4 + nc:4 + nc + nm]
        if score.size:
            offset = 0.0 if agnostic else 7680.0  # Ultralytics' max_wh: classes never overlap
            keep = nms(boxes + (cls[:, None] * offset), score, iou)[:max_det]
            boxes, score, cls, coef = boxes[keep], score[keep], cls[keep], coef[keep]
    elif a.shape[1] == 6 + nm:  # [N, 6 + nm]: end-to-end, already without duplicates
        sel = a[:, 4] >= conf
        a = a[sel]
        order = np.argsort(-a[:, 4], kind="stable")[:max_det]
        a = a[order]
        boxes, score, cls, coef = a[:, :4], a[:, 4], a[:, 5].astype(np.intp), a[:, 6:6 + nm]
    else:
        raise ValueError(f"output0 of shape {np.shape(output0)} fits neither [1, 4+{nc}+{nm}, N] "
                         f"nor [1, N, 6+{nm}]")
    return Detections(boxes.astype(np.float32), score.astype(np.float32), cls.astype(np.intp),
                      coef.astype(np.float32))


def instance_masks(det: Detections, protos: NDArray[np.floating], lb: Letterbox, mask_threshold: float = 0.5
                   ) -> tuple[list[NDArray[np.bool_]], list[tuple[int, int]], NDArray[np.float32]]:
    """Each detection's mask in image pixels, as a box-sized patch.

    Returns ``(patches, offsets, boxes)``: ``patches[i]`` is the boolean mask inside the
    instance's box (rows, cols), ``offsets[i]`` the box's top-left ``(row, col)`` in the
    image, ``boxes`` the boxes in image pixels ``(x1, y1, x2, y2)``.
    """
    p = np.asarray(protos, np.float32)
    if p.ndim == 4:
        p = p[0]
    nm, mh, mw = p.shape
    ih, iw = lb.input_hw
    h, w = lb.image_hw
    # input px → image px
    boxes = (det.boxes - np.array([lb.left, lb.top, lb.left, lb.top], np.float32)) / lb.scale
    boxes = np.clip(boxes, 0, [w, h, w, h]).astype(np.float32)
    patches: list[NDArray[np.bool_]] = []
    offsets: list[tuple[int, int]] = []
    if not len(det):
        return patches, offsets, boxes
    logits = det.coefficients @ p.reshape(nm, -1)  # (n, mh*mw)
    logits = logits.reshape(-1, mh, mw)
    sx, sy = mw / iw, mh / ih  # proto px per input px
    thr_logit = np.log(mask_threshold / (1 - mask_threshold)) if 0 < mask_threshold < 1 else \
        (-np.inf if mask_threshold <= 0 else np.inf)
    for i in range(len(det)):
        x1, y1, x2, y2 = boxes[i]
        c0, r0 = int(np.floor(x1)), int(np.floor(y1))
        c1, r1 = int(np.ceil(x2)), int(np.ceil(y2))
        if c1 <= c0 or r1 <= r0:
            patches.append(np.zeros((0, 0), bool))
            offsets.append((0, 0))
            continue
        # the proto window covering the box (+1 proto px of context for the interpolation)
        px0 = (c0 * lb.scale + lb.left) * sx
        py0 = (r0 * lb.scale + lb.top) * sy
        px1 = (c1 * lb.scale + lb.left) * sx
        py1 = (r1 * lb.scale + lb.top) * sy
        wx0, wy0 = max(int(np.floor(px0)) - 1, 0), max(int(np.floor(py0)) - 1, 0)
        wx1, wy1 = min(int(np.ceil(px1)) + 1, mw), min(int(np.ceil(py1)) + 1, mh)
        win = logits[i, wy0:wy1, wx0:wx1]
        # sample the window at the centres of the box's image pixels (bilinear, as upsampling does)
        cols = ((np.arange(c0, c1) + 0.5) * lb.scale + lb.left) * sx - 0.5 - wx0
        rows = ((np.arange(r0, r1) + 0.5) * lb.scale + lb.top) * sy - 0.5 - wy0
        mapx = np.broadcast_to(cols[None, :].astype(np.float32), (r1 - r0, c1 - c0))
        mapy = np.broadcast_to(rows[:, None].astype(np.float32), (r1 - r0, c1 - c0))
        patch = cv2.remap(np.ascontiguousarray(win), np.ascontiguousarray(mapx), np.ascontiguousarray(mapy),
                          cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        m = patch > thr_logit
        # crop to the box itself (sub-pixel edges: pixel centres inside the box)
        cc = (np.arange(c0, c1) + 0.5)
        rr = (np.arange(r0, r1) + 0.5)
        m &= ((rr >= y1) & (rr <= y2))[:, None] & ((cc >= x1) & (cc <= x2))[None, :]
        patches.append(m)
        offsets.append((r0, c0))
    return patches, offsets, boxes


def yolo_seg_postprocess(output0: NDArray[np.floating], protos: NDArray[np.floating], lb: Letterbox, nc: int,
                         conf: float = 0.25, iou: float = 0.7, mask_threshold: float = 0.5, max_det: int = 300
                         ) -> tuple[NDArray[np.uint16], NDArray[np.float32], NDArray[np.uint16], Detections]:
    """Model outputs → the label image (value = class + 1), confidence, instance image (value =
    detection + 1) and the detections."""
    from .common import compose_instances

    nm = int(np.shape(protos)[-3])
    det = decode_detections(output0, nc, nm, conf, iou, max_det)
    patches, offsets, _ = instance_masks(det, protos, lb, mask_threshold)
    label, confidence, instance = compose_instances(lb.image_hw, patches, det.classes + 1, det.scores, offsets)
    return label, confidence, instance, det
