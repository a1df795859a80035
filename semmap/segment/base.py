"""The Segmenter protocol and its registry.

A segmenter turns one camera image into a :class:`~semmap.records.Segmentation`:
a ``uint16`` label image (value k > 0 is ``names[k-1]``, 0 is no object) plus an
optional per-pixel confidence. Backends register a factory under a name::

    @register("my-backend")
    def _make(cfg: SegmentationConfig) -> Segmenter: ...

``consumes`` tells the pipeline what to feed: ``"rgb"`` for models that look at the
camera image, ``"labels"`` for label images already recorded in the bag.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, Protocol, runtime_checkable

from ..config import SegmentationConfig
from ..errors import ConfigError
from ..records import Image, Segmentation

__all__ = ["Segmenter", "SEGMENTERS", "register", "create_segmenter"]


@runtime_checkable
class Segmenter(Protocol):
    """What every segmentation backend provides."""

    #: the backend's registry name
    name: str
    #: class names of the label values it returns (value k is names[k-1])
    names: tuple[str, ...]
    #: which image stream it needs
    consumes: Literal["rgb", "labels"]

    def segment(self, image: Image) -> Segmentation:
        """Segment one image (an RGB frame, or a recorded label image for ``consumes == "labels"``)."""
        ...

    def close(self) -> None:
        """Release models, workers and files."""
        ...


SegmenterFactory = Callable[[SegmentationConfig], Segmenter]

#: backend name → factory
SEGMENTERS: dict[str, SegmenterFactory] = {}
#: backend name → the image stream it consumes ("rgb" or "labels"), known without loading a model
CONSUMES: dict[str, str] = {}


def register(name: str, consumes: Literal["rgb", "labels"] = "rgb") -> Callable[[SegmenterFactory], SegmenterFactory]:
    def deco(factory: SegmenterFactory) -> SegmenterFactory:
        SEGMENTERS[name] = factory
        CONSUMES[name] = consumes
        return factory

    return deco


def _load_backends() -> None:
    from . import topic  # noqa: F401 - registers the built-in backends


def _check(cfg: SegmentationConfig) -> None:
    _load_backends()
    if cfg.backend not in SEGMENTERS:
        known = ", ".join(sorted(SEGMENTERS))
        raise ConfigError(f"segmentation.backend: unknown backend {cfg.backend!r} (available: {known})")


def backend_consumes(cfg: SegmentationConfig) -> str:
    """Which image stream the configured backend needs, without instantiating it."""
    _check(cfg)
    return CONSUMES[cfg.backend]


def create_segmenter(cfg: SegmentationConfig) -> Segmenter:
    """Instantiate the configured backend (importing its module registers it)."""
    _check(cfg)
    return SEGMENTERS[cfg.backend](cfg)
