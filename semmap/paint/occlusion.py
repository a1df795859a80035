"""The background-line occlusion filter: points the camera cannot see lose the mask's label.

**The fault.** The LiDAR and the camera look from different places (on many robots the
LiDAR sits at a front corner, the camera at the front centre). A wall point the LiDAR sees
past the edge of a person can lie, from the camera's viewpoint, *behind* that person: it
projects onto the person's mask and is painted ``dynamic``. In the image it shows up as a
second, farther line of points inside the mask. The research's rule: a solid object
reprojects at most one line, and only background points are hit, so within a mask only
the nearer line keeps the mask's label.

**The filter** decides visibility from the camera's own viewpoint, in the LiDAR plane
(points at the image time, in the base frame, seen from the camera centre projected into
that plane). A point ``p`` on a mask with label ``L`` is *hidden* when LiDAR points of the
same mask lie nearer the camera and cover it:

1. **Same ray.** A point ``q`` labelled ``L`` whose bearing from the camera is within
   ``q``'s angular footprint of ``p``'s and which is nearer by at least the depth margin
   (``depth_margin + depth_margin_rel · distance``, which absorbs range noise and the depth
   of the object itself). The footprint is the surface patch a LiDAR beam samples (one beam
   spacing at ``q``'s range, seen from the camera) widened by ``ray_width_deg``, so the gaps
   between the scan points of a continuous surface do not let background points through.
2. **Bridged gaps.** Objects seen only in parts (a person's two legs, a table's legs) leave
   wider gaps at LiDAR height. ``p`` is also hidden when the nearest such nearer ``L`` points
   on its left and on its right are at most ``max_gap`` apart *and* the mask covers ``p``'s
   pixel row between ``p`` and each of them: the object that covers ``p``'s pixel spans
   the gap between them.
3. **Past the outermost point.** Above LiDAR height an object reaches past its legs (a
   chair's seat, a table's top, a person's arms), and a mask spills a few pixels past its
   object. ``p`` is also hidden when a nearer ``L`` point lies at most ``overhang`` to the
   side of ``p``'s ray or projects at most ``edge_px`` columns away, and the mask covers
   ``p``'s pixel row between the two.
4. **A background line across the mask.** ``p``'s surface (neighbouring scan points with
   steps under ``line_step``) runs on, across the shadows of nearer objects, to points off
   the mask, so it is structure the mask overlaps, and a point of the mask stands in front
   of it by at least ``line_depth_margin`` (less than the depth margin: a bed pushed against
   a wall), on the same connected region of the mask.
5. **Deeper than the object.** An object of a class with a typical size (``sizes:`` in the
   class table) spans at most ``paint.occlusion.object_extent`` times that size. ``p`` is hidden when a
   nearer point ``q`` of the same connected region of the mask lies farther from ``p`` than
   that span, and no farther than it to the side of ``p``'s ray: ``p`` cannot be the object
   ``q`` is on, and that object stands in front of ``p``. This is the wall or cabinet seen
   under a bed's frame from across the room; rules 2-4 do not reach it when that stretch of
   wall stands in front of the wall beside it (a cabinet's face), or when the bed's other
   legs are out of the LiDAR's sight.

6. **Off every mask** (``background``). A point on no mask (painted ``static``) is hidden when
   another point on no mask stands on its viewing ray, nearer by the depth margin, and off its own
   surface (the line through it and a neighbour in the scan: a wall seen at a grazing angle does
   not hide itself): what a LiDAR at a corner of the robot sees past the end of a wall that the
   camera's rays hit.

A run of scan points nearer than the points on either side of it (a chair's rear leg seen
through the gap between its front legs) is a foreground object to the LiDAR; only rules 1, 5 and
6 may hide it.

Hidden points become ``unknown`` (not ``static``: the camera says nothing about them). The
occluding points must carry the same label as ``p``: the label image shows one surface per
pixel, and a nearer point of another class says nothing about what ``p``'s pixel shows.
Points that project below or above the image still serve as occluders (their label is read
at the image's edge in their column): an object close to the robot can be out of view at
LiDAR height and still fill the image above it.

Several objects, overlapping or not, are handled per label; the cost is a (masked points ×
labelled points) comparison per scan.
"""

from __future__ import annotations

import weakref
from typing import cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ..config import OcclusionConfig
from ..records import REGION_BASE

__all__ = ["OcclusionConfig", "hidden_points", "mask_regions"]


def hidden_points(xy: NDArray[np.float64], eye: NDArray[np.float64], labels: NDArray[np.intp],
                  uv: NDArray[np.float64] | NDArray[np.integer], targets: NDArray[np.bool_],
                  footprint: NDArray[np.float64], label_image: NDArray[np.integer], p: OcclusionConfig,
                  extent: NDArray[np.float64] | None = None) -> NDArray[np.bool_]:
    """Which points are hidden from the camera by nearer points of the same mask (points off every mask:
    by nearer points off the masks, rule 6).

    ``xy`` (K, 2): the points in the LiDAR plane, every point in front of the camera whose
    column is in the image, where they were at the image time, in any planar frame (the
    painter uses the base frame at the scan's reference time); ``eye`` (2,): the camera
    centre at the image time in the same frame; ``labels`` (K,): the label value under each
    point (0: no mask; read at the image's edge for points above or below it); ``uv`` (K, 2):
    their pixels (column, row), clamped to the image (whole pixels if integers); ``targets``
    (K,): the points to judge (inside the image; off the masks only with ``p.background``);
    ``footprint`` (K,): each point's lateral extent, m (the LiDAR beam spacing at its range);
    ``label_image``: the
    segmentation; ``p``: the filter's settings (``paint.occlusion``; ``filter`` is the caller's
    to check); ``extent``: per label value, the most an object of that label spans, m (inf:
    unbounded, such as structure; None: rule 5 off). Returns a (K,) mask, true only for targets.
    """
    k = xy.shape[0]
    hidden = np.zeros(k, bool)
    if p.background:
        hidden |= _hidden_background(xy, eye, labels, targets, footprint, p)
    on_mask = labels > 0
    t = np.flatnonzero(targets & on_mask)
    if t.size == 0:
        return hidden
    rel = xy - eye
    dist = np.hypot(rel[:, 0], rel[:, 1])
    # occluders: points of the targets' masks, nearer than the farthest target; targets: behind the nearest
    least = min(p.line_depth_margin, p.depth_margin) if p.line_step > 0 else p.depth_margin
    lab_t = labels[t]
    o = np.flatnonzero(on_mask & (dist < dist[t].max() - least))
    lab_o = labels[o]
    if (lab_t == lab_t[0]).all():  # mostly one mask
        o = o[lab_o == lab_t[0]]
    else:
        wanted = np.zeros(int(labels.max()) + 1, bool)
        wanted[lab_t] = True
        o = o[wanted[lab_o]]
    if o.size == 0:
        return hidden
    d_o = dist[o]
    t = t[dist[t] > d_o.min() + least]
    if t.size == 0:
        return hidden
    d_t = dist[t]
    lab_o = labels[o]
    same = labels[t][:, None] == lab_o
    if not (same & (d_o < (d_t - least)[:, None])).any():
        return hidden
    masks = _Components(label_image, uv, labels)
    # bearings from the camera, relative to a target's: points in front of the camera span less than a
    # half turn, so differences of these need no wrapping
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    da = bearing[o] - bearing[t][:, None]
    if np.abs(da).max() >= np.pi:  # points around the camera (not in front of it): wrap
        da = (da + np.pi) % (2 * np.pi) - np.pi
    ada = np.abs(da)
    nearer = same & (d_o < (d_t - (p.depth_margin + p.depth_margin_rel * d_t))[:, None])
    lateral = d_o * np.sin(ada)  # each occluder's offset from each target's ray, m
    # runs: neighbouring scan points of one surface; a run nearer than the points beside it is a foreground
    # object in the LiDAR's eyes (a chair's rear leg seen through the gap between the front ones), which
    # only the same-ray test may hide
    run, first, last = _runs(xy, footprint, p.line_step)
    jump = p.line_step if p.line_step > 0 else 0.06
    d_first, d_last = dist[first], dist[last]
    foreground = np.ones(first.size, bool)
    foreground[1:] = d_last[:-1] > d_first[1:] + jump  # the point before each run is farther
    foreground[:-1] &= d_first[1:] > d_last[:-1] + jump  # and the point after it
    free = ~foreground[run[t]]
    # 1. the same viewing ray: within the occluder's footprint (half a beam spacing each side), widened
    half = 0.5 * (footprint[o] / np.maximum(d_o, 1e-6) + p.ray_width)
    hid_t = (nearer & (ada <= half)).any(axis=1)
    # rules 2 and 3 ask whether the mask covers p's pixel row up to an occluder: one look at the image for both
    rows_a: list[NDArray[np.intp]] = []
    rows_b: list[NDArray[np.intp]] = []
    # 2. a bridged gap: the nearest nearer occluders left and right, close together, joined by the mask
    c2 = np.zeros(0, np.intp)
    if p.max_gap > 0:
        # occluders whose lateral offset from p's ray (at their own distance) is within max_gap
        reach = nearer & (lateral <= p.max_gap)
        left = np.where(reach & (da < 0), da, -np.inf)
        right = np.where(reach & (da > 0), da, np.inf)
        i_l, i_r = left.argmax(axis=1), right.argmin(axis=1)
        cand = ~hid_t & free & (left.max(axis=1) > -np.inf) & (right.min(axis=1) < np.inf)
        if cand.any():
            c = np.flatnonzero(cand)
            ol, orr = o[i_l[c]], o[i_r[c]]
            gap = xy[ol] - xy[orr]
            close = np.hypot(gap[:, 0], gap[:, 1]) <= p.max_gap
            c2, ol, orr = c[close], ol[close], orr[close]
            rows_a += [t[c2], t[c2]]
            rows_b += [ol, orr]
    # 3. the mask past the object's outermost point (an overhang above LiDAR height, or the mask's spill):
    #    a nearer occluder on one side only, a little aside, joined to p by the mask
    c3 = np.zeros(0, np.intp)
    if p.edge_px > 0 or p.overhang > 0:
        du = np.abs(uv[o, 0] - uv[t, 0][:, None])
        du = np.where(nearer & ((du <= p.edge_px) | (lateral <= p.overhang)), du, np.inf)
        j = du.argmin(axis=1)
        c3 = np.flatnonzero(~hid_t & free & (du.min(axis=1) < np.inf))
        rows_a.append(t[c3])
        rows_b.append(o[j[c3]])
    if rows_a:
        on_row = masks.row_joined(np.concatenate(rows_a), np.concatenate(rows_b))
        n2 = c2.size
        hid_t[c2] = on_row[:n2] & on_row[n2:2 * n2]  # a target rule 2 leaves visible may still fall to rule 3
        hid_t[c3] |= on_row[2 * n2:]
    # 4. a background line across the mask: p's surface runs on, without a depth jump, to points off the
    #    mask, and a point of the mask stands in front of it (by less than the depth margin: a bed
    #    against a wall); an object's own far side does not run off its mask
    if p.line_step > 0 and not hid_t.all():
        # the nearest such point of the mask in front of each target not hidden yet
        c = np.flatnonzero(~hid_t)
        front = same[c] & (d_o < (d_t[c] - p.line_depth_margin)[:, None]) & (lateral[c] <= p.max_gap) & (
            run[o] != run[t[c]][:, None])
        score = np.where(front, ada[c], np.inf)
        j = score.argmin(axis=1)
        has = score.min(axis=1) < np.inf
        if has.any():
            c, j = c[has], j[has]
            # ... whose own surface runs off the mask
            off = np.zeros(first.size, bool)
            off[run[labels == 0]] = True
            off = _through_shadows(off, xy, dist, first, last, p.max_gap)
            line = off[run[t[c]]]
            c, j = c[line], j[line]
            if c.size:
                hid_t[c] = masks.joined(t[c], o[j])
    # 5. deeper than the object: a nearer point of the mask, farther from p than the object spans and
    #    no farther than that from p's ray, is on an object p cannot be part of, standing in front of p
    if extent is not None and not hid_t.all():
        ext = extent[np.minimum(labels[t], extent.size - 1)]
        # ... on a surface, not a leg: a far chair's leg seen between the legs of a nearer one is itself
        span = np.hypot(*(xy[last] - xy[first]).T)
        c = np.flatnonzero(~hid_t & np.isfinite(ext) & (span[run[t]] > _LEG))
        if c.size:
            e = ext[c][:, None]
            apart = np.hypot(xy[t[c], 0][:, None] - xy[o, 0][None, :], xy[t[c], 1][:, None] - xy[o, 1][None, :])
            front = same[c] & (d_o < d_t[c][:, None]) & (lateral[c] <= e) & (apart > e)
            score = np.where(front, ada[c], np.inf)
            j = score.argmin(axis=1)
            has = score.min(axis=1) < np.inf
            c, j = c[has], j[has]
            if c.size:
                hid_t[c] = masks.joined(t[c], o[j])
    hidden[t] = hid_t
    return hidden


#: rad, the bearing bins of the background same-ray test (a quarter of a degree)
_BEARING_BIN = np.radians(0.25)


def _hidden_background(xy: NDArray[np.float64], eye: NDArray[np.float64], labels: NDArray[np.intp],
                       targets: NDArray[np.bool_], footprint: NDArray[np.float64],
                       p: OcclusionConfig) -> NDArray[np.bool_]:
    """Rule 1 for points off every mask (label 0): hidden when another point off the masks stands on
    the same viewing ray, nearer by the depth margin, and off the target's own surface. The LiDAR at a
    corner of the robot sees past the edge of a wall that hides the same place from the camera; a
    person standing there projects onto the wall's pixels, and would be painted static (a wall). A
    nearer point of a mask on the ray would put its mask on the pixel, so only points off the masks can
    hide these. A straight surface never hides itself: a wall seen at a grazing angle has its nearer
    points on nearly the same ray, on the line through the target and its neighbours in the scan."""
    out = np.zeros(xy.shape[0], bool)
    bg = labels == 0
    t = np.flatnonzero(targets & bg)
    if t.size == 0 or np.count_nonzero(bg) < 2:
        return out
    o = np.flatnonzero(bg)
    rel = xy - eye
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    limit = dist - (p.depth_margin + p.depth_margin_rel * dist)  # an occluder is nearer than this
    # each occluder covers its footprint (half a beam spacing each side) widened by the ray width
    half = 0.5 * (footprint[o] / np.maximum(dist[o], 1e-6) + p.ray_width)
    reach = int(min(np.ceil(half.max() / _BEARING_BIN), 40))
    lo = np.floor((bearing[o] - half) / _BEARING_BIN).astype(np.int64)
    hi = np.floor((bearing[o] + half) / _BEARING_BIN).astype(np.int64)
    base = int(min(lo.min(), np.floor(bearing[t].min() / _BEARING_BIN)))
    # (bin, occluder) pairs, sorted by bin: the bins each occluder covers
    b = lo[:, None] + np.arange(2 * reach + 2)[None, :]
    ok = b <= hi[:, None]
    pair_bin = b[ok] - base
    pair_o = np.broadcast_to(o[:, None], b.shape)[ok]
    # by bin, nearest first; most targets are the nearest point of their bin: only those with something
    # nearer are checked
    order = np.lexsort((dist[pair_o], pair_bin))
    pair_bin, pair_o = pair_bin[order], pair_o[order]
    n_bins = int(max(hi.max(), np.floor(bearing[t].max() / _BEARING_BIN))) - base + 1
    nearest = np.full(n_bins, np.inf)
    first = np.ones(pair_bin.size, bool)
    first[1:] = pair_bin[1:] != pair_bin[:-1]
    nearest[pair_bin[first]] = dist[pair_o[first]]
    bt = np.floor(bearing[t] / _BEARING_BIN).astype(np.int64) - base
    behind = nearest[bt] < limit[t]
    if not behind.any():
        return out
    t, bt = t[behind], bt[behind]
    # each target against the occluders of its bin that are nearer by the depth margin
    start, stop = np.searchsorted(pair_bin, bt, "left"), np.searchsorted(pair_bin, bt, "right")
    count = stop - start
    if not count.any():
        return out
    ti = np.repeat(np.arange(t.size), count)
    pi = np.repeat(start - np.cumsum(count) + count, count) + np.arange(int(count.sum()))
    tt, oo = t[ti], pair_o[pi]
    near = dist[oo] < limit[tt]
    if not near.any():
        return out
    tt, oo = tt[near], oo[near]
    # the target's surface: the line through it and either neighbour in the scan (at the end of a
    # surface, only one of them lies on it)
    k = xy.shape[0]
    w = xy[oo] - xy[tt]
    tol = np.maximum(3.0 * footprint[tt], 0.05)
    on_surface = np.zeros(tt.size, bool)
    for nb in (np.maximum(tt - 1, 0), np.minimum(tt + 1, k - 1)):
        u = xy[nb] - xy[tt]
        norm = np.hypot(u[:, 0], u[:, 1])
        off_line = np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]) / np.maximum(norm, 1e-9)
        on_surface |= (norm > 1e-9) & (off_line <= tol)
    apart = ~on_surface
    out[tt[apart]] = True
    return out


def _runs(xy: NDArray[np.float64], footprint: NDArray[np.float64],
          line_step: float) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Runs of neighbouring points with steps under ``line_step`` (or 3 footprints): each point's run,
    and each run's first and last point."""
    k = xy.shape[0]
    run = np.zeros(k, np.intp)
    if k > 1:
        d = xy[1:] - xy[:-1]
        step = np.hypot(d[:, 0], d[:, 1])
        brk = step > np.maximum(line_step, 3.0 * footprint[1:]) if line_step > 0 else np.ones(k - 1, bool)
        np.cumsum(brk, out=run[1:])
        ends = np.flatnonzero(brk)
    else:
        ends = np.zeros(0, np.intp)
    first = np.zeros(ends.size + 1, np.intp)
    first[1:] = ends + 1
    last = np.full(ends.size + 1, k - 1, np.intp)
    last[:-1] = ends
    return run, first, last


#: m, the widest a leg (a chair's, a table's, a bed's) is seen at LiDAR height: a run of points no longer
#: than this, behind a nearer object of its class, may be a leg of another such object seen between its legs
_LEG = 0.25

_ROW_STEPS = np.linspace(0.0, 1.0, 24)[None, :]  # where row_joined samples the row between two columns


class _Regions:
    """The 8-connected regions of one mask, flood-filled from the pixels asked about (cost: their area).

    Each region gets a number the first time one of its pixels is asked about; past 255 regions
    (the numbers are bytes) every region of the mask is labelled at once instead.
    """

    _FLAGS = 8 | cv2.FLOODFILL_MASK_ONLY | cv2.FLOODFILL_FIXED_RANGE

    def __init__(self, mask: NDArray[np.uint8]) -> None:
        self.mask = mask  # 1 on the mask, 0 off it
        h, w = mask.shape
        self.filled = np.zeros((h + 2, w + 2), np.uint8)  # floodFill's mask: region numbers, a pixel of border
        self.n = 0
        self.all: NDArray[np.int32] | None = None

    def at(self, row: NDArray[np.intp], col: NDArray[np.intp], fill: bool = True) -> NDArray[np.integer]:
        """The region under each pixel (0: off the mask); ``fill``: number the regions not seen yet."""
        if self.all is not None:
            return self.all[row, col]
        ids = self.filled[row + 1, col + 1]
        if fill:
            for i in np.flatnonzero((ids == 0) & (self.mask[row, col] != 0)):
                r, c = int(row[i]), int(col[i])
                if self.filled[r + 1, c + 1] == 0:  # not filled by an earlier pixel of this call
                    if self.n == 255:
                        self.all = np.asarray(cv2.connectedComponents(self.mask, connectivity=8)[1], np.int32)
                        return self.all[row, col]
                    self.n += 1
                    cv2.floodFill(self.mask, self.filled, (c, r), 1, 0, 0, self._FLAGS | (self.n << 8))
                ids[i] = self.filled[r + 1, c + 1]
        return ids


class _Components:
    """Whether two points' pixels lie on one connected region of their mask (computed per label, lazily)."""

    _last: tuple[weakref.ReferenceType, dict[int, _Regions]] | None = None

    def __init__(self, label_image: NDArray[np.integer], uv: NDArray[np.float64] | NDArray[np.integer],
                 labels: NDArray[np.intp]) -> None:
        self.image = label_image
        h, w = label_image.shape
        self.col: NDArray[np.intp]
        self.row: NDArray[np.intp]
        if uv.dtype.kind in "iu":  # whole pixels, clamped to the image already (the painter's)
            self.col, self.row = cast(NDArray[np.intp], uv[:, 0]), cast(NDArray[np.intp], uv[:, 1])
        else:
            self.col = np.minimum(np.maximum(np.rint(uv[:, 0]).astype(np.intp), 0), w - 1)
            self.row = np.minimum(np.maximum(np.rint(uv[:, 1]).astype(np.intp), 0), h - 1)
        self.labels = labels
        # a camera frame is painted with several scans: keep its regions while the same image comes back
        last = _Components._last
        if last is not None and last[0]() is label_image:
            self._regions = last[1]
        else:
            self._regions = {}
            _Components._last = (weakref.ref(label_image), self._regions)

    def _of(self, value: int) -> _Regions:
        """The regions of the mask ``value``."""
        regions = self._regions.get(value)
        if regions is None:
            regions = _Regions((self.image == value).view(np.uint8))
            self._regions[value] = regions
        return regions

    def keys(self, idx: NDArray[np.intp]) -> NDArray[np.int32]:
        """A number per point of ``idx`` naming its label's connected region: equal for two points
        exactly when they lie on one region of one mask (-1 off the masks)."""
        out = np.full(idx.size, -1, np.int32)
        la = self.labels[idx]
        for value in np.unique(la[la > 0]):
            m = la == value
            region = self._of(int(value)).at(self.row[idx[m]], self.col[idx[m]]).astype(np.int32)
            out[m] = np.where(region > 0, int(value) * REGION_BASE + region, -1)
        return out

    def row_joined(self, a: NDArray[np.intp], b: NDArray[np.intp], min_share: float = 0.8) -> NDArray[np.bool_]:
        """Whether the mask covers ``min_share`` of a's pixel row between a's column and b's."""
        ca = self.col[a]
        cols = np.rint(ca[:, None] + (self.col[b] - ca)[:, None] * _ROW_STEPS).astype(np.intp)
        on = self.image[self.row[a][:, None], cols] == self.labels[a][:, None]
        return on.sum(axis=1) >= min_share * _ROW_STEPS.size

    def joined(self, a: NDArray[np.intp], b: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Whether a's and b's pixels lie on one connected region of a's mask."""
        la = self.labels[a]
        if (la == la[0]).all():  # mostly one label
            regions = self._of(int(la[0]))
            ra = regions.at(self.row[a], self.col[a])
            return (ra > 0) & (ra == regions.at(self.row[b], self.col[b], fill=False))
        out = np.zeros(a.size, bool)
        for value in np.unique(la):
            m = la == value
            out[m] = self.joined(a[m], b[m])
        return out


def mask_regions(label_image: NDArray[np.integer], uv: NDArray[np.integer], labels: NDArray[np.intp]
                 ) -> NDArray[np.int32]:
    """Which object each point's pixel lies on, when the segmentation does not tell objects apart:
    its label's 8-connected mask region, as a number unique within the image (-1 off the masks).

    ``uv`` (K, 2): whole pixels (column, row) inside the image; ``labels`` (K,): the label value
    under each. The regions are kept while the same label image comes back (a camera frame is
    painted with several scans), and shared with :func:`hidden_points`.
    """
    return _Components(label_image, uv, labels).keys(np.arange(labels.size))


def _through_shadows(off: NDArray[np.bool_], xy: NDArray[np.float64], dist: NDArray[np.float64],
                     first: NDArray[np.intp], last: NDArray[np.intp], max_gap: float) -> NDArray[np.bool_]:
    """Carry "runs off the mask" across the shadows of nearer objects.

    A wall behind a bed's legs reaches the LiDAR in pieces, cut by the legs' shadows. A run
    counts as off the mask when the run beyond a nearer run (the shadow's caster) continues it
    within ``max_gap`` and is off the mask; repeated a few times, so it crosses several shadows.
    """
    n = off.size
    if n < 3:
        return off
    run_max = np.maximum.reduceat(dist, first)  # the farthest point of each run
    r = np.arange(2, n)  # run r and run r - 2, with run r - 1 between them

    def bridged(a: NDArray[np.intp], b: NDArray[np.intp]) -> NDArray[np.bool_]:
        return (run_max[r - 1] < np.minimum(dist[a], dist[b])) & (np.hypot(*(xy[a] - xy[b]).T) <= max_gap)

    ok = bridged(first[r], last[r - 2])  # ok[i]: runs i and i + 2 are one surface behind run i + 1
    if not ok.any():
        return off
    out = off.copy()
    for _ in range(4):
        new = out.copy()
        new[2:] |= ok & out[:-2]
        new[:-2] |= ok & out[2:]
        if not (new ^ out).any():
            break
        out = new
    return out
