"""map_server's own loading rules, transcribed from the loaders' source, to check the maps semmap writes.

These are deliberately *not* semmap's reader: each function follows one consumer line by line.

* ``ros1``: ros-planning/navigation ``map_server/src/main.cpp`` (YAML keys, ``negate`` as an int,
  ``mode`` optional, defaulting to trinary) and ``map_server/src/image_loader.cpp``
  (``loadMapFromFile``): the mean of the channels, ``occ = (255 - avg) / 255`` in double,
  ``occ > occ_th`` occupied (100), ``occ < free_th`` free (0), else unknown (-1) in trinary mode.
* ``nav2``: ros-navigation/navigation2 ``nav2_map_server/src/map_io.cpp`` since #5071 (2025):
  ``loadMapYaml`` (``negate`` an int or a bool, ``mode`` optional) and ``loadMapFromFile``:
  grey / 255 in float32, ``1 - grey`` unless negate, ``>= occupied_thresh`` occupied,
  ``<= free_thresh`` free, else unknown.
* ``nav2_humble``: the same file before #5071 (Humble, Iron, Jazzy): per pixel in double,
  ``occupied_thresh < occ`` occupied, ``occ < free_thresh`` free.

Modes trinary, scale and raw are followed, with an alpha channel where the image has one (the
nav2 source read for the 2025 rule: navigation2 ``a3a9704``, 2026-08-21).

Each returns the ``nav_msgs/OccupancyGrid`` data as an (H, W) int8 array in grid order
(row 0 = the image's bottom row, as the loaders flip it), with 100 / 0 / -1.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

RULES = ("ros1", "nav2", "nav2_humble")


def _yaml(path: Path, rule: str) -> dict:
    doc = yaml.safe_load(path.read_text())
    for key in ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"):
        assert key in doc, f"{path}: map_server needs '{key}'"
    assert len(doc["origin"]) == 3, f"{path}: origin must have 3 elements"
    negate = doc["negate"]
    if rule == "ros1":  # doc["negate"] >> int: a bool fails in yaml-cpp
        assert isinstance(negate, int) and not isinstance(negate, bool), f"{path}: ROS1 reads negate as an int"
    mode = doc.get("mode", "trinary")
    assert mode in ("trinary", "scale", "raw"), f"{path}: unknown mode {mode!r}"
    return {**doc, "negate": int(negate), "mode": mode, "image_path": path.parent / doc["image"]}


def _channels(img: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(H, W, C) pixel values in the file's channel order R, G, B(, A), and the alpha channel or None."""
    if img.ndim == 2:
        return img[..., None].astype(np.float64), None
    rgb = img[..., [2, 1, 0]] if img.shape[2] >= 3 else img[..., :1]  # OpenCV reads BGR(A)
    if img.shape[2] == 4:
        return np.concatenate([rgb, img[..., 3:4]], axis=2).astype(np.float64), img[..., 3].astype(np.float64)
    return rgb.astype(np.float64), None


def load(yaml_path: str | Path, rule: str) -> np.ndarray:
    """The OccupancyGrid data map_server (``rule``) publishes for this map, in any mode."""
    doc = _yaml(Path(yaml_path), rule)
    img = cv2.imread(str(doc["image_path"]), cv2.IMREAD_UNCHANGED)
    assert img is not None, f"cannot read {doc['image_path']}"
    assert img.dtype == np.uint8, "semmap writes 8-bit images"
    chans, alpha = _channels(img)
    mode, negate = doc["mode"], doc["negate"]
    occ_t, free_t = float(doc["occupied_thresh"]), float(doc["free_thresh"])
    if rule == "ros1":
        # image_loader.cpp: the mean of all channels in trinary mode or without alpha, else of all but
        # the last; alpha = the last channel's byte (1 for one channel); negate flips the mean
        n = chans.shape[2]
        avg = chans.mean(axis=2) if (mode == "trinary" or alpha is None) else chans[..., :n - 1].mean(axis=2)
        a = np.ones(avg.shape) if n == 1 else chans[..., n - 1]
        if negate:
            avg = 255.0 - avg
        if mode == "raw":
            out = avg.astype(np.uint8).view(np.int8)  # unsigned char value = color_avg; stored as int8
            return np.flipud(out)
        occ = (255.0 - avg) / 255.0
        out = np.full(avg.shape, -1, np.int16)
        between = ~(occ > occ_t) & ~(occ < free_t)
        if mode == "scale":
            ratio = (occ - free_t) / (occ_t - free_t)
            scaled = np.trunc(99.0 * ratio)  # unsigned char value = 99 * ratio
            out = np.where(between & ~(a < 1.0), scaled, out)
        out = np.where(occ < free_t, 0, out)
        out = np.where(occ > occ_t, 100, out)  # checked first in the C++: occupied wins
        return np.flipud(out.astype(np.int8))
    if rule == "nav2":
        # map_io.cpp since #5071: Magick's grey conversion (R = G = B here), float32, inclusive
        grey = chans[..., 0].astype(np.uint8)
        if mode == "raw":
            out = grey.view(np.int8).astype(np.int16)  # cast<int8_t>, outside [0, 100] unknown
            out = np.where((out < 0) | (out > 100), -1, out)
            return np.flipud(out.astype(np.int8))
        norm = grey.astype(np.float32) / np.float32(255.0)
        if not negate:
            norm = np.float32(1.0) - norm
        o32, f32 = np.float32(occ_t), np.float32(free_t)
        out = np.full(grey.shape, -1, np.int16)
        out[norm >= o32] = 100
        out[norm <= f32] = 0  # applied after occupied in the C++: free wins
        if mode == "scale":
            mid = (norm > f32) & (norm < o32)
            scaled = np.round((norm - f32) / (o32 - f32) * np.float32(100.0))
            out[mid] = scaled[mid]
        if alpha is not None:
            out[alpha < 255] = -1  # any alpha below 255 is unknown, in every mode but raw
        return np.flipud(out.astype(np.int8))
    if rule == "nav2_humble":
        # map_io.cpp before #5071: per pixel in double; in trinary mode an image with alpha averages it
        # in; in scale mode a pixel that is not opaque is unknown, checked first
        ch = chans[..., :3] if chans.shape[2] >= 3 else chans[..., :1]
        if mode == "trinary" and alpha is not None:
            ch = np.concatenate([ch, alpha[..., None]], axis=2)
        shade = ch.mean(axis=2) / 255.0
        if mode == "raw":
            v = np.round(shade * 255.0)
            out = np.where((v >= 0) & (v <= 100), v, -1)
            return np.flipud(out.astype(np.int8))
        occ = shade if negate else 1.0 - shade
        out = np.full(shade.shape, -1, np.int16)
        if mode == "scale":
            ratio = (occ - free_t) / (occ_t - free_t)
            out = np.rint(ratio * 100.0).astype(np.int16)
        out = np.where(occ < free_t, 0, out)
        out = np.where(occ_t < occ, 100, out)
        if mode == "trinary":
            out = np.where(~(occ_t < occ) & ~(occ < free_t), -1, out)
        if mode == "scale" and alpha is not None:
            out = np.where(alpha < 255, -1, out)
        return np.flipud(out.astype(np.int8))
    raise ValueError(rule)
