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
from .cache import CachedSegmenter
from .select import FrameSelector, OdometrySource, SkippedFrame

__all__ = ["ImageReader", "ImageSource", "InProcessImages", "OdometrySource", "SkippedFrame"]

log = logging.getLogger(__name__)


class ImageSource(Protocol):
    """Segmentations of the camera topic, one per frame, in bag order (a :class:`SkippedFrame` for a
    frame the selection did not segment)."""

    counts: dict[str, Any]

    def wait_ready(self) -> None:
        """Block until the segmenter is loaded (start-up is not counted as work)."""

    def next(self) -> Segmentation | SkippedFrame | None:
        """The next segmentation (or skipped frame); None after the last."""

    def release(self, seg: Segmentation | SkippedFrame) -> None:
        """The caller no longer needs ``seg`` (its memory may be reused)."""

    def close(self) -> None:
        """Stop, and free what was held."""


class ImageReader:
    """Segmentations of a camera topic, one per frame; the segmenter is created and the bag opened
    here, before the first frame is asked for (start-up, not work), and released by :meth:`close`.

    With a frame selection (``segmentation.select``, ``max_rate``, ``max_frames``, ``max_seconds``) the
    frames it does not take come out as :class:`SkippedFrame`, before the model sees them; what the
    selector reads besides the images (its :attr:`~FrameSelector.topics`) is read in the same pass.
    ``selector`` default: the one ``seg_cfg`` asks for, without odometry.
    ``counts`` gains ``images`` (segmented), ``skipped_frames``, ``bad_images`` and ``segment_ms``.
    """

    def __init__(self, bag: Path, topic: str, seg_cfg: SegmentationConfig,
                 counts: dict[str, int], selector: FrameSelector | None = None) -> None:
        from ..io.bag import read_bag
        from .base import create_segmenter

        self._stack = contextlib.ExitStack()
        segmenter = create_segmenter(seg_cfg)
        self._stack.callback(segmenter.close)
        if not isinstance(segmenter, CachedSegmenter):  # (the mask cache loads its model only when it must)
            _ = segmenter.names  # a model that loads on first use loads now: start-up, not its first frame's time
        try:
            opened = self._stack.enter_context(read_bag(bag))
        except BaseException:
            self._stack.close()
            raise
        if selector is None:
            selector = FrameSelector(seg_cfg)
        selector.spread_over((opened.end_ns - opened.start_ns) * 1e-9)
        counts.setdefault("skipped_frames", 0)
        if selector.mode == "motion" and selector.odometry is None:
            log.info("segmentation.select: motion: the tour has no odometry; a frame is segmented every %.1f s",
                     selector.interval_ns * 1e-9)

        def bad(what: str, exc: SemmapError) -> None:  # an image that cannot be decoded is skipped, counted
            if what == topic:
                counts["bad_images"] += 1
            log.debug("skipped a message on %s: %s", what, exc)

        self._it = self._segmented(opened.records([topic, *selector.topics], skip=bad), topic, segmenter, counts,
                                   selector)

    @staticmethod
    def _segmented(records: Iterator[tuple[str, int, Any]], topic: str, segmenter: Segmenter,
                   counts: dict[str, int], selector: FrameSelector,
                   ) -> Generator[Segmentation | SkippedFrame, None, None]:
        for what, _, record in records:
            if what != topic:
                selector.on_record(what, record)
                continue
            img: Image = record
            if not selector.want(img.stamp_ns):
                counts["skipped_frames"] += 1
                yield SkippedFrame(img.stamp_ns)
                continue
            t0 = time.perf_counter()
            try:
                seg = segmenter.segment(img)
            except SemmapError as exc:  # an image the segmenter cannot take is skipped, counted
                counts["bad_images"] += 1
                selector.failed()
                log.debug("skipped image on %s: %s", topic, exc)
                continue
            elapsed = time.perf_counter() - t0
            counts["images"] += 1
            counts["segment_ms"] += int(elapsed * 1000)
            # the model's time for it: as measured, or as it was when the mask cache stored it
            stored = segmenter.last_model_seconds if isinstance(segmenter, CachedSegmenter) else None
            selector.timed(elapsed if stored is None else stored, img.stamp_ns)
            selector.segmented(seg)
            yield seg

    def __iter__(self) -> Iterator[Segmentation | SkippedFrame]:
        return self._it

    def close(self) -> None:
        self._it.close()
        self._stack.close()


class InProcessImages:
    """Segmentations of a camera topic, decoded in this process, one at a time."""

    def __init__(self, bag: Path, topic: str, seg_cfg: SegmentationConfig,
                 selector: FrameSelector | None = None) -> None:
        self.counts: dict[str, Any] = {"images": 0, "skipped_frames": 0, "bad_images": 0, "segment_ms": 0}
        self._source = ImageReader(bag, topic, seg_cfg, self.counts, selector)
        self._it = iter(self._source)

    def next(self) -> Segmentation | SkippedFrame | None:
        return next(self._it, None)

    def wait_ready(self) -> None:
        pass

    def release(self, seg: Segmentation | SkippedFrame) -> None:
        pass

    def close(self) -> None:
        self._source.close()
