"""Segmentations of a tour's camera topic, one per image, in bag order.

:class:`ImageSource` is what the scan stream (:class:`semmap.paint.stream.ScanStream`) pulls
segmentations from. :class:`InProcessImages` reads, decodes and segments in the calling process;
:class:`semmap.workers.ImageWorker` does the same in a worker process (both use
:class:`ImageReader`).
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any, Protocol

from ..config import SegmentationConfig
from ..errors import SemmapError
from ..records import Image, Segmentation
from .base import Segmenter

__all__ = ["ImageReader", "ImageSource", "InProcessImages"]

log = logging.getLogger(__name__)


class ImageSource(Protocol):
    """Segmentations of the camera topic, one per frame, in bag order."""

    counts: dict[str, Any]

    def wait_ready(self) -> None:
        """Block until the segmenter is loaded (start-up is not counted as work)."""

    def next(self) -> Segmentation | None:
        """The next segmentation; None after the last."""

    def release(self, seg: Segmentation) -> None:
        """The caller no longer needs ``seg`` (its memory may be reused)."""

    def close(self) -> None:
        """Stop, and free what was held."""


class ImageReader:
    """Segmentations of a camera topic, one per frame; the segmenter is created and the bag opened
    here, before the first frame is asked for (start-up, not work), and released by :meth:`close`."""

    def __init__(self, bag: Path, topic: str, seg_cfg: SegmentationConfig,
                 counts: dict[str, int]) -> None:
        from ..io.bag import read_bag
        from .base import create_segmenter

        self._stack = contextlib.ExitStack()
        segmenter = create_segmenter(seg_cfg)
        self._stack.callback(segmenter.close)
        try:
            opened = self._stack.enter_context(read_bag(bag))
        except BaseException:
            self._stack.close()
            raise

        def bad(topic: str, exc: SemmapError) -> None:  # an image that cannot be decoded is skipped, counted
            counts["bad_images"] += 1
            log.debug("skipped image on %s: %s", topic, exc)

        self._it = self._segmented(opened.records([topic], skip=bad), topic, segmenter, counts)

    @staticmethod
    def _segmented(images: Iterator[tuple[str, int, Image]], topic: str, segmenter: Segmenter,
                counts: dict[str, int]) -> Generator[Segmentation, None, None]:
        for _, _, img in images:
            t0 = time.perf_counter()
            try:
                seg = segmenter.segment(img)
            except SemmapError as exc:  # an image the segmenter cannot take is skipped, counted
                counts["bad_images"] += 1
                log.debug("skipped image on %s: %s", topic, exc)
                continue
            counts["images"] += 1
            counts["segment_ms"] += int((time.perf_counter() - t0) * 1000)
            yield seg

    def __iter__(self) -> Iterator[Segmentation]:
        return self._it

    def close(self) -> None:
        self._it.close()
        self._stack.close()


class InProcessImages:
    """Segmentations of a camera topic, decoded in this process, one at a time."""

    def __init__(self, bag: Path, topic: str, seg_cfg: SegmentationConfig) -> None:
        self.counts: dict[str, Any] = {"images": 0, "bad_images": 0, "segment_ms": 0}
        self._source = ImageReader(bag, topic, seg_cfg, self.counts)
        self._it = iter(self._source)

    def next(self) -> Segmentation | None:
        return next(self._it, None)

    def wait_ready(self) -> None:
        pass

    def release(self, seg: Segmentation) -> None:
        pass

    def close(self) -> None:
        self._source.close()
