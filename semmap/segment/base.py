"""The Segmenter protocol and its registry.

A segmenter turns one camera image into a :class:`~semmap.records.Segmentation`:
a ``uint16`` label image (value k > 0 is ``names[k-1]``, 0 is no object) plus an
optional per-pixel confidence. Backends register a factory under a name::

    class MyOptions(ModelSegmentationConfig):  # semmap.config; one model per backend
        backend: Literal["my-backend"] = "my-backend"

    @register("my-backend")
    def _make(cfg: MyOptions) -> Segmenter: ...

``consumes`` tells the pipeline what to feed: ``"rgb"`` for models that look at the
camera image, ``"labels"`` for label images already recorded in the bag.

Built-in backends (one module each; heavy runtimes are imported lazily, when a model loads):

=====================  =====================================  =============================
name                   module                                 runtime
=====================  =====================================  =============================
``topic``              :mod:`semmap.segment.topic`            none (labels in the bag)
``folder``             :mod:`semmap.segment.folder`           none (label PNGs)
``onnx``               :mod:`semmap.segment.onnx_backend`     onnxruntime
``ultralytics``        :mod:`semmap.segment.ultralytics_backend`  ultralytics (``.pt``)
``sam3``               :mod:`semmap.segment.sam3`             transformers + torch
``mediapipe-selfie``   :mod:`semmap.segment.selfie`           ai-edge-litert
=====================  =====================================  =============================

With ``segmentation.cache_dir`` set, :func:`create_segmenter` wraps a model backend in
:class:`~semmap.segment.cache.CachedSegmenter`: label images are stored per model and
image stamp, so a rebuild does not segment again.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, Protocol, runtime_checkable

from ..config import SEGMENTATION_BACKENDS, ModelSegmentationConfig, SegmentationConfig, register_segmentation_options
from ..errors import ConfigError
from ..records import Image, Segmentation

__all__ = [
    "CONSUMES",
    "SEGMENTERS",
    "Segmenter",
    "available_backends",
    "backend_consumes",
    "create_segmenter",
    "register",
]


@runtime_checkable
class Segmenter(Protocol):
    """What every segmentation backend provides."""

    @property
    def name(self) -> str:
        """The backend's registry name."""

    @property
    def names(self) -> tuple[str, ...]:
        """Class names of the label values it returns (value k is names[k-1])."""

    @property
    def consumes(self) -> str:
        """Which image stream it needs: ``"rgb"`` or ``"labels"``."""

    def segment(self, image: Image) -> Segmentation:
        """Segment one image (an RGB frame, or a recorded label image for ``consumes == "labels"``)."""
        ...

    def close(self) -> None:
        """Release models, workers and files."""
        ...


SegmenterFactory = Callable[[Any], Segmenter]  # takes its backend's SegmentationConfig subclass

#: backend name → factory
SEGMENTERS: dict[str, SegmenterFactory] = {}
#: backend name → the image stream it consumes ("rgb" or "labels"), known without loading a model
CONSUMES: dict[str, str] = {}


def register(name: str, consumes: Literal["rgb", "labels"] = "rgb",
             options: type[SegmentationConfig] | None = None) -> Callable[[SegmenterFactory], SegmenterFactory]:
    """Register a segmentation backend: ``factory(cfg)`` makes the segmenter from its options. A plugin's
    backend (not one of semmap's own) can then be named in a config file (``segmentation: {backend:
    name, ...}``), its options validated by ``options`` (default: any keys, see
    :class:`~semmap.config.PluginSegmentation`)."""
    def deco(factory: SegmenterFactory) -> SegmenterFactory:
        SEGMENTERS[name] = factory
        CONSUMES[name] = consumes
        if name not in SEGMENTATION_BACKENDS:
            register_segmentation_options(name, options)
        return factory

    return deco


def _load_backends() -> None:
    # importing a backend module registers it; none of them imports its runtime at import time
    from . import folder, onnx_backend, sam3, selfie, topic, ultralytics_backend  # noqa: F401


def _check(cfg: SegmentationConfig) -> None:
    _load_backends()
    if cfg.backend not in SEGMENTERS:
        known = ", ".join(sorted(SEGMENTERS))
        raise ConfigError(f"segmentation.backend: unknown backend {cfg.backend!r} (available: {known})")


def backend_consumes(cfg: SegmentationConfig) -> str:
    """Which image stream the configured backend needs, without instantiating it."""
    _check(cfg)
    return CONSUMES[cfg.backend]


def available_backends() -> tuple[str, ...]:
    """The registered backend names (whether their runtimes are installed or not)."""
    _load_backends()
    return tuple(sorted(SEGMENTERS))


def create_segmenter(cfg: SegmentationConfig, cache: bool = True) -> Segmenter:
    """Instantiate the configured backend (importing its module registers it).

    With ``cfg.cache_dir`` set (and ``cache`` true), an RGB backend comes wrapped in the
    on-disk mask cache (:class:`~semmap.segment.cache.CachedSegmenter`).
    """
    _check(cfg)
    seg = SEGMENTERS[cfg.backend](cfg)
    if (cache and isinstance(cfg, ModelSegmentationConfig) and cfg.cache_dir is not None
            and CONSUMES[cfg.backend] == "rgb"):
        from .cache import CachedSegmenter

        return CachedSegmenter(seg, cfg)
    return seg
