"""Ground-truth maps of a simulated world at LiDAR height."""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np
from numpy.typing import NDArray

from ..records import GridSpec, Mobility
from .world import World

__all__ = ["grid_for_world", "rasterise", "occupancy_layers", "people_swept", "change_mask"]


def grid_for_world(world: World, resolution: float, margin: float) -> GridSpec:
    return GridSpec.covering(*world.bounds(margin), resolution)


def rasterise(spec: GridSpec, polygons: Iterable[NDArray[np.float64]]) -> NDArray[np.bool_]:
    """Cells (grid order) covered by polygons; thin parts still mark the cell they stand in."""
    img = np.zeros(spec.shape, np.uint8)
    pts = [np.round(((p - [spec.origin_x, spec.origin_y]) / spec.resolution - 0.5) * 16).astype(np.int32)
           for p in polygons]
    if pts:
        cv2.fillPoly(img, pts, 1, lineType=cv2.LINE_8, shift=4)
        # a part thinner than a cell must still occupy the cell holding its centre
        for p in polygons:
            c = p.mean(axis=0)
            r, k = spec.world_to_cell(c)
            if 0 <= r < spec.height and 0 <= k < spec.width:
                img[r, k] = 1
    return img.astype(bool)


def occupancy_layers(world: World, spec: GridSpec, height: float) -> dict[str, NDArray[np.bool_]]:
    """Static and semi-static occupancy of the plane at ``height`` (what a 2D LiDAR can hit)."""
    layers = {}
    for name, mob in (("static", Mobility.STATIC), ("semi_static", Mobility.SEMI_STATIC)):
        polys = [p.polygon for o in world.objects if o.mobility == mob for p in o.parts if p.spans(height)]
        layers[name] = rasterise(spec, polys)
    layers["occupancy"] = layers["static"] | layers["semi_static"]
    return layers


def people_swept(world: World, spec: GridSpec, duration_s: float, radius: float,
                 step_s: float = 0.1) -> NDArray[np.bool_]:
    """Every cell a person's body disc covered at some time during the tour."""
    swept = np.zeros(spec.shape, np.uint8)
    for t in np.arange(0.0, duration_s + 1e-9, step_s):
        polys = [p.footprint(float(t), radius) for p in world.people]
        if polys:
            swept |= rasterise(spec, polys).astype(np.uint8)
    return swept.astype(bool)


def change_mask(before: NDArray[np.bool_], after: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """0 none, 1 added (occupied only after), 2 removed (occupied only before)."""
    out = np.zeros(before.shape, np.uint8)
    out[after & ~before] = 1
    out[before & ~after] = 2
    return out
