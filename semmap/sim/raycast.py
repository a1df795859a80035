"""Exact 2D ray casting against extruded convex polygons, vectorised with numpy.

A :class:`PartSet` flattens many :class:`~semmap.sim.world.Part` into edge arrays.
:func:`first_hit` gives the nearest edge per ray (the 2D LiDAR);
:func:`part_intervals` gives, per ray and part, the distances where the ray
enters and leaves the part's footprint (the camera renderer needs both, to see
table tops from above and people behind table legs).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .world import Part

__all__ = ["PartSet", "first_hit", "part_intervals"]

_EPS = 1e-9


@dataclass(frozen=True)
class PartSet:
    """Parts flattened into edges. Part ``p`` owns edges ``start[p]:start[p+1]``."""

    a: NDArray[np.float64]  # (M, 2) edge start points
    b: NDArray[np.float64]  # (M, 2) edge end points
    edge_part: NDArray[np.intp]  # (M,) owning part of each edge
    start: NDArray[np.intp]  # (P + 1,) first edge of each part, plus M
    z_min: NDArray[np.float64]  # (P,)
    z_max: NDArray[np.float64]  # (P,)
    color: NDArray[np.uint8]  # (P, 3)
    owner: NDArray[np.intp]  # (P,) caller-defined owner index (object table row)
    centre: NDArray[np.float64]  # (P, 2) bounding-circle centres
    radius: NDArray[np.float64]  # (P,) bounding-circle radii

    @property
    def n_parts(self) -> int:
        return int(self.z_min.size)

    @property
    def n_edges(self) -> int:
        return int(self.a.shape[0])

    @classmethod
    def build(cls, parts: Sequence[Part], owners: Sequence[int]) -> PartSet:
        """Flatten validated parts; ``owners[i]`` is a caller-defined index for part i."""
        return cls.from_raw([(p.polygon, p.z_min, p.z_max, p.color) for p in parts], owners)

    @classmethod
    def from_raw(cls, parts: Sequence[tuple[NDArray[np.float64], float, float, tuple[int, int, int]]],
                 owners: Sequence[int]) -> PartSet:
        """Flatten (polygon, z_min, z_max, colour) tuples of convex CCW polygons (not re-validated)."""
        if len(parts) != len(owners):
            raise ValueError("one owner per part")
        if not parts:
            z = np.zeros(0)
            return cls(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.intp), np.zeros(1, np.intp),
                       z, z, np.zeros((0, 3), np.uint8), np.zeros(0, np.intp), np.zeros((0, 2)), z)
        polys = [p[0] for p in parts]
        counts = np.array([len(p) for p in polys], dtype=np.intp)
        a = np.concatenate(polys)
        idx = np.arange(a.shape[0])
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
        nxt = idx + 1
        nxt[start[1:] - 1] = start[:-1]  # each polygon closes on its first vertex
        b = a[nxt]
        part_of_edge = np.repeat(np.arange(len(parts), dtype=np.intp), counts)
        lo = np.minimum.reduceat(a, start[:-1], axis=0)
        hi = np.maximum.reduceat(a, start[:-1], axis=0)
        return cls(
            a=a,
            b=b,
            edge_part=part_of_edge,
            start=start,
            z_min=np.array([p[1] for p in parts], dtype=np.float64),
            z_max=np.array([p[2] for p in parts], dtype=np.float64),
            color=np.array([p[3] for p in parts], dtype=np.uint8).reshape(-1, 3),
            owner=np.asarray(owners, dtype=np.intp),
            centre=0.5 * (lo + hi),
            radius=0.5 * np.hypot(*(hi - lo).T),
        )

    def select(self, keep: NDArray[np.bool_]) -> PartSet:
        """The subset of parts where ``keep`` is true (edges follow their parts)."""
        keep = np.asarray(keep, dtype=bool)
        if keep.all():
            return self
        counts = np.diff(self.start)[keep]
        edge_keep = np.repeat(keep, np.diff(self.start))
        return PartSet(
            a=self.a[edge_keep],
            b=self.b[edge_keep],
            edge_part=np.repeat(np.arange(int(keep.sum()), dtype=np.intp), counts),
            start=np.concatenate([[0], np.cumsum(counts)]).astype(np.intp),
            z_min=self.z_min[keep],
            z_max=self.z_max[keep],
            color=self.color[keep],
            owner=self.owner[keep],
            centre=self.centre[keep],
            radius=self.radius[keep],
        )

    def near(self, origin: Sequence[float], max_range: float) -> PartSet:
        """Parts whose bounding circle comes within ``max_range`` of ``origin``."""
        d = np.hypot(self.centre[:, 0] - origin[0], self.centre[:, 1] - origin[1]) - self.radius
        return self.select(d <= max_range)

    def at_height(self, z: float) -> PartSet:
        """Parts cut by the horizontal plane at height ``z`` (what a 2D LiDAR sees)."""
        return self.select((self.z_min <= z) & (self.z_max >= z))

    @staticmethod
    def concat(sets: Sequence[PartSet]) -> PartSet:
        sets = [s for s in sets if s.n_parts]
        if not sets:
            return PartSet.build([], [])
        if len(sets) == 1:
            return sets[0]
        offsets = np.cumsum([0] + [s.n_parts for s in sets[:-1]])
        edge_offsets = np.cumsum([0] + [s.n_edges for s in sets[:-1]])
        return PartSet(
            a=np.concatenate([s.a for s in sets]),
            b=np.concatenate([s.b for s in sets]),
            edge_part=np.concatenate([s.edge_part + o for s, o in zip(sets, offsets)]),
            start=np.concatenate([s.start[:-1] + o for s, o in zip(sets, edge_offsets)]
                                 + [[sum(s.n_edges for s in sets)]]).astype(np.intp),
            z_min=np.concatenate([s.z_min for s in sets]),
            z_max=np.concatenate([s.z_max for s in sets]),
            color=np.concatenate([s.color for s in sets]),
            owner=np.concatenate([s.owner for s in sets]),
            centre=np.concatenate([s.centre for s in sets]),
            radius=np.concatenate([s.radius for s in sets]),
        )


def _intersect(origins: NDArray[np.float64], dirs: NDArray[np.float64],
               a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance along each ray to each edge a→b, ``inf`` where the ray misses. Shape (R, M).

    ``origins`` is (2,) for a shared origin or (R, 2) for one per ray.
    """
    e = b - a  # (M, 2)
    dx, dy = dirs[:, 0:1], dirs[:, 1:2]  # (R, 1)
    denom = dx * e[:, 1] - dy * e[:, 0]  # (R, M): d × e
    if origins.ndim == 1:
        wx = a[:, 0] - origins[0]
        wy = a[:, 1] - origins[1]
    else:
        wx = a[:, 0] - origins[:, 0:1]
        wy = a[:, 1] - origins[:, 1:2]
    num_t = wx * e[:, 1] - wy * e[:, 0]  # w × e
    num_u = wx * dy - wy * dx  # (R, M): w × d
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / denom
        t = num_t * inv
        u = num_u * inv
    ok = (t > _EPS) & (u >= 0.0) & (u <= 1.0) & np.isfinite(inv)
    return np.where(ok, t, np.inf)


def _segment_distance(p: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    e = b - a
    ll = np.maximum(np.sum(e * e, axis=1), 1e-18)
    u = np.clip(np.sum((p - a) * e, axis=1) / ll, 0.0, 1.0)
    q = a + u[:, None] * e
    return np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])


def first_hit(origins: NDArray[np.float64], dirs: NDArray[np.float64], ps: PartSet,
              chunk: int = 48) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.intp]]:
    """Nearest hit per ray: (distance, part index, edge index); ``inf``, -1, -1 on a miss.

    Rays are processed in chunks of consecutive rays; each chunk only tests the edges
    whose angular extent (seen from the rays' origins) overlaps the chunk's directions.
    """
    origins = np.asarray(origins, dtype=np.float64)
    dirs = np.asarray(dirs, dtype=np.float64)
    n = dirs.shape[0]
    dist = np.full(n, np.inf)
    part = np.full(n, -1, dtype=np.intp)
    edge = np.full(n, -1, dtype=np.intp)
    if ps.n_edges == 0 or n == 0:
        return dist, part, edge
    shared = origins.ndim == 1
    centre = origins if shared else origins.mean(axis=0)
    spread = 0.0 if shared else float(np.max(np.hypot(*(origins - centre).T)))
    # angular extent of every edge seen from the centre, padded for moving origins
    th_a = np.arctan2(ps.a[:, 1] - centre[1], ps.a[:, 0] - centre[0])
    th_b = np.arctan2(ps.b[:, 1] - centre[1], ps.b[:, 0] - centre[0])
    delta = np.mod(th_b - th_a + np.pi, 2 * np.pi) - np.pi
    lo = th_a + np.minimum(delta, 0.0)
    width = np.abs(delta)
    dmin = _segment_distance(centre, ps.a, ps.b)
    close = dmin <= spread + 1e-9
    pad = np.arcsin(np.clip(spread / np.maximum(dmin, 1e-12), 0.0, 1.0)) + 1e-9
    lo = np.where(close, -np.pi, lo - pad)
    width = np.where(close, 2 * np.pi + 1.0, width + 2 * pad)
    ray_ang = np.arctan2(dirs[:, 1], dirs[:, 0])
    two_pi = 2 * np.pi
    for s in range(0, n, chunk):
        sl = slice(s, min(n, s + chunk))
        ang = ray_ang[sl]
        mid = ang[ang.size // 2]
        rel = np.mod(ang - mid + np.pi, two_pi) - np.pi
        s_lo = mid + rel.min()
        s_w = rel.max() - rel.min()
        cand = (np.mod(s_lo - lo, two_pi) <= width) | (np.mod(lo - s_lo, two_pi) <= s_w)
        idx = np.nonzero(cand)[0]
        if idx.size == 0:
            continue
        o = origins if shared else origins[sl]
        t = _intersect(o, dirs[sl], ps.a[idx], ps.b[idx])
        k = np.argmin(t, axis=1)
        best = t[np.arange(t.shape[0]), k]
        hit = np.isfinite(best)
        dist[sl] = best
        part[sl] = np.where(hit, ps.edge_part[idx[k]], -1)
        edge[sl] = np.where(hit, idx[k], -1)
    return dist, part, edge


def part_intervals(origin: NDArray[np.float64], dirs: NDArray[np.float64],
                   ps: PartSet) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Entry and exit distance of every ray through every part's footprint, (R, P) each.

    Rays that miss a part get ``inf`` entry and ``-inf`` exit. A ray starting inside
    a part enters it at 0.
    """
    origin = np.asarray(origin, dtype=np.float64)
    dirs = np.asarray(dirs, dtype=np.float64)
    if ps.n_parts == 0:
        return np.zeros((dirs.shape[0], 0)), np.zeros((dirs.shape[0], 0))
    t = _intersect(origin, dirs, ps.a, ps.b)
    starts = ps.start[:-1]
    t_in = np.minimum.reduceat(t, starts, axis=1)
    t_out = np.maximum.reduceat(np.where(np.isfinite(t), t, -np.inf), starts, axis=1)
    # rays from an origin inside a (convex, CCW) footprint enter it at 0
    e = ps.b - ps.a
    side = e[:, 0] * (origin[1] - ps.a[:, 1]) - e[:, 1] * (origin[0] - ps.a[:, 0])
    inside = np.minimum.reduceat(side, starts) > 0.0
    if inside.any():
        t_in[:, inside] = np.where(np.isfinite(t_out[:, inside]), 0.0, np.inf)
    return t_in, t_out
