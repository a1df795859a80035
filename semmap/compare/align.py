"""Global SE(2) alignment of two occupancy maps, with no initial guess.

Two tours of one building start wherever the robot stood, so their map frames differ by an
unknown rotation and translation. This finds the pose of B's map frame in A's from the static
structure of both, as correlative scan matching does it (Olson, "Real-time correlative scan
matching", ICRA 2009; Cartographer's branch-and-bound search rests on the same scores):

1. **Every heading, coarse.** A's obstacles become a likelihood field (a Gaussian of the
   distance to the nearest obstacle) on a coarse grid (20 cm, coarser for big maps). For each
   heading, B's obstacle points, turned, are rasterised and cross-correlated with the field by
   FFT: every translation is scored at once. The raster turned half way round is the raster
   flipped, so one forward transform serves two headings. Every heading in 2° steps is scored
   first on a field three times coarser (a ninth of the FFT work); the 8 best distinct headings
   and their neighbours within 4° are scored again on the coarse field.
2. **The best few, finer.** The best distinct peaks (more than 6° or 1.5 m apart) are searched
   again in a small window on a field at twice the map's resolution.
3. **Full resolution.** A robust ICP (point to point, the inlier distance shrinking from 30 cm to
   1.5 cells) takes each that scored at least half the best in its window to convergence; moved
   furniture and new walls fall outside the inlier distance and pull nothing.
4. **Which one, and how sure.** Candidates within 5° and 1 m are one fit. Each is scored by the
   B points (walls and furniture, where A observed) within 1.5 cells of A's; the fit with the most
   wins, and within a fit the pose with the best soft count. ``ambiguity`` compares the winner with
   each other fit on the points only one of the two explains (1.0: a tie, as in a bare rectangular
   room turned half way round; the walls of a ward of identical rooms fit turned round too, its
   furniture does not).
5. **Off the lattice.** A last search on a smooth field of A's walls, read between cells.

Too little overlap, too few inliers or too ambiguous a fit raise
:class:`~semmap.errors.AlignmentError` with what was measured against what threshold.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import fft as sp_fft
from scipy.spatial import cKDTree

from ..errors import AlignmentError
from ..geometry import se2_apply, wrap_angle
from ..records import GridSpec
from ..register.metrics import align_se2
from .session import Session

__all__ = ["AlignInput", "Alignment", "align_maps"]


@dataclass(frozen=True)
class AlignInput:
    """One map to align: its grid, the obstacles to align on, and the cells observed free."""

    spec: GridSpec
    #: (H, W) obstacles to align on: static structure when the map has semantic layers
    occupied: NDArray[np.bool_]
    #: (H, W) cells observed free (for the overlap)
    free: NDArray[np.bool_]
    #: (H, W) other obstacles (furniture): they choose between fits the structure alone cannot tell
    #: apart (a ward of identical rooms along a corridor looks the same turned half way round)
    movable: NDArray[np.bool_] | None = None

    @classmethod
    def from_session(cls, s: Session) -> AlignInput:
        """Structure only: movable objects and people are what changes, not what to align on; the
        furniture still helps choose between fits."""
        return cls(spec=s.spec, occupied=s.occupied & ~s.semi_static & ~s.dynamic, free=s.free,
                   movable=s.occupied & s.semi_static & ~s.dynamic)

    def points(self, with_movable: bool = False) -> NDArray[np.float64]:
        """Obstacle cell centres (N, 2), the map's frame (and the movable ones, if asked)."""
        cells = self.occupied | self.movable if with_movable and self.movable is not None else self.occupied
        rows, cols = np.nonzero(cells)
        s = self.spec
        return np.stack([s.origin_x + (cols + 0.5) * s.resolution, s.origin_y + (rows + 0.5) * s.resolution],
                        axis=1).astype(np.float64)


@dataclass(frozen=True)
class Alignment:
    """The pose of B's map frame in A's: ``p_a = se2_apply(T_a_b, p_b)``, and how good it is."""

    T_a_b: NDArray[np.float64]
    #: RMS distance (m) from B's inlier wall points to A's nearest wall point
    residual_m: float = 0.0
    #: share of B's wall points (in A's observed area) within 1.5 cells of A's walls
    inlier_fraction: float = 1.0
    #: share of B's observed cells that land on A's observed cells
    overlap: float = 1.0
    #: where the best and the best distinct other fit disagree, the other's evidence over the best's (1.0: a tie)
    ambiguity: float = 0.0
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        t = np.asarray(self.T_a_b, np.float64)
        return {"T_a_b": [round(float(t[0]), 4), round(float(t[1]), 4), round(float(t[2]), 6)],
                "yaw_deg": round(math.degrees(float(t[2])), 3), "residual_m": round(self.residual_m, 4),
                "inlier_fraction": round(self.inlier_fraction, 4), "overlap": round(self.overlap, 4),
                "ambiguity": round(self.ambiguity, 4), "seconds": round(self.seconds, 3)}


def _field(points: NDArray[np.float64], origin: NDArray[np.float64], res: float, shape: tuple[int, int],
           sigma_cells: float = 1.0) -> NDArray[np.float32]:
    """A likelihood field on a grid: exp(-d² / 2σ²) with d the distance to the nearest point, in cells."""
    img = np.ones(shape, np.uint8)
    ij = np.floor((points - origin) / res).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < shape[0])
    img[ij[ok, 1], ij[ok, 0]] = 0
    d = cv2.distanceTransform(img, cv2.DIST_L2, 5)
    return np.exp(-0.5 * (d.astype(np.float32) / sigma_cells) ** 2)


def _lookup(field: NDArray[np.float32], origin: NDArray[np.float64], res: float,
            points: NDArray[np.float64]) -> NDArray[np.float32]:
    ij = np.floor((points - origin) / res).astype(np.int64)
    h, w = field.shape
    ok = (ij[..., 0] >= 0) & (ij[..., 0] < w) & (ij[..., 1] >= 0) & (ij[..., 1] < h)
    out = np.zeros(ij.shape[:-1], np.float32)
    out[ok] = field[ij[..., 1][ok], ij[..., 0][ok]]
    return out


def _rot(theta: float) -> NDArray[np.float64]:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _coarse(pa: NDArray[np.float64], pb: NDArray[np.float64], res: float, headings_deg: NDArray[np.float64]
            ) -> list[tuple[float, float, NDArray[np.float64]]]:
    """(score, heading, translation) of the best translation for each heading (degrees, on a lattice
    of whole degrees): B's points, turned about their centroid by the heading and then shifted, land
    on A's field."""
    lo = pa.min(axis=0) - 3 * res
    hi = pa.max(axis=0) + 3 * res
    shape = (int(math.ceil((hi[1] - lo[1]) / res)) + 1, int(math.ceil((hi[0] - lo[0]) / res)) + 1)
    field = _field(pa, lo, res, shape)
    cb = pb.mean(axis=0)
    centred = pb - cb
    # one FFT size for every heading (B's raster is at most its bounding circle across), so A's field
    # is transformed once
    reach = int(math.ceil(2.0 * float(np.linalg.norm(centred, axis=1).max()) / res)) + 2
    size = (sp_fft.next_fast_len(shape[0] + reach, real=True), sp_fft.next_fast_len(shape[1] + reach, real=True))
    f_field = sp_fft.rfft2(field, size, workers=-1)
    # B's raster turned half way round is its raster flipped, whose transform is the conjugate times a
    # phase: every forward transform serves two headings, 180° apart (a base in [-180, 0) and base + 180)
    wanted: dict[float, set[float]] = {}
    for h in np.asarray(headings_deg, np.float64):
        h = float((h + 180.0) % 360.0 - 180.0)
        wanted.setdefault(h if h < 0.0 else h - 180.0, set()).add(h)
    out = []
    for deg in sorted(wanted):
        th = math.radians(deg)
        q = centred @ _rot(th).T
        qmin = q.min(axis=0)
        ij = np.floor((q - qmin) / res).astype(np.int64)
        hb, wb = int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1
        img = np.zeros((hb, wb), np.float32)
        np.add.at(img, (ij[:, 1], ij[:, 0]), 1.0)
        f_img = sp_fft.rfft2(img, size, workers=-1)
        # heading th: B's raster correlated with A's field (the transform of the flipped raster);
        # th + 180°: the flipped raster is B's raster at that heading, its cells from -qmax on
        for t_deg in sorted(wanted[deg]):
            if t_deg == deg:
                # the flipped raster's transform: exp(-2πi (k (h - 1) / P + l (w - 1) / Q)) conj(F)
                phase = np.outer(np.exp(-2j * np.pi * np.arange(size[0]) * (hb - 1) / size[0]),
                                 np.exp(-2j * np.pi * np.arange(f_img.shape[1]) * (wb - 1) / size[1])
                                 ).astype(np.complex64)
                f_corr, origin = phase * np.conj(f_img), qmin
            else:
                f_corr, origin = f_img, -qmin - np.array([wb, hb], np.float64) * res
            corr = sp_fft.irfft2(f_field * f_corr, size, workers=-1)
            k = int(np.argmax(corr))
            r, c = divmod(k, corr.shape[1])
            # full correlation: index j <-> shift j - (hb - 1) of B's raster against A's field; B's
            # raster cell u holds points from origin + u res, and lands on A's cell u + shift
            shift = np.array([c - (wb - 1), r - (hb - 1)], np.float64)
            t_th = math.radians(t_deg)
            t = lo + shift * res - origin
            out.append((float(corr[r, c]), t_th, t - _rot(t_th) @ cb))
    return out


def _distinct(cands: list[tuple[float, float, NDArray[np.float64]]], k: int, deg: float, dist: float
              ) -> list[tuple[float, float, NDArray[np.float64]]]:
    keep: list[tuple[float, float, NDArray[np.float64]]] = []
    for c in sorted(cands, key=lambda c: -c[0]):
        if all(abs(math.degrees(float(wrap_angle(c[1] - o[1])))) > deg or np.linalg.norm(c[2] - o[2]) > dist
               for o in keep):
            keep.append(c)
            if len(keep) == k:
                break
    return keep


def _refine_window(pose: NDArray[np.float64], pb: NDArray[np.float64], field: NDArray[np.float32],
                   origin: NDArray[np.float64], res: float, half_deg: float, half_m: float
                   ) -> tuple[NDArray[np.float64], float]:
    """Brute force around ``pose`` on a fine field: headings in 0.5° steps, shifts in whole field
    cells; the best pose and its score (the field summed over the points). A shift by whole cells
    moves every point's cell by the same offset, so each heading is one gather of the field around
    the points' cells."""
    n = max(1, int(round(half_m / res)))
    fp = np.pad(field, n)  # zeros beyond the field: no point is scored off its edge
    h, w = fp.shape
    k = np.arange(-n, n + 1)
    dy, dx = np.meshgrid(k, k, indexing="ij")
    offs = (dy * w + dx).ravel()
    flat_field = fp.ravel()
    best, best_s = pose, -1.0
    for d in np.arange(-half_deg, half_deg + 1e-9, 0.5):
        th = float(pose[2]) + math.radians(float(d))
        q = pb @ _rot(th).T + pose[:2]
        ij = np.floor((q - origin) / res).astype(np.int64) + n
        ok = (ij[:, 0] >= n) & (ij[:, 0] < w - n) & (ij[:, 1] >= n) & (ij[:, 1] < h - n)
        flat = ij[ok, 1] * w + ij[ok, 0]
        s = flat_field[flat[:, None] + offs[None, :]].sum(axis=0)
        j = int(np.argmax(s))
        if s[j] > best_s:
            best_s = float(s[j])
            best = np.array([pose[0] + dx.ravel()[j] * res, pose[1] + dy.ravel()[j] * res, th])
    return best, best_s


def _icp(pose: NDArray[np.float64], pb: NDArray[np.float64], tree: cKDTree, pa: NDArray[np.float64],
         res: float, sub: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Trimmed point-to-point ICP, the inlier distance shrinking to 1.5 cells. The wide stages only
    bring the pose near (on ``sub``, a subset of the points, if given, and to a millimetre); the
    last takes it to convergence on every point."""
    stages = ((0.3, 1e-3, 1e-4), (0.15, 1e-3, 1e-4), (3.0 * res, 1e-3, 1e-4), (1.5 * res, 1e-4, 1e-5))
    for k, (max_d, tol_m, tol_rad) in enumerate(stages):
        pts = sub if sub is not None and k < 2 else pb
        for _ in range(15):
            q = se2_apply(pose, pts)
            d, j = tree.query(q, distance_upper_bound=max_d)
            ok = np.isfinite(d)
            if ok.sum() < 10:
                return pose
            new = align_se2(pts[ok], pa[j[ok]])
            done = np.linalg.norm(new[:2] - pose[:2]) < tol_m and abs(float(wrap_angle(new[2] - pose[2]))) < tol_rad
            pose = new
            if done:
                break
    return pose


def _polish(pose: NDArray[np.float64], pb: NDArray[np.float64], field: NDArray[np.float32],
            origin: NDArray[np.float64], res: float) -> NDArray[np.float64]:
    """The last step, off the cell lattice: the pose near ``pose`` whose points score best on a smooth
    likelihood field of A's walls (σ one cell, read between cells by bilinear interpolation). ICP
    between cell centres locks onto whole cells and lets a few points of furniture by a wall pull
    the fit by a cell; a smooth field does neither."""
    from scipy.ndimage import map_coordinates

    def score(poses: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.empty(len(poses))
        for k, (x, y, th) in enumerate(poses):
            q = pb @ _rot(float(th)).T + (x, y)
            ij = (q - origin) / res - 0.5
            out[k] = map_coordinates(field, [ij[:, 1], ij[:, 0]], order=1, mode="constant", cval=0.0).sum()
        return out

    step_xy, step_th = 0.5 * res, math.radians(0.1)
    for _ in range(3):
        dx = np.arange(-2, 3) * step_xy
        dth = np.arange(-2, 3) * step_th
        gx, gy, gt = np.meshgrid(dx, dx, dth, indexing="ij")
        poses = pose + np.stack([gx.ravel(), gy.ravel(), gt.ravel()], axis=1)
        pose = poses[int(np.argmax(score(poses)))]
        step_xy, step_th = step_xy / 2.0, step_th / 2.0
    return pose


def _observed_mask(m: AlignInput) -> NDArray[np.bool_]:
    return np.asarray(m.occupied | m.free, bool)


def _inside(spec: GridSpec, mask: NDArray[np.bool_], pts: NDArray[np.float64]) -> NDArray[np.bool_]:
    rc = spec.world_to_cell(pts)
    ok = (rc[:, 0] >= 0) & (rc[:, 0] < spec.height) & (rc[:, 1] >= 0) & (rc[:, 1] < spec.width)
    out = np.zeros(len(pts), bool)
    out[ok] = mask[rc[ok, 0], rc[ok, 1]]
    return out


def _inliers(pose: NDArray[np.float64], pb: NDArray[np.float64], tree: cKDTree, a: AlignInput,
             seen_a: NDArray[np.bool_], tol: float) -> tuple[NDArray[np.bool_], float]:
    """B's points that land within ``tol`` of A's points, in A's observed area, under ``pose``; and
    their soft count (each weighted by exp(-d² / 2σ²), σ half a cell)."""
    q = se2_apply(pose, pb)
    d, _ = tree.query(q, distance_upper_bound=tol, workers=-1)
    ok = np.isfinite(d) & _inside(a.spec, seen_a, q)
    sigma = 0.5 * a.spec.resolution
    return ok, float(np.exp(-0.5 * (d[ok] / sigma) ** 2).sum())


def _score(pose: NDArray[np.float64], pb: NDArray[np.float64], tree: cKDTree, a: AlignInput,
           seen_a: NDArray[np.bool_], tol: float) -> tuple[float, float, float]:
    """(inlier fraction, inlier count, RMS residual of inliers) of B's points under ``pose``."""
    q = se2_apply(pose, pb)
    # B's walls that land where A observed (or within a cell of A's walls) can be checked
    checkable = _inside(a.spec, seen_a, q)
    d, _ = tree.query(q, distance_upper_bound=tol * (1.0 + 1e-9), workers=-1)  # inf beyond: not an inlier
    inl = (d <= tol) & checkable
    n = int(checkable.sum())
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else math.inf
    return (float(inl.sum()) / n if n else 0.0), float(inl.sum()), rms


def align_maps(a: AlignInput, b: AlignInput, *, min_overlap: float = 0.25, min_inliers: float = 0.4,
               max_ambiguity: float = 0.75, max_points: int = 2500, seed: int = 0) -> Alignment:
    """The pose of B's map frame in A's (see the module's description); raises
    :class:`~semmap.errors.AlignmentError` when the maps cannot be aligned with confidence."""
    t0 = time.perf_counter()
    pa, pb_all = a.points(), b.points()
    if len(pa) < 20 or len(pb_all) < 20:
        which = "A" if len(pa) < 20 else "B"
        raise AlignmentError(f"map {which} has {min(len(pa), len(pb_all))} wall cells: too few to align on")
    res = min(a.spec.resolution, b.spec.resolution)
    rng = np.random.default_rng(seed)
    pb = pb_all if len(pb_all) <= max_points else pb_all[rng.choice(len(pb_all), max_points, replace=False)]
    extent = float(max(np.ptp(pa, axis=0).max(), np.ptp(pb, axis=0).max()))
    coarse_res = max(0.2, extent / 350.0)
    # 1. every heading in 2° steps, on a field three times coarser still (a ninth of the FFT work);
    # then the 8 best distinct headings and their neighbours within 4° on the coarse field
    first = _coarse(pa, pb, 3.0 * coarse_res, np.arange(-180.0, 180.0, 2.0))
    near = {round(math.degrees(th)) + d for _, th, _t in _distinct(first, 8, deg=6.0, dist=3.0)
            for d in (-4, -2, 0, 2, 4)}
    cands = _coarse(pa, pb, coarse_res, np.array(sorted(near), np.float64))
    top = _distinct(cands, 6, deg=6.0, dist=1.5)
    # 2. finer, in a window; 3. ICP at full resolution
    fine_res = 2.0 * res
    lo = pa.min(axis=0) - 1.0 - 0.5 * res  # A's cell centres at the centres of the fields' cells
    hi = pa.max(axis=0) + 1.0
    fshape = (int(math.ceil((hi[1] - lo[1]) / fine_res)) + 1, int(math.ceil((hi[0] - lo[0]) / fine_res)) + 1)
    ffield = _field(pa, lo, fine_res, fshape)
    tree = cKDTree(pa)
    seen_a = _observed_mask(a) | (cv2.dilate(a.occupied.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    sub = pb[:: max(1, len(pb) // 1500)]
    windowed = [_refine_window(np.array([t[0], t[1], th]), sub, ffield, lo, fine_res, half_deg=2.5,
                               half_m=1.5 * coarse_res) for _, th, t in top]
    # ICP only where the fit can compete: one that explains less than half what the best explains
    # on the field is kept at its window pose (it still counts towards the ambiguity)
    best_window = max(s for _, s in windowed)
    refined = [_icp(pose, pb, tree, pa, res, sub) if s >= 0.5 * best_window else pose for pose, s in windowed]
    # which candidate: structure and furniture together, and only the points on which two fits
    # disagree count (a ward of identical rooms matches its walls turned half way round as well as
    # straight; the few things that differ decide)
    pa_all, pb_every = a.points(with_movable=True), b.points(with_movable=True)
    tree_all = cKDTree(pa_all)
    pb_choice = pb_every[:: max(1, len(pb_every) // 8000)]
    fits = [_inliers(pose, pb_choice, tree_all, a, seen_a, 1.5 * res) for pose in refined]
    inliers = [f[0] for f in fits]
    # the fits, grouped (within 5° and 1 m they are one fit found twice, or one fit of two maps that do
    # not quite agree, as real maps with drift do; a symmetric building's other fit is a turn or a room
    # away): a group's strength is its members' best inlier count; its pose the member with the best
    # soft count (a point half a cell off counts 0.6, a cell off 0.14), so that of two poses keeping
    # every point within the tolerance the closer one wins
    def same(p: NDArray[np.float64], q: NDArray[np.float64]) -> bool:
        return abs(math.degrees(float(wrap_angle(p[2] - q[2])))) <= 5.0 and float(np.linalg.norm(p[:2] - q[:2])) <= 1.0

    groups: list[list[int]] = []
    for i in range(len(refined)):
        for g in groups:
            if same(refined[i], refined[g[0]]):
                g.append(i)
                break
        else:
            groups.append([i])
    groups.sort(key=lambda g: -max(int(inliers[i].sum()) for i in g))
    reps = [max(g, key=lambda i: fits[i][1]) for g in groups]
    best_i = reps[0]
    best = refined[best_i]
    ambiguity = 0.0
    for i in reps[1:]:
        only_best = int((inliers[best_i] & ~inliers[i]).sum())
        only_other = int((inliers[i] & ~inliers[best_i]).sum())
        # the evidence for the other fit over the evidence for the best (+10 points: no evidence is a tie)
        ambiguity = max(ambiguity, (only_other + 10) / (only_best + 10))
    # off the cell lattice, on a smooth field of A's walls
    full = _field(pa, lo, res, (int(math.ceil((hi[1] - lo[1]) / res)) + 1, int(math.ceil((hi[0] - lo[0]) / res)) + 1),
                  sigma_cells=1.0)
    best = _polish(best, pb, full, lo, res)
    # final score on every wall point of B
    frac, _, rms = _score(best, pb_all, tree, a, seen_a, 1.5 * res)
    obs_flat = np.flatnonzero(_observed_mask(b))
    obs_flat = obs_flat[:: max(1, obs_flat.size // 20000)]
    obs_r, obs_c = np.divmod(obs_flat, b.spec.width)
    pts_b = np.stack([b.spec.origin_x + (obs_c + 0.5) * b.spec.resolution,
                      b.spec.origin_y + (obs_r + 0.5) * b.spec.resolution], axis=1)
    overlap = float(_inside(a.spec, _observed_mask(a), se2_apply(best, pts_b)).mean()) if len(pts_b) else 0.0
    best = np.array([best[0], best[1], float(wrap_angle(best[2]))])
    result = Alignment(best, rms if math.isfinite(rms) else 0.0, frac, overlap, ambiguity, time.perf_counter() - t0)
    if overlap < min_overlap:
        raise AlignmentError(f"the maps overlap too little to align: {overlap:.0%} of B's observed floor lands on "
                             f"A's at the best fit (at least {min_overlap:.0%} needed)")
    if frac < min_inliers:
        raise AlignmentError(f"the maps do not match: at the best fit only {frac:.0%} of B's walls lie on A's "
                             f"(at least {min_inliers:.0%} needed); are they of the same building?")
    if ambiguity > max_ambiguity:
        raise AlignmentError(f"the alignment is ambiguous: where two fits disagree, the evidence for another is "
                             f"{ambiguity:.0%} of the best's (at most {max_ambiguity:.0%} allowed): a symmetric "
                             f"room or a featureless corridor")
    return result
