"""map_server maps: a PGM/PNG image plus the YAML that ROS ``map_server`` and nav2 load.

semmap writes trinary maps: occupied pixels 0 (black), free 254, unknown 205, the
values ``map_saver`` writes. The image's top row is the highest y; ``origin`` is
the pose of the lower-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..records import GridSpec
from .yamlio import read_yaml, write_yaml

__all__ = ["OCCUPIED", "FREE", "UNKNOWN", "write_map", "read_map", "MapImage"]

OCCUPIED = 0
FREE = 254
UNKNOWN = 205


def write_map(
    yaml_path: str | Path,
    spec: GridSpec,
    occupied: NDArray[np.bool_],
    known: NDArray[np.bool_] | None = None,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.25,
) -> Path:
    """Write a trinary map: ``occupied`` and ``known`` are (H, W) in grid order (row 0 = lowest y).

    The image goes beside the YAML with the same stem (``.pgm``). Returns the YAML path.
    """
    yaml_path = Path(yaml_path)
    occ = np.asarray(occupied, dtype=bool)
    if occ.shape != spec.shape:
        raise ValueError(f"occupancy shape {occ.shape} does not match grid {spec.shape}")
    img = np.full(spec.shape, UNKNOWN, np.uint8)
    kn = np.ones(spec.shape, bool) if known is None else np.asarray(known, dtype=bool)
    img[kn] = FREE
    img[occ] = OCCUPIED
    image_path = yaml_path.with_suffix(".pgm")
    if not cv2.imwrite(str(image_path), np.flipud(img)):
        raise OSError(f"{image_path}: cannot write map image")
    meta = {
        "image": image_path.name,
        "mode": "trinary",
        "resolution": float(spec.resolution),
        "origin": [float(spec.origin_x), float(spec.origin_y), 0.0],
        "negate": 0,
        "occupied_thresh": float(occupied_thresh),
        "free_thresh": float(free_thresh),
    }
    return write_yaml(yaml_path, meta)


@dataclass(frozen=True)
class MapImage:
    """A map read back as map_server interprets it (grid order: row 0 = lowest y)."""

    spec: GridSpec
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    yaw: float

    @property
    def unknown(self) -> NDArray[np.bool_]:
        return ~(self.occupied | self.free)


def read_map(yaml_path: str | Path) -> MapImage:
    """Read a map_server YAML + image the way map_server does (trinary/scale, negate, thresholds)."""
    p = Path(yaml_path)
    meta = read_yaml(p, "map")
    try:
        image = p.parent / str(meta["image"])
        res = float(meta["resolution"])
        ox, oy, yaw = (float(v) for v in meta["origin"])
        negate = int(meta.get("negate", 0))
        occ_t = float(meta["occupied_thresh"])
        free_t = float(meta["free_thresh"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{p}: missing or malformed map key ({exc})") from None
    img = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ConfigError(f"{p}: cannot read map image {image}")
    if img.ndim == 3:
        img = img[:, :, :3].mean(axis=2)
    grey = img.astype(np.float64) / (65535.0 if img.dtype == np.uint16 else 255.0)
    occ_p = grey if negate else 1.0 - grey
    grid = np.flipud(occ_p)
    h, w = grid.shape
    spec = GridSpec(res, ox, oy, w, h)
    return MapImage(spec, grid > occ_t, grid < free_t, yaw)
