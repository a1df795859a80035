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


def load(yaml_path: str | Path, rule: str) -> np.ndarray:
    """The OccupancyGrid data map_server (``rule``) publishes for this map."""
    doc = _yaml(Path(yaml_path), rule)
    img = cv2.imread(str(doc["image_path"]), cv2.IMREAD_UNCHANGED)
    assert img is not None, f"cannot read {doc['image_path']}"
    assert img.dtype == np.uint8, "semmap writes 8-bit images"
    assert doc["mode"] == "trinary", "semmap's map folder maps are trinary"
    grey = img.astype(np.float64) if img.ndim == 2 else img[..., :3].mean(axis=2)
    occ_t, free_t = float(doc["occupied_thresh"]), float(doc["free_thresh"])
    out = np.full(grey.shape, -1, np.int8)
    if rule == "ros1":
        avg = 255.0 - grey if doc["negate"] else grey
        occ = (255.0 - avg) / 255.0
        out[occ < free_t] = 0
        out[occ > occ_t] = 100  # checked first in the C++: occupied wins
    elif rule == "nav2":
        norm = grey.astype(np.float32) / np.float32(255.0)
        if not doc["negate"]:
            norm = np.float32(1.0) - norm
        out[norm >= np.float32(occ_t)] = 100
        out[norm <= np.float32(free_t)] = 0  # applied after occupied in the C++: free wins
    elif rule == "nav2_humble":
        shade = grey / 255.0
        occ = shade if doc["negate"] else 1.0 - shade
        out[occ < free_t] = 0
        out[occ_t < occ] = 100
    else:
        raise ValueError(rule)
    return np.flipud(out)
