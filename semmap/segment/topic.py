"""The ``topic`` backend: label images recorded in the bag (``mono8``/``mono16``).

Their class list comes from configuration (``segmentation.class_list``), as the
docs/conventions.md's "Label images" convention says.
"""

from __future__ import annotations

import numpy as np

from ..classes import load_class_table
from ..config import TopicSegmentation
from ..errors import BagError
from ..io.messages import LABEL_ENCODINGS
from ..records import Image, Segmentation
from .base import register

__all__ = ["LabelTopicSegmenter"]


class LabelTopicSegmenter:
    """Pass recorded label images through as segmentations."""

    name = "topic"
    consumes = "labels"

    def __init__(self, cfg: TopicSegmentation) -> None:
        table = load_class_table(cfg.classes_file)
        self.names: tuple[str, ...] = table.names(cfg.class_list)

    def segment(self, image: Image) -> Segmentation:
        if image.encoding not in LABEL_ENCODINGS or image.data.ndim != 2:
            raise BagError(f"label image has encoding {image.encoding!r}; expected one of "
                           f"{', '.join(sorted(LABEL_ENCODINGS))}")
        label = image.data.astype(np.uint16, copy=False)
        return Segmentation(image.stamp_ns, label, self.names)

    def close(self) -> None:
        pass


@register("topic", consumes="labels")
def _make(cfg: TopicSegmentation) -> LabelTopicSegmenter:
    return LabelTopicSegmenter(cfg)
