"""Writing a layer as a map_server map (image + YAML) that loads as semmap meant it.

A layer says, per cell: occupied, free, or neither, and (where a scan observed the cell) how
likely it is occupied. The image must make each map_server load the same three states back, in
every mode, whatever the thresholds and ``negate``. Three loaders are honoured, each from its
source:

* ROS1 ``map_server`` (``image_loader.cpp``): the mean of the colour channels (the alpha channel
  left out, except in trinary mode), negated first when ``negate``; ``occ = (255 - v) / 255`` in
  double; ``occ > occupied_thresh`` occupied, ``occ < free_thresh`` free, else unknown in trinary
  mode, unknown in scale mode when alpha is 0, else ``99 * ratio`` truncated. Raw mode: the grey
  value itself (after negate), 255 reading as -1.
* nav2 ``map_io`` since 2025 (#5071): grey / 255 in float32, ``1 - grey`` unless negate,
  ``>= occupied_thresh`` occupied, ``<= free_thresh`` free, in scale mode ``round(ratio * 100)``
  in between, and any alpha below 255 unknown. Raw mode: the grey value as int8, outside 0..100
  unknown; ``negate`` is ignored.
* nav2 before #5071 (Humble, Iron, Jazzy): per pixel in double, strict comparisons, in scale mode
  the alpha checked first and ``rint(ratio * 100)`` in between.

So semmap picks, for each state, grey levels that every one of them reads as that state
(:func:`levels`), and refuses thresholds under which no such level exists. Trinary maps use
map_saver's levels (0 / 205 / 254, mirrored under ``negate``) whenever they qualify. Scale maps
keep each observed cell's probability as its grey level, moved just enough to land in its
state's band; never-observed cells are transparent (RGBA PNG: scale mode needs PNG). Raw maps
write 0 for free, 100 for occupied, the probability in per cent (1-99) for observed cells left
undecided, and 255 (unknown) for the rest; ``negate`` is refused in raw mode, because ROS1 applies
it there and nav2 does not.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..io.yamlio import write_yaml
from ..records import GridSpec

__all__ = ["FORMATS", "MODES", "MapEncoding", "encode", "levels", "write_layer"]

MODES = ("trinary", "scale", "raw")
FORMATS = ("pgm", "png")

# the state of a cell, as the loaders report it
_OCC, _FREE, _MID, _DISAGREE = 0, 1, 2, 3


@dataclass(frozen=True)
class MapEncoding:
    """How a layer is written: map_server ``mode``, thresholds, ``negate`` and the image format."""

    mode: str = "trinary"
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196
    negate: bool = False
    image_format: str = "pgm"

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.image_format not in FORMATS:
            raise ConfigError(f"image format must be one of {', '.join(FORMATS)}, got {self.image_format!r}")
        if not 0.0 <= self.free_thresh < self.occupied_thresh <= 1.0:
            raise ConfigError(f"thresholds must satisfy 0 <= free_thresh < occupied_thresh <= 1, got free_thresh "
                              f"{self.free_thresh} and occupied_thresh {self.occupied_thresh}")
        if self.mode == "scale" and self.image_format != "png":
            raise ConfigError("mode scale needs PNG: its unknown cells are transparent, and PGM has no alpha")
        if self.mode == "raw" and self.negate:
            raise ConfigError("negate does not apply to mode raw: ROS1 map_server applies it there and nav2 "
                              "ignores it, so the two would load different maps")
        if self.mode != "raw":
            levels(self)  # thresholds no map_server reads alike are refused here, before any work

    def yaml_fields(self) -> dict[str, object]:
        return {"mode": self.mode, "negate": int(self.negate), "occupied_thresh": float(self.occupied_thresh),
                "free_thresh": float(self.free_thresh)}


def _bands(enc: MapEncoding) -> NDArray[np.int8]:
    """(3, 256): the state (occupied, free, between) each grey level loads as, per loader (ROS1, nav2,
    nav2 before #5071); a level is usable for a state only where all three agree."""
    v = np.arange(256, dtype=np.float64)
    out = np.empty((3, 256), np.int8)
    # ROS1: negate flips the level before occ = (255 - v) / 255
    avg = 255.0 - v if enc.negate else v
    occ = (255.0 - avg) / 255.0
    out[0] = np.where(occ > enc.occupied_thresh, _OCC, np.where(occ < enc.free_thresh, _FREE, _MID))
    # nav2 since #5071: float32, inclusive; free is applied after occupied
    g = v.astype(np.float32) / np.float32(255.0)
    n = g if enc.negate else np.float32(1.0) - g
    st = np.full(256, _MID, np.int8)
    st[n >= np.float32(enc.occupied_thresh)] = _OCC
    st[n <= np.float32(enc.free_thresh)] = _FREE
    out[1] = st
    # nav2 before #5071: double, strict
    shade = v / 255.0
    occ2 = shade if enc.negate else 1.0 - shade
    out[2] = np.where(enc.occupied_thresh < occ2, _OCC, np.where(occ2 < enc.free_thresh, _FREE, _MID))
    if enc.mode == "scale":
        # a level between the thresholds must load as 1..99 in each: ROS1 truncates 99 * ratio, nav2
        # rounds 100 * ratio (float32 since #5071)
        span = enc.occupied_thresh - enc.free_thresh
        ros1 = np.trunc(99.0 * (occ - enc.free_thresh) / span)
        f32 = np.float32(enc.free_thresh)
        nav2 = np.round((n - f32) / (np.float32(enc.occupied_thresh) - f32) * np.float32(100.0))
        humble = np.rint((occ2 - enc.free_thresh) / span * 100.0)
        bad = (ros1 < 1) | (ros1 > 99) | (nav2 < 1) | (nav2 > 99) | (humble < 1) | (humble > 99)
        out[:, bad & (out == _MID).all(axis=0)] = _DISAGREE
    return out


def levels(enc: MapEncoding) -> tuple[NDArray[np.int16], NDArray[np.int16], NDArray[np.int16]]:
    """For trinary and scale maps: a lookup (256,) per state (occupied, free, between) taking any
    grey level to the nearest level every loader reads as that state. Raises ``ConfigError`` when
    the thresholds leave a state no level."""
    b = _bands(enc)
    out = []
    for state, name in ((_OCC, "occupied"), (_FREE, "free"), (_MID, "unknown" if enc.mode == "trinary" else
                                                             "between the thresholds")):
        ok = np.flatnonzero((b == state).all(axis=0))
        if ok.size == 0:
            raise ConfigError(f"occupied_thresh {enc.occupied_thresh} / free_thresh {enc.free_thresh}: no grey "
                              f"level loads as {name} in every map_server (ROS1, nav2, nav2 before 2025); "
                              f"widen the gap between the thresholds")
        v = np.arange(256)
        nearest = ok[np.abs(v[:, None] - ok[None, :]).argmin(axis=1)]
        out.append(nearest.astype(np.int16))
    return out[0], out[1], out[2]


def _grey(p: NDArray[np.float32], negate: bool) -> NDArray[np.int16]:
    """The grey level whose map_server occupancy is ``p`` (``1 - v/255``, or ``v/255`` under negate)."""
    q = np.clip(np.nan_to_num(p, nan=0.5), 0.0, 1.0)
    v = np.rint(255.0 * (q if negate else 1.0 - q))
    return v.astype(np.int16)


def encode(enc: MapEncoding, occupied: NDArray[np.bool_], free: NDArray[np.bool_],
           prob: NDArray[np.float32]) -> NDArray[np.uint8]:
    """The image (grid order: row 0 = lowest y) for a layer: ``occupied`` and ``free`` (H, W)
    disjoint, ``prob`` (H, W) the probability of occupancy, NaN where no scan observed the cell.
    (H, W) uint8 for trinary and raw, (H, W, 4) RGBA for scale."""
    occ = np.asarray(occupied, bool)
    fr = np.asarray(free, bool) & ~occ
    observed = np.isfinite(prob)
    mid = ~occ & ~fr
    if enc.mode == "raw":
        img = np.full(occ.shape, 255, np.uint8)
        img[fr] = 0
        img[occ] = 100
        und = mid & observed
        img[und] = np.clip(np.rint(100.0 * prob[und]), 1, 99).astype(np.uint8)
        return img
    lo_occ, lo_free, lo_mid = levels(enc)
    if enc.mode == "trinary":
        conv = (255, 1, 50) if enc.negate else (0, 254, 205)  # map_saver's levels, mirrored under negate
        img = np.full(occ.shape, lo_mid[conv[2]], np.uint8)
        img[fr] = lo_free[conv[1]]
        img[occ] = lo_occ[conv[0]]
        return img
    grey = _grey(prob, enc.negate)
    out = np.where(occ, lo_occ[grey], np.where(fr, lo_free[grey], lo_mid[grey])).astype(np.uint8)
    alpha = np.where(mid & ~observed, 0, 255).astype(np.uint8)
    # never observed: mid-grey, transparent (nav2's own saver writes 0.5 grey, transparent)
    out[mid & ~observed] = lo_mid[128]
    return np.dstack([out, out, out, alpha])


def write_layer(yaml_path: Path, spec: GridSpec, enc: MapEncoding, occupied: NDArray[np.bool_],
                free: NDArray[np.bool_], prob: NDArray[np.float32]) -> Path:
    """Write one layer as ``NAME.yaml`` + ``NAME.pgm``/``.png`` beside it; returns the YAML path."""
    img = encode(enc, occupied, free, prob)
    image_path = yaml_path.with_suffix("." + enc.image_format)
    flipped = np.flipud(img)
    if flipped.ndim == 3:  # RGBA -> OpenCV's BGRA (grey, so only the channel order of alpha matters)
        flipped = np.asarray(cv2.cvtColor(np.ascontiguousarray(flipped), cv2.COLOR_RGBA2BGRA), np.uint8)
    if not cv2.imwrite(str(image_path), np.ascontiguousarray(flipped)):
        raise OSError(0, "cannot write the map image", str(image_path))
    meta = {"image": image_path.name, "resolution": float(spec.resolution),
            "origin": [float(spec.origin_x), float(spec.origin_y), 0.0], **enc.yaml_fields()}
    return write_yaml(yaml_path, meta)
