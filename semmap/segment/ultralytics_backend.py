"""The ``ultralytics`` backend: ``.pt`` segmentation models through the Ultralytics package.

This is the one module that imports :mod:`ultralytics`, lazily, when a model loads
(Ultralytics imports torch and torchvision itself). Any model Ultralytics' ``YOLO`` class
loads for the ``segment`` task works (YOLOv8/YOLO11/YOLO26-seg, custom trained weights);
its class names come from the model. Set ``YOLO_OFFLINE=1`` to keep Ultralytics from
reaching the network.

Install: ``pip install -c constraints.txt ultralytics``. Ultralytics needs a torchvision
that imports beside the installed torch (see docs/build.md, "Installing").
"""

from __future__ import annotations

import logging
from typing import Any

import cv2
import numpy as np

from ..config import UltralyticsSegmentation
from ..errors import ConfigError
from ..records import Image, Segmentation
from .base import register
from .common import compose_instances, require_model, rgb_array

__all__ = ["UltralyticsSegmenter"]

log = logging.getLogger(__name__)


class UltralyticsSegmenter:
    """A YOLO-seg ``.pt`` model run by Ultralytics."""

    name = "ultralytics"
    consumes = "rgb"

    def __init__(self, cfg: UltralyticsSegmentation) -> None:
        self.cfg = cfg
        self.path = require_model(cfg.model, "ultralytics", "a .pt model file")
        self._model: Any = None

    def _load(self) -> Any:
        if self._model is None:
            try:
                from ultralytics import YOLO
            except Exception as exc:
                raise ConfigError(f"segmentation.backend 'ultralytics' cannot import ultralytics "
                                  f"({type(exc).__name__}: {exc}); pip install ultralytics with a matching "
                                  f"torchvision") from None
            try:
                self._model = YOLO(str(self.path), task="segment")
            except Exception as exc:
                raise ConfigError(f"segmentation.model: {self.path}: Ultralytics cannot load it ({exc})") from None
        return self._model

    @property
    def names(self) -> tuple[str, ...]:
        raw = self._load().names
        return tuple(raw[i] for i in sorted(raw)) if isinstance(raw, dict) else tuple(raw)

    def segment(self, image: Image) -> Segmentation:
        model = self._load()
        rgb = rgb_array(image, self.name)
        h, w = rgb.shape[:2]
        kwargs: dict[str, Any] = {"conf": self.cfg.conf, "iou": self.cfg.iou, "max_det": self.cfg.max_det,
                                  "device": self.cfg.device, "verbose": False, "retina_masks": True}
        if self.cfg.imgsz:
            kwargs["imgsz"] = self.cfg.imgsz
        res = model.predict(np.ascontiguousarray(rgb[:, :, ::-1]), **kwargs)[0]  # Ultralytics takes BGR
        if res.masks is None or res.boxes is None or len(res.boxes) == 0:
            return Segmentation(image.stamp_ns, np.zeros((h, w), np.uint16), self.names,
                                np.zeros((h, w), np.float32))
        masks = res.masks.data.cpu().numpy() > 0.5
        if masks.shape[1:] != (h, w):
            masks = np.stack([cv2.resize(m.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
                              for m in masks])
        cls = res.boxes.cls.cpu().numpy().astype(np.intp)
        scores = res.boxes.conf.cpu().numpy().astype(np.float32)
        label, conf, instance = compose_instances((h, w), masks, cls + 1, scores)
        return Segmentation(image.stamp_ns, label, self.names, conf, instance)

    def close(self) -> None:
        self._model = None


@register("ultralytics")
def _make(cfg: UltralyticsSegmentation) -> UltralyticsSegmenter:
    return UltralyticsSegmenter(cfg)
