"""map_server maps: a PGM/PNG image plus the YAML that ROS ``map_server`` and nav2 load.

semmap writes trinary maps: occupied pixels 0 (black), free 254, unknown 205, the
values ``map_saver`` writes. The image's top row is the highest y; ``origin`` is
the pose of the lower-left pixel.

Both loaders turn a pixel into an occupancy ``p = (255 - v) / 255`` (``negate: 0``) and
compare it with the YAML's thresholds: ROS1's ``map_server`` calls it occupied when
``p > occupied_thresh`` and free when ``p < free_thresh``; nav2's ``map_io`` when
``p >= occupied_thresh`` and ``p <= free_thresh`` (in float32 since 2025). Unknown grey 205
is ``p = 0.196078...``: with the free threshold of a quarter that nav2's examples use, every
unknown cell loads as free, and a planner plans through unexplored space. semmap writes ``free_thresh: 0.196``
and ``occupied_thresh: 0.65``, as ROS1's ``map_saver`` and nav2's trinary saver do, under
which 0, 205 and 254 load as occupied, unknown and free in both loaders
(:func:`check_trinary_thresholds`).
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

__all__ = [
    "FREE",
    "FREE_THRESH",
    "MODES",
    "OCCUPIED",
    "OCCUPIED_THRESH",
    "UNKNOWN",
    "MapImage",
    "check_trinary_thresholds",
    "read_map",
    "write_map",
]

OCCUPIED = 0
FREE = 254
UNKNOWN = 205
#: the thresholds of every trinary map semmap writes (those of ROS1's map_saver and nav2's trinary saver)
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


def check_trinary_thresholds(occupied_thresh: float, free_thresh: float) -> None:
    """Raise ``ValueError`` unless 0, 205 and 254 load as occupied, unknown and free under
    ROS1 map_server's rule (strict, double) and nav2's (inclusive, float32) alike."""
    for v, want in ((OCCUPIED, "occupied"), (UNKNOWN, "unknown"), (FREE, "free")):
        p64 = (255 - v) / 255.0
        p32 = np.float32(1.0) - np.float32(v) / np.float32(255.0)
        ros1 = "occupied" if p64 > occupied_thresh else "free" if p64 < free_thresh else "unknown"
        nav2 = ("occupied" if p32 >= np.float32(occupied_thresh) else
                "free" if p32 <= np.float32(free_thresh) else "unknown")
        if ros1 != want or nav2 != want:
            raise ValueError(f"occupied_thresh {occupied_thresh} / free_thresh {free_thresh}: pixel {v} would "
                             f"load as {ros1} (ROS1 map_server) / {nav2} (nav2), not {want}")


def write_map(
    yaml_path: str | Path,
    spec: GridSpec,
    occupied: NDArray[np.bool_],
    known: NDArray[np.bool_] | None = None,
) -> Path:
    """Write a trinary map: ``occupied`` and ``known`` are (H, W) in grid order (row 0 = lowest y).

    The image goes beside the YAML with the same stem (``.pgm``); cells not ``known`` are
    unknown (205), and load as unknown in ROS1's map_server and nav2's. Returns the YAML path.
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
        raise OSError(0, "cannot write the map image", str(image_path))
    meta = {
        "image": image_path.name,
        "mode": "trinary",
        "resolution": float(spec.resolution),
        "origin": [float(spec.origin_x), float(spec.origin_y), 0.0],
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
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


#: the map modes map_server and nav2 read (the YAML's ``mode``; trinary when it has none)
MODES = ("trinary", "scale", "raw")


def read_map(yaml_path: str | Path) -> MapImage:
    """Read a map_server YAML + image as map_server and nav2 publish it, in any ``mode``:

    * ``trinary`` (the default): the mean of the colour channels ``v`` turns into an occupancy ``p =
      (255 - v) / 255`` (``v / 255`` when ``negate``); occupied when ``p > occupied_thresh``, free
      when ``p < free_thresh``, else unknown. A pixel with an alpha channel below 255 is unknown, as
      nav2 has it;
    * ``scale``: the same ``p``; occupied and free where nav2 publishes 100 and 0 (the thresholds, and
      in-between values that round to them), the values in between (1-99) neither;
    * ``raw``: the pixel value is the published occupancy itself, 0-100 (``negate`` aside, as nav2
      ignores it there), judged by the YAML's thresholds on ``v / 100`` as a trinary map would be;
      any other value is unknown (map_saver's 255).

    Errors are one line naming the YAML and the key."""
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
    mode = meta.get("mode", "trinary")
    if mode not in MODES:
        raise ConfigError(f"{p}: mode {mode!r} is not a map_server mode ({', '.join(MODES)})")
    img = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ConfigError(f"{p}: cannot read map image {image}")
    top = 65535.0 if img.dtype == np.uint16 else 255.0  # the pixel's full value
    alpha = None
    if img.ndim == 3:
        if img.shape[2] in (2, 4):  # grey or colour with an alpha channel, last
            alpha = img[:, :, -1].astype(np.float64) / top
        img = img[:, :, :3 if img.shape[2] >= 3 else 1].mean(axis=2)
    grey = img.astype(np.float64) / top
    if mode == "raw":
        v = np.round(grey * 255.0)
        occ_p = np.where(v <= 100.0, v / 100.0, np.nan)
    else:
        occ_p = grey if negate else 1.0 - grey
        if alpha is not None:
            occ_p = np.where(alpha < 1.0, np.nan, occ_p)
    grid = np.flipud(occ_p)
    h, w = grid.shape
    spec = GridSpec(res, ox, oy, w, h)
    if mode == "scale":
        # nav2 publishes round(100 (p - free) / (occupied - free)) in between: 0 is free, 100 occupied
        shade = np.round(100.0 * (grid - free_t) / (occ_t - free_t))
        return MapImage(spec, shade >= 100.0, shade <= 0.0, yaw)
    return MapImage(spec, grid > occ_t, grid < free_t, yaw)  # (NaN, unknown, is neither)
