"""``T_cam_lidar`` from board observations, with no hand-picked points (Zhang & Pless, 2004).

Each observation is a camera image of a calibration board and a 2D scan taken at the same
time. The camera gives the board's plane (``n · p_cam = d``, from the pattern's pose); the
scan gives the line where the scan plane cuts the board. Every scan point ``p`` on that
line must lie on the plane once moved into the camera::

    n_i · (R p + t) = d_i          with T_cam_lidar = [R | t]

* **Board line in the scan** (:func:`find_board_segments`): the scan is split into straight
  segments; segments that stay put across observations are the room, not the board (the
  board moves between observations); among the rest, the combination most consistent with
  the planes wins.
* **Linear start** (Zhang & Pless): with ``p = (x, y, 0)``, ``R p + t = H (x, y, 1)`` where
  ``H = [r1 r2 t]``; the constraints are linear in ``H`` and solved by least squares, then
  ``[r1 r2]`` is projected onto the nearest rotation. No initial guess is needed.
* **Refinement**: Levenberg–Marquardt-style robust least squares on the point-to-plane
  distances, with a weak prior that only matters for directions the boards do not constrain.

**Observability.** If every board stands vertical and the LiDAR is level (the usual set-up,
and the ACFR data's), the planes' normals all lie in one plane: the height of the scan plane
and its tilt are then not observable (to first order) from line-on-plane constraints. The
result says so (``unobservable``) and holds those directions at the prior: the linear
solution (scan plane through the camera centre, perpendicular to the boards), or a prior
calibration the user gives. Tilting the board forward/back in some views removes the problem.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..errors import ConfigError
from ..geometry import se3_inverse
from ..records import CameraIntrinsics
from .boards import BoardDetection
from .common import normalize_pixels, project

__all__ = [
    "BoardPlane",
    "ScanSegment",
    "TargetCalibration",
    "TargetObservation",
    "ViewResidual",
    "board_plane",
    "calibrate_target",
    "find_board_segments",
    "linear_target_solution",
    "scan_segments",
]

log = logging.getLogger(__name__)

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class BoardPlane:
    """A board's pose and plane in the camera frame.

    ``T_cam_board`` maps board-frame points into the camera. The plane is
    ``normal · p_cam = distance_m`` with ``normal`` pointing away from the camera (so
    ``distance_m > 0`` is the camera's distance to the plane). ``rms_px`` is the pattern's
    reprojection error.
    """

    T_cam_board: NDArray[np.float64]
    normal: NDArray[np.float64]
    distance_m: float
    rms_px: float
    n_points: int

    @property
    def centre(self) -> NDArray[np.float64]:
        return self.T_cam_board[:3, 3]


def board_plane(detection: BoardDetection, intrinsics: CameraIntrinsics) -> BoardPlane:
    """The board's pose (PnP, refined) and plane in the camera frame from one detection."""
    obj = detection.object_points.astype(np.float64)
    xn = normalize_pixels(intrinsics, detection.image_points).reshape(-1, 1, 2)
    eye = np.eye(3)
    n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, xn, eye, None, flags=cv2.SOLVEPNP_IPPE)
    best = None
    for r, t in zip(rvecs[:n], tvecs[:n]):
        r, t = cv2.solvePnPRefineLM(obj, xn, eye, None, r.copy(), t.copy())
        R = cast("NDArray[np.float64]", cv2.Rodrigues(r)[0])  # float64 (cv2's stubs carry no dtype)
        pc = obj @ R.T + t.ravel()
        err = float(np.sqrt(np.mean(np.sum((project(intrinsics, pc) - detection.image_points) ** 2, axis=1))))
        if best is None or err < best[2]:
            best = (R, t.ravel(), err)
    assert best is not None
    R, t, err = best
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    normal = R[:, 2].copy()
    dist = float(normal @ t)
    if dist < 0:
        normal, dist = -normal, -dist
    return BoardPlane(T, normal, dist, err, len(detection))


@dataclass(frozen=True)
class ScanSegment:
    """A straight run of scan points: indices into the scan, end points, fit RMS (m)."""

    indices: NDArray[np.intp]
    start: NDArray[np.float64]
    end: NDArray[np.float64]
    rms_m: float

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def centre(self) -> NDArray[np.float64]:
        return 0.5 * (self.start + self.end)


def _fit_line(p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    c = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - c, full_matrices=False)
    d = vt[0]
    rms = float(s[1] / math.sqrt(len(p))) if len(s) > 1 else 0.0
    return c, d, rms


def _split(p: NDArray[np.float64], idx: NDArray[np.intp], tol: float, out: list[NDArray[np.intp]]) -> None:
    if len(idx) < 3:
        out.append(idx)
        return
    a, b = p[idx[0]], p[idx[-1]]
    ab = b - a
    L = float(np.linalg.norm(ab))
    q = p[idx] - a
    dist = np.abs(ab[0] * q[:, 1] - ab[1] * q[:, 0]) / L if L > 1e-9 else np.linalg.norm(q, axis=1)
    k = int(np.argmax(dist))
    if dist[k] > tol and 0 < k < len(idx) - 1:
        _split(p, idx[: k + 1], tol, out)
        _split(p, idx[k:], tol, out)
    else:
        out.append(idx)


def scan_segments(scan_xy: NDArray[np.float64], *, min_points: int = 8, min_length_m: float = 0.15,
                  max_rms_m: float = 0.02, split_tol_m: float = 0.04) -> list[ScanSegment]:
    """Straight segments of a 2D scan (split-and-merge on the points in bearing order)."""
    p = np.asarray(scan_xy, dtype=np.float64).reshape(-1, 2)
    r = np.hypot(p[:, 0], p[:, 1])
    valid = np.flatnonzero(np.isfinite(r) & (r > 0.05))
    if valid.size < min_points:
        return []
    order = valid[np.argsort(np.arctan2(p[valid, 1], p[valid, 0]), kind="stable")]
    q = p[order]
    step = np.diff(np.arctan2(q[:, 1], q[:, 0]))
    dth = float(np.median(step[step > 0])) if np.any(step > 0) else math.radians(1.0)
    gaps = np.linalg.norm(np.diff(q, axis=0), axis=1)
    rr = np.hypot(q[:, 0], q[:, 1])
    limit = np.maximum(0.06, 4.0 * np.minimum(rr[:-1], rr[1:]) * dth)
    breaks = np.flatnonzero(gaps > limit) + 1
    segs: list[ScanSegment] = []
    for run in np.split(np.arange(len(q)), breaks):
        if len(run) < min_points:
            continue
        pieces: list[NDArray[np.intp]] = []
        _split(q, run, split_tol_m, pieces)
        # merge neighbours (they share their split point) that are one straight line after all
        merged: list[NDArray[np.intp]] = []
        for piece in pieces:
            if merged:
                cand = np.union1d(merged[-1], piece)
                if _fit_line(q[cand])[2] < 0.5 * max_rms_m:
                    merged[-1] = cand
                    continue
            merged.append(piece)
        for piece in merged:
            if len(piece) < min_points:
                continue
            c, d, rms = _fit_line(q[piece])
            s = (q[piece] - c) @ d
            start, end = c + s.min() * d, c + s.max() * d
            seg = ScanSegment(order[piece], start, end, rms)
            if seg.length_m >= min_length_m and rms <= max_rms_m:
                segs.append(seg)
    return segs


@dataclass(frozen=True)
class TargetObservation:
    """One board observation: the pattern found in the image, the plane it gives, and the scan.

    ``scan_xy`` (K, 2) is the whole scan in the LiDAR frame; ``board_indices`` are the scan
    points on the board, once found (or given).
    """

    name: str
    detection: BoardDetection
    plane: BoardPlane
    scan_xy: NDArray[np.float64]
    board_indices: NDArray[np.intp] | None = None

    @property
    def board_xy(self) -> NDArray[np.float64]:
        if self.board_indices is None:
            raise ValueError(f"{self.name}: board points not selected yet")
        return self.scan_xy[self.board_indices]


def _contained(seg_pts: NDArray[np.float64], tree: cKDTree, radius: float) -> float:
    d, _ = tree.query(seg_pts, distance_upper_bound=radius)
    return float(np.mean(np.isfinite(d)))


def linear_target_solution(planes: Sequence[BoardPlane], points: Sequence[NDArray[np.float64]],
                           free_direction: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Zhang & Pless's linear solution: ``H = [r1 r2 t]`` by least squares, then the nearest rotation.

    ``free_direction`` (camera frame): when every board normal is perpendicular to it (vertical
    boards), the constraints say nothing about ``H`` along it; the solution then has no
    component along it: the scan plane is perpendicular to it and passes through the camera
    centre. Each view counts equally, whatever its number of points.
    """
    if free_direction is not None:
        v = np.asarray(free_direction, dtype=np.float64) / np.linalg.norm(free_direction)
        basis = np.linalg.svd(np.eye(3) - np.outer(v, v))[0][:, :2]  # 3x2, orthonormal, ⟂ v
    else:
        basis = np.eye(3)
    k = basis.shape[1]
    rows, rhs = [], []
    for pl, pts in zip(planes, points):
        w = 1.0 / math.sqrt(len(pts))
        n = basis.T @ pl.normal
        a = np.hstack([np.outer(pts[:, 0], n), np.outer(pts[:, 1], n), np.tile(n, (len(pts), 1))])
        rows.append(w * a)
        rhs.append(w * np.full(len(pts), pl.distance_m))
    A, b = np.vstack(rows), np.concatenate(rhs)
    h, *_ = np.linalg.lstsq(A, b, rcond=None)
    h1, h2, t = basis @ h[0:k], basis @ h[k:2 * k], basis @ h[2 * k:3 * k]
    U, _, Vt = np.linalg.svd(np.column_stack([h1, h2]), full_matrices=False)
    r12 = U @ Vt
    R = np.column_stack([r12[:, 0], r12[:, 1], np.cross(r12[:, 0], r12[:, 1])])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def find_board_segments(
    scans: Sequence[NDArray[np.float64]],
    planes: Sequence[BoardPlane],
    board_width_m: float,
    *,
    static_radius_m: float = 0.04,
    max_sensor_offset_m: float = 1.5,
    max_residual_m: float = 0.05,
    iterations: int = 300,
    seed: int = 0,
) -> list[ScanSegment | None]:
    """Pick, in each scan, the straight segment where the scan cuts the board (None if none fits).

    Candidates: straight segments at least 80 % of the board's width (a scan may cut a board
    at a slant, never shorter), not part of the room (a segment found at the same place in
    half or more of the other scans is structure: the board moves between observations), and
    within ``max_sensor_offset_m`` of the distance the camera sees the board at. Then RANSAC
    over views: the linear solution from four views' candidates, every view takes the
    candidate closest to its plane, and the hypothesis that fits most views wins. A view
    whose best candidate is off its plane by more than ``max_residual_m`` (RMS) gets None.
    """
    cands: list[list[ScanSegment]] = []
    trees = [cKDTree(np.asarray(s)[np.isfinite(np.asarray(s)).all(axis=1)]) for s in scans]
    for i, (scan, plane) in enumerate(zip(scans, planes)):
        keep = []
        for seg in scan_segments(scan, min_length_m=0.8 * board_width_m):
            pts = np.asarray(scan)[seg.indices]
            if len(scans) >= 3:
                others = [j for j in range(len(scans)) if j != i]
                held = sum(_contained(pts, trees[j], static_radius_m) > 0.5 for j in others)
                if held >= 0.5 * len(others):
                    continue
            r = float(np.linalg.norm(seg.centre))
            if abs(r - float(np.linalg.norm(plane.centre))) > max_sensor_offset_m:
                continue
            keep.append(seg)
        log.debug("scan %d: %d board candidates", i, len(keep))
        cands.append(keep)
    present = [i for i, c in enumerate(cands) if c]
    chosen: list[ScanSegment | None] = [None] * len(scans)
    if len(present) < 3:
        for i in present:
            chosen[i] = min(cands[i], key=lambda s: abs(np.linalg.norm(s.centre) - np.linalg.norm(planes[i].centre)))
        return chosen
    cand_pts = {(i, k): np.asarray(scans[i])[s.indices] for i in present for k, s in enumerate(cands[i])}

    def assign(T: NDArray[np.float64], cap: float) -> tuple[float, dict[int, tuple[int, float]]]:
        best: dict[int, tuple[int, float]] = {}
        for i in present:
            rms = [float(np.sqrt(np.mean(_plane_residuals(T, planes[i], cand_pts[(i, k)]) ** 2)))
                   for k in range(len(cands[i]))]
            k = int(np.argmin(rms))
            best[i] = (k, rms[k])
        cost = sum(min(r, cap) for _, r in best.values())
        return cost, best

    rng = np.random.default_rng(seed)
    m = min(6, len(present))  # the linear solution needs five views or more (two equations each)
    n_combos = math.prod(len(cands[i]) for i in present)
    exhaustive = len(present) <= 6 and n_combos <= iterations
    samples = (itertools.product(*(range(len(cands[i])) for i in present)) if exhaustive else
               (() for _ in range(iterations)))  # random draws: the sample is not used
    hypotheses: list[tuple[float, NDArray[np.float64], NDArray[np.float64] | None]] = []
    for sample in samples:
        if exhaustive:
            views, picks = list(present), list(sample)
        else:
            views = [int(i) for i in rng.choice(present, m, replace=False)]
            picks = [int(rng.integers(len(cands[i]))) for i in views]
        sub_planes = [planes[i] for i in views]
        if np.linalg.svd(np.array([p.normal for p in sub_planes]), compute_uv=False)[1] < 0.05:
            continue
        free = _free_direction(sub_planes)
        sub_pts = [cand_pts[(i, k)] for i, k in zip(views, picks)]
        T = linear_target_solution(sub_planes, sub_pts, free)
        hypotheses.append((assign(T, 3 * max_residual_m)[0], T, free))
    # the linear solution is rough: polish the most promising hypotheses on every view they fit
    best_cost, best_assign = math.inf, {}
    for _, T, free in sorted(hypotheses, key=lambda h: h[0])[:8]:
        _, assignment = assign(T, 3 * max_residual_m)
        fit = [i for i, (_, r) in assignment.items() if r < 3 * max_residual_m]
        if len(fit) >= 3:
            T = _refine_fixed_planes(T, [planes[i] for i in fit], [cand_pts[(i, assignment[i][0])] for i in fit],
                                     free)
        cost, assignment = assign(T, max_residual_m)
        if cost < best_cost:
            best_cost, best_assign = cost, assignment
    if not best_assign:  # every sample was degenerate: fall back to the nearest-distance choice
        for i in present:
            chosen[i] = min(cands[i], key=lambda s: abs(np.linalg.norm(s.centre) - np.linalg.norm(planes[i].centre)))
        return chosen
    # re-solve from every view the hypothesis kept, and assign once more
    kept = [i for i, (_, r) in best_assign.items() if r < max_residual_m]
    if len(kept) >= 3:
        sub_planes = [planes[i] for i in kept]
        sub_pts = [cand_pts[(i, best_assign[i][0])] for i in kept]
        free = _free_direction(sub_planes)
        T = _refine_fixed_planes(linear_target_solution(sub_planes, sub_pts, free), sub_planes, sub_pts, free)
        _, best_assign = assign(T, max_residual_m)
    for i, (k, r) in best_assign.items():
        if r < max_residual_m:
            chosen[i] = cands[i][k]
        else:
            log.info("scan %d: no segment lies on the board's plane (best %.0f mm off)", i, r * 1e3)
    return chosen


def _free_direction(planes: Sequence[BoardPlane], min_tilt_deg: float = 5.0) -> NDArray[np.float64] | None:
    """The direction every board normal is perpendicular to, if there is one (vertical boards).

    With fewer than five views the linear system (two equations per view, nine unknowns) is
    short, so the least-spanned normal direction is treated as free for the start as well.
    """
    normals = np.array([p.normal for p in planes])
    _, s, vt = np.linalg.svd(normals, full_matrices=False)
    spread = math.degrees(math.asin(min(1.0, s[-1] / math.sqrt(len(planes)))))
    return vt[-1] if spread < min_tilt_deg or len(planes) < 5 else None


def _refine_fixed_planes(T0: NDArray[np.float64], planes: Sequence[BoardPlane],
                         points: Sequence[NDArray[np.float64]], free_direction: NDArray[np.float64] | None
                         ) -> NDArray[np.float64]:
    """Point-to-plane least squares with the planes as measured (robust, a few ms).

    With a ``free_direction`` the tilts about axes perpendicular to it and the offset along it
    stay at ``T0``'s values.
    """
    all_n = np.concatenate([np.tile(p.normal, (len(q), 1)) for p, q in zip(planes, points)])
    all_d = np.concatenate([np.full(len(q), p.distance_m) for p, q in zip(planes, points)])
    all_p = np.concatenate(points)
    if free_direction is not None:
        v = free_direction / np.linalg.norm(free_direction)
        perp = np.linalg.svd(np.eye(3) - np.outer(v, v))[0][:, :2]
        expand = np.zeros((6, 3))
        expand[:3, 0] = v  # rotation about v
        expand[3:, 1:] = perp  # translation perpendicular to v
    else:
        expand = np.eye(6)

    def residuals(y: NDArray[np.float64]) -> NDArray[np.float64]:
        T = _compose(expand @ y, T0)
        pc = all_p @ T[:3, :2].T + T[:3, 3]
        return np.sum(pc * all_n, axis=1) - all_d

    sol = least_squares(residuals, np.zeros(expand.shape[1]), method="trf", loss="soft_l1", f_scale=0.02)
    return _compose(expand @ sol.x, T0)


def _plane_residuals(T: NDArray[np.float64], plane: BoardPlane, pts_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    pc = pts_xy @ T[:3, :2].T + T[:3, 3]
    return pc @ plane.normal - plane.distance_m


@dataclass(frozen=True)
class ViewResidual:
    """How one observation agrees with the solution.

    ``rms_mm``/``mean_mm``: point-to-plane distance of the board's scan points (mm);
    ``line_angle_deg``: angle between the scan line (moved into the camera) and the plane.
    """

    name: str
    n_points: int
    rms_mm: float
    mean_mm: float
    line_angle_deg: float
    board_rms_px: float


@dataclass(frozen=True)
class TargetCalibration:
    """``T_cam_lidar`` from board observations, and how well each direction is known.

    ``rotation_std_deg`` / ``translation_std_m`` are 1-σ uncertainties about / along the
    LiDAR's own axes (x forward, y left, z up: roll, pitch, yaw; and the LiDAR's position).
    ``unobservable`` names the directions the boards did not constrain; they are held at the
    prior ``T_prior_cam_lidar``. ``normal_spread_deg`` is how far (RMS) the boards' normals
    leave their best common plane: near 0 (vertical boards) leaves the scan plane's height and
    tilt unobservable.
    """

    T_cam_lidar: NDArray[np.float64]
    T_linear_cam_lidar: NDArray[np.float64]
    T_prior_cam_lidar: NDArray[np.float64]
    views: tuple[ViewResidual, ...]
    rms_mm: float
    rotation_std_deg: NDArray[np.float64]
    translation_std_m: NDArray[np.float64]
    unobservable: tuple[str, ...]
    skipped: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    range_noise_m: float = 0.0
    pixel_noise_px: float = 0.0
    normal_spread_deg: float = 0.0

    @property
    def T_lidar_cam(self) -> NDArray[np.float64]:
        """The inverse: maps camera-frame points into the LiDAR frame."""
        return se3_inverse(self.T_cam_lidar)

    def report(self) -> dict[str, Any]:
        """What goes into the calibration file's ``extrinsics`` section."""
        return {
            "method": "board_planes",
            "views": len(self.views),
            "rms_mm": round(self.rms_mm, 3),
            "range_noise_m": round(self.range_noise_m, 5),
            "pixel_noise_px": round(self.pixel_noise_px, 4),
            "normal_spread_deg": round(self.normal_spread_deg, 3),
            "rotation_std_deg": {f"about_lidar_{a}": round(float(v), 4) for a, v in zip(AXES, self.rotation_std_deg)},
            "translation_std_m": {f"along_lidar_{a}": round(float(v), 5) for a, v in zip(AXES, self.translation_std_m)},
            "unobservable": list(self.unobservable),
            "per_view": [{"name": v.name, "points": v.n_points, "rms_mm": round(v.rms_mm, 3),
                          "mean_mm": round(v.mean_mm, 3), "line_angle_deg": round(v.line_angle_deg, 3),
                          "board_rms_px": round(v.board_rms_px, 3)} for v in self.views],
            "skipped": [{"name": n, "reason": r} for n, r in self.skipped],
        }


def _compose(delta: NDArray[np.float64], T0: NDArray[np.float64]) -> NDArray[np.float64]:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(delta[:3]).as_matrix() @ T0[:3, :3]
    T[:3, 3] = T0[:3, 3] + delta[3:]
    return T


def _delta(T: NDArray[np.float64], T0: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate([Rotation.from_matrix(T[:3, :3] @ T0[:3, :3].T).as_rotvec(), T[:3, 3] - T0[:3, 3]])


def _sigma_range(points: Sequence[NDArray[np.float64]]) -> float:
    """Range noise seen on the boards: the pooled RMS of straight-line fits (m), at least 2 mm."""
    ss = sum(_fit_line(p)[2] ** 2 * len(p) for p in points)
    n = sum(max(len(p) - 2, 1) for p in points)
    return max(math.sqrt(ss / n), 0.002)


def calibrate_target(
    observations: Sequence[TargetObservation],
    intrinsics: CameraIntrinsics,
    *,
    prior_T_cam_lidar: NDArray[np.float64] | None = None,
    prior_rotation_deg: float = 5.0,
    prior_translation_m: float = 0.2,
    range_noise_m: float | None = None,
    min_normal_spread_deg: float = 5.0,
) -> TargetCalibration:
    """Solve ``T_cam_lidar`` from observations whose ``board_indices`` are set.

    Starts from the linear solution, then refines ``T_cam_lidar`` jointly with every board's
    pose: the boards' corner pixels (reprojection error) and the scan points (distance to
    their board's plane) are weighted by their own noise, so a board whose plane the camera
    sees poorly (far, or facing it squarely) counts for less.

    The prior (default: the linear solution) only decides directions the boards leave free;
    ``prior_rotation_deg`` / ``prior_translation_m`` are its 1-σ widths. ``range_noise_m``
    defaults to the scatter of the board points about their lines. If the boards' normals
    leave their common plane by less than ``min_normal_spread_deg`` (RMS; vertical boards), the
    tilts about axes in that plane and the offset along its normal (for a level LiDAR: the
    scan plane's tilt and height) are held at the prior outright: they are only observable
    to second order.
    """
    obs = [o for o in observations if o.board_indices is not None and len(o.board_indices) >= 3]
    if len(obs) < 3:
        raise ConfigError(f"board observations: {len(obs)} usable; need at least 3 "
                          "(each with the board found in the image and in the scan)")
    normals = np.array([o.plane.normal for o in obs])
    _, sv_n, vt_n = np.linalg.svd(normals, full_matrices=False)
    if sv_n[1] / math.sqrt(len(obs)) < 0.05:
        raise ConfigError("board observations: every board faces the same way; turn the board "
                          "left/right (and tilt it) between observations")
    planes = [o.plane for o in obs]
    pts = [o.board_xy for o in obs]
    # how far the boards' normals leave a common plane: ~0 for vertical boards
    tilt = math.degrees(math.asin(min(1.0, sv_n[2] / math.sqrt(len(obs)))))
    v = vt_n[2]
    degenerate = tilt < min_normal_spread_deg
    T_lin = linear_target_solution(planes, pts, v if degenerate or len(obs) < 5 else None)
    T_prior = T_lin if prior_T_cam_lidar is None else np.asarray(prior_T_cam_lidar, dtype=np.float64)
    sig_rot = math.radians(prior_rotation_deg)
    sig_t = prior_translation_m
    held = 1e-6  # a prior this tight fixes a direction
    if degenerate:
        # prior basis: two axes perpendicular to v, then v; tilts about the first two and the
        # offset along v are what vertical boards cannot see
        basis = np.column_stack([np.linalg.svd(np.eye(3) - np.outer(v, v))[0][:, :2], v])
        sig_rot_axes = np.array([held, held, sig_rot])
        sig_t_axes = np.array([sig_t, sig_t, held])
    else:
        basis = T_prior[:3, :3]  # the LiDAR's axes
        sig_rot_axes = np.full(3, sig_rot)
        sig_t_axes = np.full(3, sig_t)
    sig_r = range_noise_m if range_noise_m is not None else _sigma_range(pts)
    sig_px = max(math.sqrt(np.mean([o.plane.rms_px**2 for o in obs]) / 2.0), 0.05)
    V = len(obs)
    boards0 = [o.plane.T_cam_board for o in obs]
    n_corner = [len(o.detection) for o in obs]

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        T = _compose(x[:6], T_prior)
        out = []
        for i, o in enumerate(obs):
            Tb = _compose(x[6 + 6 * i: 12 + 6 * i], boards0[i])
            pc = o.detection.object_points @ Tb[:3, :3].T + Tb[:3, 3]
            out.append(((project(intrinsics, pc) - o.detection.image_points) / sig_px).ravel())
            n = Tb[:3, 2]
            pl = pts[i] @ T[:3, :2].T + T[:3, 3]
            out.append((pl @ n - n @ Tb[:3, 3]) / sig_r)
        out.append((basis.T @ x[:3]) / sig_rot_axes)
        out.append((basis.T @ x[3:6]) / sig_t_axes)
        return np.concatenate(out)

    from scipy.sparse import lil_matrix

    n_res = sum(2 * c + len(p) for c, p in zip(n_corner, pts)) + 6
    sparsity = lil_matrix((n_res, 6 + 6 * V), dtype=int)
    row = 0
    for i in range(V):
        sparsity[row: row + 2 * n_corner[i], 6 + 6 * i: 12 + 6 * i] = 1
        row += 2 * n_corner[i]
        sparsity[row: row + len(pts[i]), 0:6] = 1
        sparsity[row: row + len(pts[i]), 6 + 6 * i: 12 + 6 * i] = 1
        row += len(pts[i])
    sparsity[row: row + 3, 0:3] = 1
    sparsity[row + 3: row + 6, 3:6] = 1
    x0 = np.zeros(6 + 6 * V)
    d0 = _delta(T_lin, T_prior)
    # start with the held directions at the prior's values
    keep_r, keep_t = (sig_rot_axes > held).astype(float), (sig_t_axes > held).astype(float)
    x0[:3] = basis @ ((basis.T @ d0[:3]) * keep_r)
    x0[3:6] = basis @ ((basis.T @ d0[3:]) * keep_t)
    sol = least_squares(residuals, x0, method="trf", loss="soft_l1", f_scale=3.0, x_scale="jac",
                        jac_sparsity=sparsity)
    T = _compose(sol.x[:6], T_prior)
    boards = [_compose(sol.x[6 + 6 * i: 12 + 6 * i], boards0[i]) for i in range(V)]
    J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
    dof = max(n_res - 6 - 6 * V, 1)
    s2 = max(2.0 * float(sol.cost) / dof, 1.0)
    try:
        cov = np.linalg.inv(J.T @ J)[:6, :6] * s2
    except np.linalg.LinAlgError:
        cov = np.diag(np.concatenate([sig_rot_axes, sig_t_axes]) ** 2)
    # into the LiDAR's axes: δω_lidar = Rᵀ δω_cam, δt_lidar = Rᵀ δt_cam
    rot = np.zeros((6, 6))
    rot[:3, :3] = rot[3:, 3:] = T[:3, :3].T
    std = np.sqrt(np.clip(np.diag(rot @ cov @ rot.T), 0, None))
    names = [f"rotation about lidar {a}" for a in AXES] + [f"translation along lidar {a}" for a in AXES]
    if degenerate:
        vl = T[:3, :3].T @ v  # the free direction in LiDAR axes
        if abs(vl[2]) > math.cos(math.radians(10)):
            unobs = [names[0], names[1], names[5]]
        else:
            vc = ", ".join(f"{c:.2f}" for c in v)
            unobs = [f"rotation about camera axes perpendicular to ({vc})", f"translation along camera ({vc})"]
    else:
        prior_sd = np.concatenate([sig_rot_axes, sig_t_axes])
        unobs = [n for k, n in enumerate(names) if std[k] > 0.5 * prior_sd[k]]
    if unobs:
        log.warning("the boards' normals all lie within %.1f° of one plane (boards standing vertical?): "
                    "%s not observable, held at the prior (lean the board forward/back by 20-40° in some "
                    "views, or give a prior calibration)", tilt, ", ".join(unobs))
    views = []
    all_r = []
    for o, p, Tb in zip(obs, pts, boards):
        n = Tb[:3, 2]
        pl = p @ T[:3, :2].T + T[:3, 3]
        r = pl @ n - n @ Tb[:3, 3]
        r = r if n @ Tb[:3, 3] > 0 else -r  # positive: the scan point lies behind the board
        all_r.append(r)
        _, d, _ = _fit_line(p)
        ang = math.degrees(math.asin(min(1.0, abs(float((T[:3, :2] @ d) @ n)))))
        pc = o.detection.object_points @ Tb[:3, :3].T + Tb[:3, 3]
        rms_px = float(np.sqrt(np.mean(np.sum((project(intrinsics, pc) - o.detection.image_points) ** 2, axis=1))))
        views.append(ViewResidual(o.name, len(p), float(np.sqrt(np.mean(r**2)) * 1e3), float(np.mean(r) * 1e3),
                                  ang, rms_px))
    rms = float(np.sqrt(np.mean(np.concatenate(all_r) ** 2)) * 1e3)
    used = {id(o) for o in obs}
    skipped = tuple((o.name, "board not found in the scan") for o in observations if id(o) not in used)
    return TargetCalibration(T, T_lin, T_prior, tuple(views), rms, np.degrees(std[:3]), std[3:], tuple(unobs), skipped,
                             range_noise_m=sig_r, pixel_noise_px=sig_px, normal_spread_deg=tilt)
