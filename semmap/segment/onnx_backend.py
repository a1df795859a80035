"""The ``onnx`` backend: segmentation models exported to ONNX, run with onnxruntime.

This is the one module that imports :mod:`onnxruntime`, lazily, when a model loads.

Two kinds of models are recognised from their outputs:

* **Instance segmentation** (YOLOv8/YOLO11/YOLO26-seg as Ultralytics exports them): two
  outputs, ``output0`` with boxes, class scores and mask coefficients, and 4-D mask
  prototypes. Letterboxing, NMS and mask assembly are in :mod:`semmap.segment.yolo`.
* **Semantic segmentation**: one output, a class map ``[1, H, W]`` (integers) or class
  scores ``[1, C, H, W]`` (argmax; ``C = 1``: a sigmoid mask of the single class).

Class names come from the model's metadata key ``names`` (Ultralytics writes
``{0: 'person', ...}``; a JSON list works too). Names that are only numbers (a model built
from a YAML without a dataset) are replaced by ``segmentation.class_list``. A semantic model whose names include
``background`` maps that class to label 0. Optional metadata for semantic models:
``mean`` and ``std`` (per channel, in [0, 1] units; default: pixels / 255 only).
"""

from __future__ import annotations

import json
import logging
import os
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..classes import load_class_table
from ..config import OnnxSegmentation
from ..errors import ConfigError
from ..records import Image, Segmentation
from .base import register
from .common import parse_names, require_model, rgb_array
from .yolo import letterbox, yolo_seg_postprocess

__all__ = ["OnnxSegmenter"]

log = logging.getLogger(__name__)

_BACKGROUND = {"background", "__background__", "_background_", "bg"}


def _providers(device: str, available: list[str]) -> list[str]:
    if device.startswith("cuda"):
        if "CUDAExecutionProvider" not in available:
            raise ConfigError(f"segmentation.device: {device!r} asked for, but this onnxruntime has only "
                              f"{', '.join(available)} (install onnxruntime-gpu)")
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    if device != "cpu":
        raise ConfigError(f"segmentation.device: {device!r} is not 'cpu' or 'cuda[:N]'")
    return ["CPUExecutionProvider"]


class OnnxSegmenter:
    """A YOLO-seg instance model or a semantic class-map model in ONNX."""

    name = "onnx"
    consumes = "rgb"

    def __init__(self, cfg: OnnxSegmentation) -> None:
        self.cfg = cfg
        self.path = require_model(cfg.model, "onnx", "a .onnx model file")
        self._session: Any = None
        self._meta: dict[str, str] | None = None
        self._names: tuple[str, ...] | None = None

    # -- loading -----------------------------------------------------------------------------
    def _load(self) -> Any:
        if self._session is not None:
            return self._session
        try:
            import onnxruntime as ort
        except ImportError:
            raise ConfigError("segmentation.backend 'onnx' needs onnxruntime: pip install onnxruntime") from None
        so = ort.SessionOptions()
        threads = self.cfg.threads or (os.cpu_count() or 1)
        so.intra_op_num_threads = threads
        so.inter_op_num_threads = 1
        so.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(str(self.path), so,
                                                 providers=_providers(self.cfg.device, ort.get_available_providers()))
        except Exception as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(f"segmentation.model: {self.path}: not a loadable ONNX model ({exc})") from None
        self._meta = dict(self._session.get_modelmeta().custom_metadata_map)
        self._inspect()
        return self._session

    def _inspect(self) -> None:
        s = self._session
        ins, outs = s.get_inputs(), s.get_outputs()
        if len(ins) != 1 or len(ins[0].shape) != 4:
            raise ConfigError(f"segmentation.model: {self.path}: expected one NCHW image input, got "
                              f"{[(i.name, i.shape) for i in ins]}")
        self._input = ins[0].name
        shape = ins[0].shape
        self._fixed_hw = (shape[2], shape[3]) if all(isinstance(v, int) for v in shape[2:]) else None
        self.kind = "instance" if len(outs) >= 2 and len(outs[1].shape) == 4 else "semantic"
        meta = self._meta or {}
        if "names" in meta:
            names = parse_names(meta["names"], f"{self.path} metadata 'names'")
        else:
            raise ConfigError(f"segmentation.model: {self.path}: no 'names' in the model metadata; "
                              f"export it with Ultralytics or add a 'names' metadata entry")
        if all(n.isdigit() for n in names):  # a model built without a dataset: numbers as names
            table = load_class_table(self.cfg.classes_file).names(self.cfg.class_list)
            if len(table) != len(names):
                raise ConfigError(f"segmentation.model: {self.path}: its {len(names)} classes are only numbered "
                                  f"and class list {self.cfg.class_list!r} has {len(table)} names")
            log.info("%s: classes are only numbered; naming them by class list %r", self.path, self.cfg.class_list)
            names = table
        self.model_names = names
        if self.kind == "semantic":
            kept = [n for n in names if n.lower() not in _BACKGROUND]
            # label value of each model class: background → 0, the others 1.. in order
            self._values = np.array([0 if n.lower() in _BACKGROUND else kept.index(n) + 1 for n in names],
                                    np.uint16)
            self._names = tuple(kept)
        else:
            self._names = names
        imgsz = self.cfg.imgsz
        if self._fixed_hw is not None:
            self._input_hw = self._fixed_hw
            if imgsz is not None and max(self._fixed_hw) != imgsz:
                log.warning("%s has a fixed %dx%d input; segmentation.imgsz=%d ignored", self.path,
                            self._fixed_hw[1], self._fixed_hw[0], imgsz)
        else:
            size = imgsz or _meta_imgsz(meta) or 640
            self._input_hw = (size, size)
        self._stride = int(meta.get("stride", 32))
        mean = meta.get("mean")
        std = meta.get("std")
        self._mean = np.asarray(json.loads(mean), np.float32) if mean else None
        self._std = np.asarray(json.loads(std), np.float32) if std else None
        log.info("onnx model %s: %s, %d classes, input %s", self.path, self.kind, len(names),
                 self._fixed_hw or f"dynamic (long side {self._input_hw[0]})")

    @property
    def names(self) -> tuple[str, ...]:
        if self._names is None:
            self._load()
        assert self._names is not None
        return self._names

    # -- inference ---------------------------------------------------------------------------
    def _input_size(self, h: int, w: int) -> tuple[int, int]:
        """The model input: the fixed size, or (dynamic models) the image fitted into imgsz, each
        side rounded up to the stride (no padding to a square: fewer pixels, faster)."""
        if self._fixed_hw is not None:
            return self._fixed_hw
        size = self._input_hw[0]
        r = min(size / h, size / w)
        s = self._stride
        return (int(np.ceil(round(h * r) / s) * s), int(np.ceil(round(w * r) / s) * s))

    def segment(self, image: Image) -> Segmentation:
        session = self._load()
        rgb = rgb_array(image, self.name)
        h, w = rgb.shape[:2]
        if self.kind == "instance":
            x, lb = letterbox(rgb, self._input_size(h, w))
            out0, out1 = session.run(None, {self._input: x})[:2]
            nc = len(self.model_names)
            label, conf, instance, _ = yolo_seg_postprocess(out0, out1, lb, nc, self.cfg.conf, self.cfg.iou,
                                                            self.cfg.mask_threshold, self.cfg.max_det)
            return Segmentation(image.stamp_ns, label, self.names, conf, instance)
        return self._semantic(image.stamp_ns, rgb, session)

    def _semantic(self, stamp: int, rgb: NDArray[np.uint8], session: Any) -> Segmentation:
        h, w = rgb.shape[:2]
        ih, iw = self._input_size(h, w)
        x = cv2.resize(rgb, (iw, ih), interpolation=cv2.INTER_LINEAR).astype(np.float32) / 255.0
        if self._mean is not None:
            x = x - self._mean
        if self._std is not None:
            x = x / self._std
        x = np.ascontiguousarray(x.transpose(2, 0, 1)[None])
        out = np.asarray(session.run(None, {self._input: x})[0])
        out = out[0] if out.ndim in (3, 4) and out.shape[0] == 1 else out
        n = len(self.model_names)
        if out.ndim == 3 and out.shape[0] == 1 and n == 1:  # one sigmoid channel
            prob = 1 / (1 + np.exp(-out[0])) if (out.min() < 0 or out.max() > 1) else out[0]
            prob = cv2.resize(prob.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
            on = prob > self.cfg.mask_threshold
            label = np.where(on, self._values[0], 0).astype(np.uint16)
            conf = np.where(label > 0, prob, 0).astype(np.float32)
        elif out.ndim == 3:  # scores (C, H, W)
            e = np.exp(out - out.max(0, keepdims=True))
            p = e / e.sum(0, keepdims=True)
            cls = p.argmax(0)
            pmax = p.max(0)
            cls = cv2.resize(cls.astype(np.uint16), (w, h), interpolation=cv2.INTER_NEAREST)
            pmax = cv2.resize(pmax.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
            label = self._values[np.clip(cls, 0, n - 1)]
            conf = np.where(label > 0, pmax, 0).astype(np.float32)
        elif out.ndim == 2:  # a class map
            cls = cv2.resize(out.astype(np.uint16), (w, h), interpolation=cv2.INTER_NEAREST)
            label = np.where(cls < n, self._values[np.clip(cls, 0, n - 1)], 0).astype(np.uint16)
            conf = None
        else:
            raise ConfigError(f"segmentation.model: {self.path}: output of shape {out.shape} is not a class map")
        return Segmentation(stamp, label, self.names, conf)

    def close(self) -> None:
        self._session = None


def _meta_imgsz(meta: dict[str, str]) -> int | None:
    raw = meta.get("imgsz")
    if not raw:
        return None
    try:
        v = json.loads(raw)
    except ValueError:
        return None
    return int(max(v)) if isinstance(v, list) else int(v)


@register("onnx")
def _make(cfg: OnnxSegmentation) -> OnnxSegmenter:
    return OnnxSegmenter(cfg)

