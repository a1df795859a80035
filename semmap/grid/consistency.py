"""A truth-free score of how well a tour's scans agree with the map built from them.

Real recordings have no ground truth, yet a map whose poses drift shows it: walls come out thick
or doubled, and beams end beside the walls instead of on them. Two figures say so, for every build:

* **endpoints on the map**: the share of beam endpoints (returns not painted as people), placed
  at their scan's final pose, that land within one cell of an occupied cell of the final map;
* **wall thickness**: the mean thickness of the occupied structures, ``2 · area / perimeter``
  (a wall one cell thick and long scores one cell; a doubled or smeared wall more).

Both compare modes on the same tour (odometry, ICP, fused; with and without loop closure); they
do not compare different tours. :class:`EndpointSample` keeps a bounded sample of the endpoints
in their scans' base frames, so it can be placed again after loop closure moves the poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..records import GridSpec, Mobility, PaintedScan

__all__ = ["ConsistencyScore", "EndpointSample", "consistency_score", "wall_thickness"]


class EndpointSample:
    """A bounded, evenly spread sample of beam endpoints in their scans' base frames.

    Up to ``per_scan`` returns of every scan are kept (evenly spaced along the sweep, dynamic ones
    left out). When ``capacity`` points are held, every other kept scan is dropped and from then on
    only every second scan is taken (and so on), so memory stays bounded on any tour while the
    sample stays spread over all of it.
    """

    def __init__(self, per_scan: int = 32, capacity: int = 1_000_000) -> None:
        self.per_scan = max(int(per_scan), 1)
        self.capacity = max(int(capacity), self.per_scan)
        self._xy = np.zeros((self.capacity, 2), np.float32)
        self._scan = np.zeros(self.capacity, np.int64)
        self._n = 0
        self._stride = 1

    def __len__(self) -> int:
        return self._n

    def add(self, index: int, scan: PaintedScan) -> None:
        """Offer scan number ``index`` (scans are numbered in the order they are registered)."""
        if index % self._stride:
            return
        keep = scan.hit & (scan.mobility != int(Mobility.DYNAMIC))
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            return
        if idx.size > self.per_scan:
            idx = idx[np.linspace(0, idx.size - 1, self.per_scan).round().astype(np.intp)]
        while self._n + idx.size > self.capacity:
            self._thin()
            if index % self._stride:
                return
        m = idx.size
        self._xy[self._n:self._n + m] = scan.points[idx]
        self._scan[self._n:self._n + m] = index
        self._n += m

    def _thin(self) -> None:
        self._stride *= 2
        keep = (self._scan[:self._n] % self._stride) == 0
        m = int(keep.sum())
        self._xy[:m] = self._xy[:self._n][keep]
        self._scan[:m] = self._scan[:self._n][keep]
        self._n = m

    @property
    def base_points(self) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
        """The sampled points (M, 2) in their base frames, and their scan numbers (M,)."""
        return self._xy[:self._n].copy(), self._scan[:self._n].copy()

    def in_map(self, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        """The sampled points (M, 2) in the map frame, each at its scan's pose in ``poses`` (N, 3)."""
        return place(self._xy[:self._n], self._scan[:self._n], poses)


def place(xy: NDArray[np.floating], scan: NDArray[np.integer], poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Base-frame points ``xy`` (M, 2) of scans ``scan`` (M,) at ``poses[scan]``: (M, 2) map frame."""
    p = np.asarray(poses, np.float64).reshape(-1, 3)[np.asarray(scan, np.intp)]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    x, y = np.asarray(xy, np.float64).T
    return np.column_stack([p[:, 0] + c * x - s * y, p[:, 1] + s * x + c * y])


@dataclass(frozen=True)
class ConsistencyScore:
    """How well the scans agree with the map (see the module docstring)."""

    endpoints_on_map: float  # share, 0..1
    wall_thickness_m: float
    endpoints_sampled: int

    def as_dict(self) -> dict[str, float | int]:
        return {"endpoints_on_map": round(self.endpoints_on_map, 4),
                "wall_thickness_m": round(self.wall_thickness_m, 4),
                "endpoints_sampled": self.endpoints_sampled}


def consistency_score(points: NDArray[np.float64], occupied: NDArray[np.bool_], spec: GridSpec,
                      tolerance_cells: int = 1) -> ConsistencyScore:
    """Score map-frame endpoints ``points`` (M, 2) against the ``occupied`` cells of the map ``spec``."""
    import cv2

    occ = np.asarray(occupied, bool)
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    if pts.shape[0] == 0 or not occ.any():
        return ConsistencyScore(0.0, wall_thickness(occ, spec.resolution), int(pts.shape[0]))
    k = 2 * tolerance_cells + 1
    near = cv2.dilate(occ.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    col = np.floor((pts[:, 0] - spec.origin_x) / spec.resolution).astype(np.int64)
    row = np.floor((pts[:, 1] - spec.origin_y) / spec.resolution).astype(np.int64)
    inside = (col >= 0) & (col < occ.shape[1]) & (row >= 0) & (row < occ.shape[0])
    on = np.zeros(pts.shape[0], bool)
    on[inside] = near[row[inside], col[inside]]
    return ConsistencyScore(float(on.mean()), wall_thickness(occ, spec.resolution), int(pts.shape[0]))


def wall_thickness(occupied: NDArray[np.bool_], resolution: float) -> float:
    """Mean thickness (m) of the occupied structures: their area over their length.

    The length of a structure is half its boundary (outside and holes, through the boundary cells'
    centres as OpenCV traces it) plus one cell, so a straight run ``t`` cells thick scores ``t``
    cells at any length, a closed room wall too, and a lone cell one. 0 for a map without any.
    """
    import cv2

    occ = np.ascontiguousarray(np.asarray(occupied, bool).astype(np.uint8))
    if not occ.any():
        return 0.0
    contours, hierarchy = cv2.findContours(occ, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    outer = int(np.count_nonzero(hierarchy[0][:, 3] < 0))
    length = sum(cv2.arcLength(c, True) for c in contours) / 2.0 + outer
    return float(occ.sum()) / length * resolution
