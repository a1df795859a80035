"""The ``folder`` backend: precomputed label images, one PNG per camera image.

``semmap segment`` writes such a folder: ``<stamp_ns>.png`` per bag image (or
``<image name>.png`` per file of an image folder), ``uint16`` (or ``uint8``) label values
following the "Label images" convention, and ``classes.json`` naming them. A frame is
matched by its stamp: file names that are all digits are read as integer nanoseconds
(``000000000009.png`` is stamp 9); other names are numbered in sorted order, as
:func:`semmap.segment.run.iter_image_folder` numbers the images of a folder.

Class names: ``classes.json`` in the folder (``{"names": [...]}``), else
``segmentation.class_list``.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from ..classes import load_class_table
from ..config import FolderSegmentation
from ..errors import ConfigError, SemmapError
from ..records import Image, Segmentation
from .base import register

__all__ = ["FolderSegmenter", "stamp_index"]


def stamp_index(files: list[Path]) -> dict[int, Path]:
    """Stamp → file: all-digit stems are stamps; other files are numbered in sorted order."""
    files = sorted(files)
    if files and all(f.stem.isdigit() for f in files):
        return {int(f.stem): f for f in files}
    return dict(enumerate(files))


class FolderSegmenter:
    """Read the label PNG recorded for each image's stamp."""

    name = "folder"
    consumes = "rgb"

    def __init__(self, cfg: FolderSegmentation) -> None:
        if cfg.folder is None:
            raise ConfigError("segmentation.folder: the folder backend needs the folder of label PNGs")
        self.root = Path(cfg.folder).expanduser()
        if not self.root.is_dir():
            raise ConfigError(f"segmentation.folder: {self.root}: no such folder")
        meta = self.root / "classes.json"
        if meta.is_file():
            try:
                names = json.loads(meta.read_text())["names"]
            except (ValueError, KeyError, TypeError):
                raise ConfigError(f"{meta}: expected {{\"names\": [...]}}") from None
            if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
                raise ConfigError(f"{meta}: names must be a list of strings")
            self.names: tuple[str, ...] = tuple(names)
        else:
            self.names = load_class_table(cfg.classes_file).names(cfg.class_list)
        self._index = stamp_index(list(self.root.glob("*.png")))
        if not self._index:
            raise ConfigError(f"segmentation.folder: {self.root}: no .png label images")

    def segment(self, image: Image) -> Segmentation:
        path = self._index.get(image.stamp_ns)
        if path is None:
            raise SemmapError(f"{self.root}: no label image for stamp {image.stamp_ns}")
        label = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if label is None or label.ndim != 2 or label.dtype not in (np.uint8, np.uint16):
            raise SemmapError(f"{path}: not a single-channel 8- or 16-bit label PNG")
        if label.shape != (image.height, image.width):
            raise SemmapError(f"{path}: label image is {label.shape[1]}x{label.shape[0]}, "
                              f"the camera image {image.width}x{image.height}")
        if int(label.max(initial=0)) > len(self.names):
            raise SemmapError(f"{path}: label value {int(label.max())} beyond the {len(self.names)} class names")
        return Segmentation(image.stamp_ns, label.astype(np.uint16), self.names)

    def close(self) -> None:
        pass


@register("folder")
def _make(cfg: FolderSegmentation) -> FolderSegmenter:
    return FolderSegmenter(cfg)
