"""The ``mediapipe-selfie`` backend: MediaPipe's pretrained selfie (person) segmenter.

The model is a TFLite file (``selfie_segmentation.tflite``, 256×256 input, or
``selfie_segmentation_landscape.tflite``, 144×256) run with the LiteRT interpreter
(``ai-edge-litert``), which is imported here and nowhere else, lazily. It answers one
class, ``person``: the probability that each pixel shows a person. Pixels above
``segmentation.mask_threshold`` are labelled 1 (``person``); the confidence is that
probability.

Preprocessing follows MediaPipe's selfie graph: the whole image is resized (aspect ratio
not kept) to the model input and scaled to [0, 1].
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..config import SelfieSegmentation
from ..errors import ConfigError
from ..records import Image, Segmentation
from .base import register
from .common import default_data_dir, rgb_array

__all__ = ["SelfieSegmenter", "default_selfie_model"]

log = logging.getLogger(__name__)


def default_selfie_model() -> Path:
    """``$SEMMAP_DATA/models/selfie_segmentation.tflite`` (or ``../shared/data/models/...``)."""
    return default_data_dir() / "models" / "selfie_segmentation.tflite"


class SelfieSegmenter:
    """Person segmentation with the MediaPipe selfie model."""

    name = "mediapipe-selfie"
    consumes = "rgb"
    names: tuple[str, ...] = ("person",)

    def __init__(self, cfg: SelfieSegmentation) -> None:
        self.cfg = cfg
        self.path = Path(cfg.model).expanduser() if cfg.model is not None else default_selfie_model()
        if not self.path.is_file():
            raise ConfigError(f"segmentation.model: {self.path}: no such file (the selfie model, "
                              f"selfie_segmentation.tflite; see ../shared/data/README.md)")
        self._interp: Any = None

    def _load(self) -> Any:
        if self._interp is not None:
            return self._interp
        try:
            from ai_edge_litert.interpreter import Interpreter
        except ImportError:
            raise ConfigError("segmentation.backend 'mediapipe-selfie' needs the LiteRT interpreter: "
                              "pip install ai-edge-litert") from None
        if self.cfg.device != "cpu":
            raise ConfigError(f"segmentation.device: the selfie model runs on the CPU only, not {self.cfg.device!r}")
        try:
            interp = Interpreter(model_path=str(self.path), num_threads=self.cfg.threads or (os.cpu_count() or 1))
            interp.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise ConfigError(f"segmentation.model: {self.path}: not a loadable TFLite model ({exc})") from None
        inp = interp.get_input_details()[0]
        out = interp.get_output_details()[0]
        if len(inp["shape"]) != 4 or inp["shape"][3] != 3 or inp["dtype"] != np.float32:
            raise ConfigError(f"segmentation.model: {self.path}: expected a [1, H, W, 3] float input, "
                              f"got {list(inp['shape'])} {inp['dtype'].__name__}")
        self._in_idx, self._out_idx = inp["index"], out["index"]
        self._in_hw = (int(inp["shape"][1]), int(inp["shape"][2]))
        self._interp = interp
        return interp

    def probability(self, rgb: np.ndarray) -> np.ndarray:
        """Per-pixel person probability, float32 (H, W) at the image's size."""
        interp = self._load()
        h, w = rgb.shape[:2]
        ih, iw = self._in_hw
        x = cv2.resize(rgb, (iw, ih), interpolation=cv2.INTER_AREA if ih < h else cv2.INTER_LINEAR)
        x = (x.astype(np.float32) * np.float32(1 / 255))[None]
        interp.set_tensor(self._in_idx, x)
        interp.invoke()
        p = np.asarray(interp.get_tensor(self._out_idx), np.float32).reshape(ih, iw)
        return cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR)

    def segment(self, image: Image) -> Segmentation:
        p = self.probability(rgb_array(image, self.name))
        on = p > self.cfg.mask_threshold
        label = on.astype(np.uint16)
        conf = np.where(on, p, 0).astype(np.float32)
        return Segmentation(image.stamp_ns, label, self.names, conf)

    def close(self) -> None:
        self._interp = None


@register("mediapipe-selfie")
def _make(cfg: SelfieSegmentation) -> SelfieSegmenter:
    return SelfieSegmenter(cfg)
