"""Loop closure: keyframes, place recognition, ICP verification and a robust pose graph.

Scan-to-map registration drifts; on a long tour the walls of a place seen twice double.
:class:`LoopCloser` takes every registered scan in order (:meth:`LoopCloser.add`) and at
the end returns corrected poses for all of them (:meth:`LoopCloser.optimise`).

* **Keyframes.** A scan becomes a keyframe after ``keyframe_distance`` m or
  ``keyframe_angle`` rad since the last one. Only keyframes keep points (float32: KISS-ICP's
  map down-sampling and each point's line-normal direction); every other scan keeps its
  index, keyframe and pose relative to it (36 bytes), so memory stays small on long tours
  and the graph has keyframe nodes only. A keyframe's own work (down-sampling, normals,
  descriptor and its matches, the step edge's re-match to the keyframe before) is
  :class:`KeyframeSelector`'s, which needs nothing the search learns: the build runs it where the
  scans are registered and hands its :class:`ScanRecord` to :meth:`LoopCloser.add_record` in
  another process.
* **Place recognition**, each time a keyframe is added, among keyframes at least
  ``min_separation`` keyframes older, best first:

  - tracked: the last loop found, carried forward by the registration's motion (within
    ``track_keyframes``): on a revisit each keyframe proposes the next with a guess good to
    centimetres, whatever the drift; a loop found late is also carried back over the
    keyframes before it (the drift hid the place from them);
  - by position: within ``search_radius`` + ``drift_per_m`` · (distance driven since them)
    of the drifted estimate;
  - with ``descriptor``, by a scan-context-style polar descriptor (rings × sectors; a cell
    is 1 inside the farthest return of its sector, so the descriptor is the visible area,
    which changes smoothly with position). Its ring key (share of sectors reaching each
    ring) is rotation invariant and pre-selects ``descriptor_preselect`` keyframes (brute
    force: exact, and at 20 dimensions as fast as a KD-tree); the column-shift comparison
    ranks them and yields a yaw guess, independent of the drift.

  Candidates within ``submap_keyframes`` of each other are one place, verified once from
  each of their guesses; at most ``max_candidates`` places per keyframe, and a place that
  just failed is not tried again for ``retry_keyframes``.
* **Verification**: KISS-ICP (:class:`~semmap.register.kiss.KissMatcher`) against the
  candidate and its ``submap_keyframes`` neighbours on each side (placed by the
  registration's relative poses), from each guess; then a point-to-line Gauss-Newton fit
  to the candidate keyframe alone (``refine_keyframes``: the registration's drift bends a
  longer submap by centimetres at its far end). A match is a loop when

  - ``min_inliers`` of the keyframe's points lie within ``inlier_distance`` of the submap,
    with a point-to-line RMS of at most ``max_rms``;
  - the point-to-line Hessian is well conditioned (smallest / largest eigenvalue ≥
    ``min_condition``, rotation scaled by the points' RMS range): a corridor match that can
    slide is not a loop;
  - the keyframe's beams passed through at most ``max_conflicts`` of the submap's points
    (free space: a place that only looks alike has walls where the keyframe saw through);
  - the correction it asks of the registration is plausible (``gate_factor``: moved at most
    that times the search radius, turned at most that times 3 σ of the registration's
    heading over the stretch). A candidate whose every guess lies beyond that radius by more
    than the ICP's reach is not verified at all (``skipped_gate``).

  Its covariance is the Hessian's inverse times the residual variance, the keyframe's
  points counted as ``loop_effective_points`` independent ones (scan residuals are
  correlated). It joins the graph once ``confirm`` loops found within ``track_keyframes``
  agree on where the keyframes are (a revisit yields a run of them; an alias rarely does).
* **Pose graph** (:func:`solve_pose_graph`): keyframe nodes; odometry edges between
  consecutive keyframes with the registration's relative poses and a covariance
  propagated from every step (the caller's information matrices, or a random-walk
  default); loop edges. :func:`scipy.optimize.least_squares` with an analytic sparse
  Jacobian (first node fixed), preconditioned by a sparse LDLᵀ factor of JᵀJ, from a robust
  linear initial estimate (LAGO); see there.
* **False loops** in the graph: loops that disagree with the loops around them are dropped
  first (pairwise consistency, greedily); then a Cauchy kernel on each loop's χ², graduated
  from a wide scale down to ``kernel_chi2`` over successive solves; then every loop whose χ²
  still exceeds ``reject_chi2`` is dropped and the graph re-solved.

Frames: poses are ``T_map_base`` as SE(2) ``(x, y, yaw)``; a loop or odometry measurement
between keyframes i and j is ``T_i_j``; covariances are of a right perturbation (in the
frame of j), errors ``e = t2v(Z⁻¹ · X_i⁻¹ · X_j)``.
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import RegistrationConfig
from ..geometry import se2_apply, se2_between, se2_compose, se2_inverse, wrap_angle

__all__ = [
    "KeyframeSelector",
    "LoopCloser",
    "LoopConfig",
    "LoopResult",
    "ScanRecord",
    "descriptor_distance",
    "ring_key",
    "scan_context",
    "solve_pose_graph",
]

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
_LINEAR_FLOOR = 20.0  # the linear estimate's Cauchy scale, in kernel_chi2 (it overstates χ²)
_GNC_RATIO = 2.0  # the Cauchy scale shrinks by this factor between the nonlinear solves
_RESTART_NFEV = 10  # least_squares evaluations before the preconditioner is renewed


@dataclass(frozen=True)
class LoopConfig:
    """Loop closure settings (lengths in m, angles in rad)."""

    # keyframes
    keyframe_distance: float = 0.5  # m driven between keyframes
    keyframe_angle: float = 0.35  # rad turned between keyframes
    # place recognition
    min_separation: int = 30  # keyframes between the two ends of a loop candidate (no trivial loops)
    search_radius: float = 3.0  # m, plus drift_per_m * distance driven since the candidate
    drift_per_m: float = 0.05
    descriptor: bool = True  # also candidates from the polar descriptor (independent of the drifted estimate)
    descriptor_rings: int = 20
    descriptor_sectors: int = 60
    descriptor_range: float = 15.0  # m, outer radius of the descriptor
    descriptor_preselect: int = 10  # nearest ring keys compared column by column
    descriptor_threshold: float = 0.15  # descriptor distance (1 - column cosine similarity) below which a place
    #                                     may match
    max_candidates: int = 3  # candidate places verified per new keyframe
    rematch: bool = True  # each keyframe matched point-to-line to the one before: the graph's step edge
    max_loops_per_keyframe: int = 1  # stop verifying a keyframe's candidates after this many loops
    # verification
    submap_keyframes: int = 5  # each side: the candidate's neighbours form the map a keyframe is matched against
    refine_keyframes: int = 0  # each side: the final point-to-line fit is to these (drift bends a longer submap)
    track_keyframes: int = 10  # the last loop found, carried forward this many keyframes, proposes the next
    min_points: int = 20  # fewer down-sampled points in the keyframe: not matched
    icp_threshold: float = 0.5  # m, KISS-ICP kernel σ for loop ICP (correspondences within 3σ)
    refine_iterations: int = 20  # point-to-line Gauss-Newton steps after KISS-ICP
    max_query_points: int = 200  # the keyframe's points fitted and counted (evenly thinned to this many)
    min_inliers: float = 0.6  # share of the query points within inlier_distance of the submap after ICP
    inlier_distance: float = 0.1  # m
    min_condition: float = 0.05  # smallest / largest eigenvalue of the scaled point-to-line Hessian
    max_rms: float = 0.03  # m, point-to-line RMS of the inliers above which a match is too loose to be the place
    max_conflicts: float = 0.2  # share of the submap's points the keyframe's beams passed through (free space)
    retry_keyframes: int = 4  # a place that failed verification is not tried again for this many keyframes
    confirm: int = 3  # a loop counts once this many found within track_keyframes agree (1: at once)
    confirm_distance: float = 0.3  # m, how well two loops must agree on where the later keyframe is
    confirm_angle: float = 0.1  # rad, and on its heading
    gate_factor: float = 2.0  # a loop moving a keyframe more than this × the search radius, or turning it more
    #                            than this × 3 σ of the registration's heading, is rejected (0: off)
    loop_sigma_min: float = 0.01  # m, floor of the residual σ in the loop covariance
    loop_effective_points: float = 10.0  # the query points count as this many independent ones
    # odometry edges: default covariance of one registration step (random walk in the distance driven)
    odom_sigma_xy: float = 0.002  # m per step
    odom_sigma_yaw: float = 0.001  # rad per step
    odom_sigma_xy_per_sqrt_m: float = 0.02  # m per √m driven
    odom_sigma_yaw_per_sqrt_m: float = 0.02  # rad per √m driven
    odom_sigma_yaw_per_sqrt_rad: float = 0.01  # rad per √rad turned
    # robust solve
    pairwise_window: int = 50  # keyframes: loops whose ends are this close must agree with each other (0: off)
    pairwise_chi2: float = 25.0  # χ² of a pair's disagreement beyond which they do not agree
    kernel_chi2: float = 25.0  # scale (χ²) of the Cauchy kernel on loop edges
    reject_chi2: float = 50.0  # after the solve, loops above this χ² are dropped and the graph re-solved
    max_rejection_rounds: int = 10
    max_nfev: int = 50  # least_squares evaluations per solve
    tolerance: float = 1e-6  # least_squares ftol, xtol and gtol

    def __post_init__(self) -> None:
        positive = ("keyframe_distance", "keyframe_angle", "descriptor_range", "icp_threshold",
                    "inlier_distance", "max_rms", "loop_sigma_min", "loop_effective_points", "pairwise_chi2",
                    "kernel_chi2",
                    "reject_chi2", "tolerance")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"LoopConfig.{name} must be > 0, got {getattr(self, name)}")
        at_least_one = ("descriptor_rings", "descriptor_sectors", "descriptor_preselect", "max_loops_per_keyframe",
                        "min_points", "max_query_points", "max_nfev", "confirm")
        for name in at_least_one:
            if getattr(self, name) < 1:
                raise ValueError(f"LoopConfig.{name} must be >= 1, got {getattr(self, name)}")
        non_negative = ("min_separation", "search_radius", "drift_per_m", "descriptor_threshold", "max_candidates",
                        "confirm_distance", "confirm_angle",
                        "submap_keyframes", "refine_keyframes", "track_keyframes", "refine_iterations",
                        "min_condition", "max_conflicts", "retry_keyframes", "gate_factor", "odom_sigma_xy",
                        "odom_sigma_yaw", "odom_sigma_xy_per_sqrt_m", "odom_sigma_yaw_per_sqrt_m",
                        "odom_sigma_yaw_per_sqrt_rad", "pairwise_window", "max_rejection_rounds")
        for name in non_negative:
            if not getattr(self, name) >= 0:
                raise ValueError(f"LoopConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 < self.min_inliers <= 1.0:
            raise ValueError(f"LoopConfig.min_inliers must be in (0, 1], got {self.min_inliers}")
        if self.odom_sigma_xy <= 0 and self.odom_sigma_xy_per_sqrt_m <= 0:
            raise ValueError("LoopConfig: odometry translation variance would be zero")
        if self.odom_sigma_yaw <= 0 and self.odom_sigma_yaw_per_sqrt_m <= 0 and self.odom_sigma_yaw_per_sqrt_rad <= 0:
            raise ValueError("LoopConfig: odometry yaw variance would be zero")


@dataclass(frozen=True)
class LoopResult:
    """What :meth:`LoopCloser.optimise` returns.

    ``poses``: (N, 3) corrected ``T_map_base`` per :meth:`LoopCloser.add` call, in order;
    ``stats``: counters and timings (see :meth:`LoopCloser.optimise`);
    ``loops``: the loops kept, as the scan indices of their two keyframes (a older than b).
    """

    poses: F64
    stats: dict[str, Any]
    loops: list[tuple[int, int]] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------
# Place recognition: a scan-context-style polar descriptor


def scan_context(points_xy: ArrayLike, rings: int, sectors: int, max_range: float) -> NDArray[np.float32]:
    """The (rings, sectors) polar descriptor of base-frame points.

    Sector s covers bearings [-π + s·2π/S, -π + (s+1)·2π/S); a cell is 1 when its ring
    lies inside the farthest return of its sector (the visible area), 0 beyond it or in
    sectors without returns. Ring r covers ranges [r, r+1) · max_range / rings.
    """
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    out = np.zeros((rings, sectors), dtype=np.float32)
    if pts.shape[0] == 0:
        return out
    r = np.hypot(pts[:, 0], pts[:, 1])
    a = np.arctan2(pts[:, 1], pts[:, 0])
    keep = np.isfinite(r) & (r > 0)
    r, a = np.minimum(r[keep], max_range), a[keep]
    sec = np.clip(((a + np.pi) * (sectors / (2.0 * np.pi))).astype(np.int64), 0, sectors - 1)
    far = np.zeros(sectors)
    np.maximum.at(far, sec, r)
    edge = np.ceil(far * (rings / max_range)).astype(np.int64)  # rings reached, 0 for an empty sector
    out[:] = (np.arange(rings)[:, None] < edge[None, :]).astype(np.float32)
    return out


def ring_key(desc: NDArray[np.float32]) -> NDArray[np.float32]:
    """The rotation-invariant ring key of a descriptor: per ring, the share of sectors reaching it."""
    return np.asarray(desc.mean(axis=-1), dtype=np.float32)


def descriptor_distance(query: NDArray[np.float32], others: NDArray[np.float32]) -> tuple[F64, F64]:
    """Distance of ``query`` (R, S) to each of ``others`` (C, R, S) at the best column shift.

    The distance is 1 - the cosine similarity of the columns summed over those present in
    both and divided by the number present in the fuller one (scan context, with sectors
    outside one field of view counting as unlike); it is 1 when no column pairs up. Returns
    (distances (C,), yaw (C,)), the yaw being that of the query's frame in the other's frame
    implied by the best shift.
    """
    q = np.asarray(query, dtype=np.float64)
    c = np.asarray(others, dtype=np.float64).reshape(-1, *q.shape)
    n_sec = q.shape[1]
    if c.shape[0] == 0:
        return np.zeros(0), np.zeros(0)
    qn = q / np.maximum(np.linalg.norm(q, axis=0, keepdims=True), 1e-12)
    cn = c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)
    c_present = c.sum(axis=1) > 0  # (C, S)
    # the cosines of the columns present in both, summed over the columns, at every shift k: a
    # column absent from either is all zeros (the descriptors are not negative), so this is the
    # circular cross-correlation of the two along the sectors, summed over the rings, [c, k] =
    # Σ_s cn[c, :, s] · qn[:, s + k], by FFT
    spec = (np.conj(np.fft.rfft(cn, axis=-1)) * np.fft.rfft(qn, axis=-1)[None]).sum(axis=1)
    cos_sum = np.fft.irfft(spec, n=n_sec, axis=-1)  # (C, K)
    # columns present in only one count as dissimilar: a narrow field of view must not match
    # by overlapping the other's in a few sectors
    n_either = np.maximum(int((q.sum(axis=0) > 0).sum()), c_present.sum(axis=1))  # (C,)
    # rounded, so that shifts the descriptors cannot tell apart tie exactly (the first wins)
    sim = np.round(cos_sum / np.maximum(n_either, 1)[:, None], 9)  # (C, K)
    best = np.argmax(sim, axis=1)
    dist = 1.0 - sim[np.arange(c.shape[0]), best]
    # query column s + k matches the other's column s: a bearing b there is b + kΔ here, so the
    # query frame is turned by -kΔ in the other's frame
    yaw = wrap_angle(-best * (2.0 * np.pi / n_sec))
    return dist, np.asarray(yaw, dtype=np.float64).reshape(-1)


# ---------------------------------------------------------------------------------------------
# Verification: point-to-line refinement against a submap


@dataclass(frozen=True)
class _Match:
    pose: F64  # T_sub_query
    inliers: float  # share of query points within inlier_distance
    condition: float  # smallest / largest eigenvalue of the scaled Hessian
    cov: F64  # 3x3 covariance of a right perturbation of pose
    rms: float  # point-to-line RMS of the inliers, m


def _line_normals(points: F64, neighbours: int = 6, max_spread: float = 0.5, max_flatness: float = 0.05) -> F64:
    """The direction (rad) of each point's line normal, NaN where its neighbourhood is no line.

    PCA of the ``neighbours`` nearest points (closed form in 2D); a line when they lie within
    ``max_spread`` m and spread across it by at most ``max_flatness`` of the spread along it.
    """
    from scipy.spatial import cKDTree

    n = points.shape[0]
    if n < 3:
        return np.full(n, np.nan)
    k = min(neighbours, n)
    d, idx = cKDTree(points).query(points, k=k)
    nb = points[idx.reshape(n, k)]
    c = nb - nb.mean(axis=1, keepdims=True)
    sxx = np.mean(c[..., 0] ** 2, axis=1)
    syy = np.mean(c[..., 1] ** 2, axis=1)
    sxy = np.mean(c[..., 0] * c[..., 1], axis=1)
    half = 0.5 * (sxx + syy)
    root = np.sqrt((0.5 * (sxx - syy)) ** 2 + sxy**2)
    flat = (half - root) <= max_flatness * np.maximum(half + root, 1e-12)
    near = d.reshape(n, k)[:, -1] <= max_spread
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy) + 0.5 * np.pi  # across the principal direction
    return np.where(flat & near, angle, np.nan)


class _Submap:
    """Points with their line normals (directions, NaN: no line) and a KD-tree."""

    def __init__(self, points: F64, normal_angles: F64) -> None:
        from scipy.spatial import cKDTree

        self.points = points
        # built for each place verified (hundreds a tour) and queried a few dozen times: the sliding
        # midpoint split without compaction builds in two thirds of the time and queries as fast
        self.tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
        self.good = np.isfinite(normal_angles)
        a = np.where(self.good, normal_angles, 0.0)
        self.normals = np.column_stack([np.cos(a), np.sin(a)])


def _correspondences(sub: _Submap, pts: F64, pose: F64, radius: float) -> tuple[F64, F64, F64, float]:
    """Point-to-line residuals of ``pts`` placed at ``pose`` against ``sub`` within ``radius``.

    Returns (residuals (U,), Jacobian (U, 3) with respect to (x, y, yaw) added to ``pose``,
    the used points relative to the pose's origin (U, 2), the share of ``pts`` with a submap
    point within ``radius``). A point is used when its nearest submap point lies on a line.
    Called some twenty thousand times a long tour (each Gauss-Newton step of every verification),
    so it is written for few array operations: the search tree's query is most of its time.
    """
    c, s = math.cos(pose[2]), math.sin(pose[2])
    v_all = pts @ np.array([[c, s], [-s, c]])  # rotated into the submap's frame
    d, idx = sub.tree.query(v_all + pose[:2], distance_upper_bound=radius)
    near = np.flatnonzero(d < np.inf)
    share = near.size / pts.shape[0] if pts.shape[0] else 0.0
    i = idx[near]
    ok = sub.good[i]
    i = i[ok]
    v = v_all[near[ok]]
    nrm = sub.normals[i]
    diff = v + (pose[:2] - sub.points[i])
    jac = np.empty((i.shape[0], 3))
    jac[:, :2] = nrm
    jac[:, 2] = nrm[:, 1] * v[:, 0] - nrm[:, 0] * v[:, 1]
    r = nrm[:, 0] * diff[:, 0] + nrm[:, 1] * diff[:, 1]
    return r, jac, v, share


def _scaled_condition(h: F64, v: F64) -> float:
    """Smallest over largest eigenvalue of a point-to-line Hessian, rotation in metres at the points'
    (``v``, relative to the pose's origin) RMS range, so that the eigenvalues compare."""
    scale = math.sqrt(float(np.mean(np.sum(v * v, axis=1)))) or 1.0
    d = np.array([1.0, 1.0, 1.0 / scale])
    ev = np.linalg.eigvalsh(h * d[:, None] * d[None, :])
    return float(ev[0] / ev[-1]) if ev[-1] > 0 else 0.0


#: Gauss-Newton steps after which a fit still far below ``min_condition`` (a quarter of it) stops:
#: along a corridor it slides without converging, and its match is refused as degenerate anyway.
#: After 5 steps some fits on the Intel log that would have slid into a corner were cut; after 10
#: none were (the same loops on Intel, Freiburg 101 and the simulated ``loop`` tour)
_DEGENERATE_AFTER = 10
#: a Gauss-Newton step below this (m, and rad) ends the fit: a millimetre and 0.06°, a tenth of the
#: loop edges' floor (``loop_sigma_min``); 1e-4 before stop 56 took a third more steps for the same loops
#: on Intel and Freiburg 101 (their RPE and ATE the same to the millimetre)
_STEP_TOL = 1e-3
#: after this many steps, a fit with fewer than this share of the keyframe's points within reach of the
#: submap (3 · ``inlier_distance``) stops: it will not reach ``min_inliers``. On Intel and Freiburg 101
#: no fit that ended with 60 % inliers had fewer than half its points in reach by its fifth step
_HOPELESS_AFTER = 5
_HOPELESS_SHARE = 0.5


def _align(sub: _Submap, pts: F64, guess: F64, cfg: LoopConfig) -> F64:
    """Point-to-line ICP (Gauss-Newton, Cauchy weights) of ``pts`` onto ``sub`` from ``guess``."""
    pose = np.asarray(guess, dtype=np.float64).copy()
    c = 0.5 * cfg.inlier_distance
    for it in range(cfg.refine_iterations):
        r, jac, v, share = _correspondences(sub, pts, pose, 3.0 * cfg.inlier_distance)
        if r.shape[0] < 3:
            break
        if it >= _HOPELESS_AFTER and share < _HOPELESS_SHARE:
            break
        jw = jac * (1.0 / (1.0 + (r / c) ** 2))[:, None]
        h = jw.T @ jac
        if it >= _DEGENERATE_AFTER and _scaled_condition(h, v) < 0.25 * cfg.min_condition:
            break
        try:
            step = np.linalg.solve(h + 1e-9 * np.eye(3), jw.T @ r)
        except np.linalg.LinAlgError:
            break
        pose = pose - step
        pose[2] = wrap_angle(float(pose[2]))
        if math.hypot(step[0], step[1]) < _STEP_TOL and abs(step[2]) < _STEP_TOL:
            break
    return pose


def _overlap(sub: _Submap, pts: F64, pose: F64, cfg: LoopConfig) -> float:
    """The share of ``pts`` at ``pose`` within ``inlier_distance`` of ``sub``."""
    d, _ = sub.tree.query(se2_apply(pose, pts), distance_upper_bound=cfg.inlier_distance)
    return float(np.isfinite(d).mean()) if d.size else 0.0


def _evaluate(sub: _Submap, pts: F64, pose: F64, cfg: LoopConfig) -> _Match:
    """Inlier share, conditioning and covariance of ``pts`` at ``pose`` on ``sub``."""
    r, jac, v, inliers = _correspondences(sub, pts, pose, cfg.inlier_distance)
    n = r.shape[0]
    if n < 3:
        return _Match(pose, inliers, 0.0, np.eye(3), float("inf"))
    h = jac.T @ jac / n
    condition = _scaled_condition(h, v)
    rms = math.sqrt(float(np.mean(r * r)))
    sigma2 = max(rms, cfg.loop_sigma_min) ** 2
    try:
        cov_add = sigma2 * np.linalg.inv(h) / cfg.loop_effective_points
    except np.linalg.LinAlgError:
        return _Match(pose, inliers, 0.0, np.eye(3), rms)
    a = _rot3(-pose[2])  # (t, yaw) added -> right perturbation (t = R ρ)
    return _Match(pose, inliers, condition, a @ cov_add @ a.T, rms)


def _free_space_conflicts(sub: F64, query: F64, pose: F64, cfg: LoopConfig, bins: int = 360) -> float:
    """The share of submap points (``sub``, (M, 2)) that the query scan's beams passed through.

    ``query`` (N, 2) are the keyframe's points in its own frame, placed at ``pose`` in the
    submap. Per bearing bin (1°), the query's nearest return; a submap point in that bin more
    than 2 · ``inlier_distance`` closer than it lies where every beam of the bin saw free
    space. A place that merely looks alike has walls where the keyframe saw through.
    """
    r_q = np.hypot(query[:, 0], query[:, 1])
    b_q = ((np.arctan2(query[:, 1], query[:, 0]) + np.pi) * (bins / (2.0 * np.pi))).astype(np.int64) % bins
    nearest = np.full(bins, np.inf)
    np.minimum.at(nearest, b_q, r_q)
    p = se2_apply(se2_inverse(pose), sub)
    r = np.hypot(p[:, 0], p[:, 1])
    b = ((np.arctan2(p[:, 1], p[:, 0]) + np.pi) * (bins / (2.0 * np.pi))).astype(np.int64) % bins
    seen = np.isfinite(nearest[b]) & (r > 3.0 * cfg.inlier_distance)
    n = int(seen.sum())
    if n == 0:
        return 0.0
    return float(np.sum(seen & (r < nearest[b] - 2.0 * cfg.inlier_distance)) / n)


# ---------------------------------------------------------------------------------------------
# The pose graph


def _rot3(yaw: float) -> F64:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _adjoint(pose: F64) -> F64:
    """SE(2) adjoint: ``T · exp(ξ) = exp(Ad_T ξ) · T``."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, y], [s, c, -x], [0.0, 0.0, 1.0]])


def _upper_factors(info: F64) -> F64:
    """U with Uᵀ U = info, for (E, 3, 3) information matrices (symmetrised, made positive definite)."""
    info = 0.5 * (info + np.swapaxes(info, -1, -2))
    try:
        low = np.linalg.cholesky(info)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(info)
        w = np.maximum(w, 1e-9 * np.maximum(w.max(axis=-1, keepdims=True), 1e-12))
        low = np.linalg.cholesky(np.einsum("eij,ej,ekj->eik", v, w, v))
    return np.asarray(np.swapaxes(low, -1, -2))


def _edge_errors(pi: F64, pj: F64, z: F64) -> F64:
    """``t2v(Z⁻¹ · Pi⁻¹ · Pj)`` for (E, 3) arrays."""
    ci, si = np.cos(pi[:, 2]), np.sin(pi[:, 2])
    dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
    ux = ci * dx + si * dy - z[:, 0]
    uy = -si * dx + ci * dy - z[:, 1]
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    return np.column_stack([cz * ux + sz * uy, -sz * ux + cz * uy,
                            wrap_angle(pj[:, 2] - pi[:, 2] - z[:, 2])])


def loop_chi2(poses: ArrayLike, loop_a: ArrayLike, loop_b: ArrayLike, loop_z: ArrayLike,
              loop_info: ArrayLike) -> F64:
    """χ² (Mahalanobis²) of each loop edge at the given node poses."""
    p = np.asarray(poses, dtype=np.float64)
    a = np.asarray(loop_a, dtype=np.int64)
    b = np.asarray(loop_b, dtype=np.int64)
    e = _edge_errors(p[a], p[b], np.asarray(loop_z, dtype=np.float64).reshape(-1, 3))
    return np.asarray(np.einsum("ei,eij,ej->e", e, np.asarray(loop_info, dtype=np.float64).reshape(-1, 3, 3), e))


def _linear_solve(n_nodes: int, a: NDArray[np.int64], b: NDArray[np.int64], target: F64, info: F64,
                  fixed: F64) -> F64:
    """Minimise Σ (x_b - x_a - target)ᵀ info (x_b - x_a - target) over node values x (dim d), x_0 = ``fixed``.

    ``target`` (E, d), ``info`` (E, d, d). One sparse direct solve of the normal equations.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    d = target.shape[1]
    blk = np.arange(d)
    ia = (d * a)[:, None] + blk  # (E, d)
    ib = (d * b)[:, None] + blk
    rows = np.concatenate([np.repeat(ia, d, axis=1), np.repeat(ib, d, axis=1),
                           np.repeat(ia, d, axis=1), np.repeat(ib, d, axis=1)]).ravel()
    cols = np.concatenate([np.tile(ia, d), np.tile(ib, d), np.tile(ib, d), np.tile(ia, d)]).ravel()
    flat = info.reshape(-1, d * d)
    h = coo_matrix((np.concatenate([flat, flat, -flat, -flat]).ravel(), (rows, cols)),
                   shape=(d * n_nodes, d * n_nodes)).tocsc()
    lt = np.einsum("eij,ej->ei", info, target)
    g = np.zeros(d * n_nodes)
    np.add.at(g, ib.ravel(), lt.ravel())
    np.add.at(g, ia.ravel(), -lt.ravel())
    free = h[d:, d:]
    rhs = g[d:] - h[d:, :d] @ fixed
    x = np.asarray(spsolve(free, rhs), dtype=np.float64).reshape(-1, d)
    return np.vstack([fixed.reshape(1, d), x])


def _linear_estimate(p0: F64, a: NDArray[np.int64], b: NDArray[np.int64], z: F64, cov: F64, n_chain: int,
                     weights: F64) -> F64:
    """Orientations, then positions, each by linear least squares (LAGO, Carlone et al. 2014).

    The first ``n_chain`` edges are the chain, whose composed yaws fix each other edge's 2π
    ambiguity. ``cov`` (E, 3, 3) covariances; ``weights`` (E,) scale the informations.
    """
    n = p0.shape[0]
    chain_yaw = p0[0, 2] + np.concatenate([[0.0], np.cumsum(z[:n_chain, 2])])
    turns = np.round((chain_yaw[b] - chain_yaw[a] - z[:, 2]) / (2.0 * np.pi))
    dyaw = z[:, 2] + 2.0 * np.pi * turns
    w_yaw = weights / np.maximum(cov[:, 2, 2], 1e-18)
    yaw = _linear_solve(n, a, b, dyaw[:, None], w_yaw[:, None, None], p0[0, 2:3])[:, 0]
    # t_b - t_a = R(yaw_a) z_t; error frame R(yaw_a + z_yaw)
    ca, sa = np.cos(yaw[a]), np.sin(yaw[a])
    dt = np.column_stack([ca * z[:, 0] - sa * z[:, 1], sa * z[:, 0] + ca * z[:, 1]])
    rot = yaw[a] + z[:, 2]
    c, s = np.cos(rot), np.sin(rot)
    r = np.stack([np.stack([c, -s], axis=-1), np.stack([s, c], axis=-1)], axis=-2)
    info_xy = np.linalg.inv(cov[:, :2, :2])
    info_w = np.einsum("eij,ejk,elk->eil", r, info_xy, r) * weights[:, None, None]
    xy = _linear_solve(n, a, b, dt, info_w, p0[0, :2])
    return np.column_stack([xy, yaw])


def _edge_jacobians(pi: F64, pj: F64, z: F64) -> F64:
    """(E, 3, 6) Jacobians of :func:`_edge_errors` with respect to (x_i, y_i, yaw_i, x_j, y_j, yaw_j)."""
    ci, si = np.cos(pi[:, 2]), np.sin(pi[:, 2])
    dx, dy = pj[:, 0] - pi[:, 0], pj[:, 1] - pi[:, 1]
    tx, ty = ci * dx + si * dy, -si * dx + ci * dy  # Pj in Pi's frame
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    c, s = np.cos(pi[:, 2] + z[:, 2]), np.sin(pi[:, 2] + z[:, 2])  # R_zᵀ R_iᵀ = R(-(yaw_i + yaw_z))
    jac = np.zeros((pi.shape[0], 3, 6))
    jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 0], jac[:, 1, 1] = -c, -s, s, -c
    jac[:, 0, 3], jac[:, 0, 4], jac[:, 1, 3], jac[:, 1, 4] = c, s, -s, c
    jac[:, 0, 2] = cz * ty - sz * tx  # R_zᵀ (ty, -tx)
    jac[:, 1, 2] = -sz * ty - cz * tx
    jac[:, 2, 2], jac[:, 2, 5] = -1.0, 1.0
    return jac


def _nonlinear_solve(p0: F64, a: NDArray[np.int64], b: NDArray[np.int64], z: F64, info: F64, max_nfev: int,
                     tolerance: float) -> tuple[F64, dict[str, Any]]:
    """:func:`scipy.optimize.least_squares` on the absolute poses (node 0 fixed), from ``p0``.

    Analytic sparse Jacobian. LSMR, the solver least_squares uses for sparse problems, needs
    many iterations on a pose graph (its normal matrix is a graph Laplacian); the unknowns are
    therefore preconditioned by the exact LDLᵀ factor of JᵀJ at ``p0`` (SuperLU, fill-reducing
    order): ``x = x0 + M (y - y0)`` with ``Mᵀ JᵀJ M = I``, which takes a handful of evaluations.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import csc_matrix, csr_matrix, identity
    from scipy.sparse.linalg import LinearOperator, splu

    n_nodes, n_edges = p0.shape[0], a.shape[0]
    n_var = 3 * (n_nodes - 1)
    u = _upper_factors(info)
    three = np.arange(3)
    rows = np.repeat(3 * np.arange(n_edges)[:, None] + three, 6, axis=1).ravel()  # (E, 3, 6) row-major
    node_cols = np.concatenate([3 * (a[:, None] - 1) + three, 3 * (b[:, None] - 1) + three], axis=1)
    cols = np.tile(node_cols, (1, 3)).ravel()
    keep = cols >= 0  # node 0 is fixed
    rows, cols = rows[keep], cols[keep]

    def full(x: F64) -> F64:
        return np.vstack([p0[:1], x.reshape(-1, 3)])

    def residuals(x: F64) -> F64:
        p = full(x)
        return np.asarray(np.einsum("eij,ej->ei", u, _edge_errors(p[a], p[b], z)).ravel())

    def jacobian(x: F64) -> Any:
        p = full(x)
        jac = np.einsum("eij,ejk->eik", u, _edge_jacobians(p[a], p[b], z)).ravel()[keep]
        return csr_matrix((jac, (rows, cols)), shape=(3 * n_edges, n_var))

    t0 = time.perf_counter()
    x = p0[1:].ravel().copy()
    nfev, status, cost = 0, 0, 0.0
    while nfev < max_nfev:
        # a preconditioner for the Jacobian at x; when the solution wanders far from it, LSMR
        # slows down again, so least_squares is restarted with a fresh one every few steps
        x0 = x
        j0 = jacobian(x0)
        h = csc_matrix(j0.T @ j0)
        h = csc_matrix(h + identity(n_var, format="csc") * (1e-9 * max(float(h.diagonal().max()), 1e-12)))
        lu = splu(h, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        if not np.array_equal(lu.perm_r, lu.perm_c):  # pragma: no cover - SuperLU pivoted off the diagonal
            raise np.linalg.LinAlgError("the pose graph's normal matrix is not positive definite")
        order = np.argsort(lu.perm_c)
        inv_sqrt_d = 1.0 / np.sqrt(np.maximum(lu.U.diagonal(), 1e-300))
        lower = splu(csc_matrix(lu.L), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                     options={"SymmetricMode": True})

        def m_apply(y: F64, lower: Any = lower, order: Any = order, inv_sqrt_d: F64 = inv_sqrt_d) -> F64:
            v = lower.solve(inv_sqrt_d * y, trans="T")  # M y = Pᵀ L⁻ᵀ D^-1/2 y
            out = np.empty_like(v)
            out[order] = v
            return out

        def mt_apply(r: F64, lower: Any = lower, order: Any = order, inv_sqrt_d: F64 = inv_sqrt_d) -> F64:
            return np.asarray(inv_sqrt_d * lower.solve(r[order]))  # Mᵀ r = D^-1/2 L⁻¹ P r

        # least_squares starts its trust region at |y0| (1 when y0 = 0): offset y so that the
        # first radius is of the size of a Gauss-Newton step in these whitened units
        y0 = np.full(n_var, 10.0 * float(np.linalg.norm(residuals(x0))) / math.sqrt(n_var) + 1.0)

        def fun(y: F64, x0: F64 = x0, y0: F64 = y0, m_apply: Any = m_apply) -> F64:
            return residuals(x0 + m_apply(y - y0))

        def jac(y: F64, x0: F64 = x0, y0: F64 = y0, m_apply: Any = m_apply, mt_apply: Any = mt_apply
                ) -> LinearOperator:
            j = jacobian(x0 + m_apply(y - y0))
            return LinearOperator(j.shape, matvec=lambda v: j @ m_apply(np.ravel(v)),
                                  rmatvec=lambda r: mt_apply(j.T @ np.ravel(r)), dtype=np.float64)

        res = least_squares(fun, y0, jac=jac, method="trf", tr_solver="lsmr",
                            max_nfev=min(_RESTART_NFEV, max_nfev - nfev), ftol=tolerance, xtol=tolerance,
                            gtol=tolerance)
        x = x0 + m_apply(res.x - y0)
        nfev += int(res.nfev)
        status, cost = int(res.status), float(res.cost)
        if status != 0:  # converged
            break
    p = full(x)
    p[:, 2] = wrap_angle(p[:, 2])
    return p, {"nfev": nfev, "status": status, "cost": cost, "seconds": time.perf_counter() - t0}


def _pairwise_consistent(p0: F64, odom_cov: F64, la: NDArray[np.int64], lb: NDArray[np.int64], lz: F64,
                         loop_cov: F64, window: int, chi2_max: float) -> NDArray[np.bool_]:
    """The largest set of mutually consistent loops found greedily (pairwise consistency, as PCM).

    Two loops whose ends are within ``window`` nodes of each other's must agree on where the
    second's later end lies, through the chain's short stretches between their ends: the
    cycle ``Z_i · T(b_i → b_j)`` against ``T(a_i → a_j) · Z_j``, its χ² taken with both loops'
    covariances and the stretches' (summed along the chain, the heading's share growing with
    the stretch's length). Loops farther apart are not compared. Then, while any pair
    disagrees, the loop in most disagreements is dropped. A false loop can agree with the
    registration alone (it is the odometry that decides), but not with the true loops around it.
    """
    n_loops = la.shape[0]
    keep = np.ones(n_loops, dtype=bool)
    if n_loops < 2:
        return keep
    lo, hi = np.minimum(la, lb), np.maximum(la, lb)
    flip = la > lb  # orient every loop forward: T_lo_hi
    z = lz.copy()
    if np.any(flip):
        z[flip] = se2_inverse(lz[flip])
    step = np.hypot(*(p0[1:, :2] - p0[:-1, :2]).T)
    path = np.concatenate([[0.0], np.cumsum(step)])
    var_t = np.concatenate([[0.0], np.cumsum(0.5 * (odom_cov[:, 0, 0] + odom_cov[:, 1, 1]))])
    var_r = np.concatenate([[0.0], np.cumsum(odom_cov[:, 2, 2])])
    loop_t = 0.5 * (loop_cov[:, 0, 0] + loop_cov[:, 1, 1])
    loop_r = loop_cov[:, 2, 2]
    i, j = np.triu_indices(n_loops, k=1)
    near = (np.abs(lo[i] - lo[j]) <= window) & (np.abs(hi[i] - hi[j]) <= window)
    i, j = i[near], j[near]
    if i.size == 0:
        return keep

    def stretch(u: NDArray[np.int64], v: NDArray[np.int64]) -> tuple[F64, F64, F64]:
        a, b = np.minimum(u, v), np.maximum(u, v)
        length = path[b] - path[a]
        vr = var_r[b] - var_r[a]
        return se2_between(p0[u], p0[v]), var_t[b] - var_t[a] + vr * length**2 / 3.0, vr

    t_hi, vt_hi, vr_hi = stretch(hi[i], hi[j])
    t_lo, vt_lo, vr_lo = stretch(lo[i], lo[j])
    via_i = se2_compose(z[i], t_hi)
    via_j = se2_compose(t_lo, z[j])
    d = via_i - via_j
    d[:, 2] = wrap_angle(d[:, 2])
    # the second loop's error reaches the cycle turned by the first stretch; heading errors of
    # the loops themselves move the far end by their lever arm
    arm2 = np.sum(t_hi[:, :2] ** 2, axis=1) + np.sum(t_lo[:, :2] ** 2, axis=1)
    vt = loop_t[i] + loop_t[j] + vt_hi + vt_lo + (loop_r[i] + loop_r[j]) * arm2
    vr = loop_r[i] + loop_r[j] + vr_hi + vr_lo
    chi2 = (d[:, 0] ** 2 + d[:, 1] ** 2) / vt + d[:, 2] ** 2 / vr
    bad = chi2 > chi2_max
    i, j = i[bad], j[bad]
    while i.size:
        counts = np.bincount(np.concatenate([i, j]), minlength=n_loops)
        worst = int(np.argmax(counts))
        keep[worst] = False
        alive = (i != worst) & (j != worst)
        i, j = i[alive], j[alive]
    return keep


def solve_pose_graph(poses: ArrayLike, odom_z: ArrayLike, odom_info: ArrayLike, loop_a: ArrayLike,
                     loop_b: ArrayLike, loop_z: ArrayLike, loop_info: ArrayLike, *, kernel_chi2: float = 25.0,
                     reject_chi2: float = 50.0, max_rejection_rounds: int = 10, max_nfev: int = 50,
                     tolerance: float = 1e-6, pairwise_window: int = 50, pairwise_chi2: float = 25.0
                     ) -> tuple[F64, NDArray[np.bool_], dict[str, Any]]:
    """Solve a pose graph whose nodes form a chain, with extra (loop) edges; reject false loops.

    ``poses`` (K, 3): the nodes' initial poses (the chain composed); node 0 stays fixed (gauge).
    ``odom_z`` (K-1, 3): the measurement ``T_{i-1}_i`` of each chain edge, ``odom_info``
    (K-1, 3, 3) its information. ``loop_a``, ``loop_b`` (L,) node numbers, ``loop_z`` (L, 3)
    ``T_a_b``, ``loop_info`` (L, 3, 3).

    0. Loops that disagree with the loops around them (ends within ``pairwise_window`` nodes;
       disagreement χ² above ``pairwise_chi2``) are dropped, the one in most disagreements first.
    1. A robust linear initial estimate: orientations then positions by sparse linear least
       squares (LAGO, Carlone et al. 2014), the loops re-weighted with a Cauchy kernel on their
       χ² whose scale shrinks to 20 × ``kernel_chi2`` (the linear estimate is approximate: true
       loops can show χ² of tens there). It needs no initial guess, so a drift of tens of
       degrees is no problem, and gross false loops lose their weight.
    2. :func:`scipy.optimize.least_squares` from that estimate, a few steps at a time, the loops
       weighted by the Cauchy kernel of their χ² in the previous solution, its scale halving
       from 20 × ``kernel_chi2`` to ``kernel_chi2`` (graduated non-convexity).
    3. Loops whose χ² still exceeds ``reject_chi2`` are dropped and the graph solved with the
       rest at full weight, until none does (at most ``max_rejection_rounds`` times).

    Returns (poses (K, 3), kept (L,) bool, info: ``nfev``, ``rejected_pairwise``,
    ``rejected_after_solve``, ``seconds``).
    """
    t0 = time.perf_counter()
    p0 = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    n = p0.shape[0]
    zo = np.asarray(odom_z, dtype=np.float64).reshape(-1, 3)
    io = np.asarray(odom_info, dtype=np.float64).reshape(-1, 3, 3)
    la = np.asarray(loop_a, dtype=np.int64).reshape(-1)
    lb = np.asarray(loop_b, dtype=np.int64).reshape(-1)
    lz = np.asarray(loop_z, dtype=np.float64).reshape(-1, 3)
    li = np.asarray(loop_info, dtype=np.float64).reshape(-1, 3, 3)
    n_loops = la.shape[0]
    if zo.shape[0] != n - 1 or io.shape[0] != n - 1:
        raise ValueError(f"{n} nodes need {n - 1} chain edges, got {zo.shape[0]} and {io.shape[0]} informations")
    if not (lb.shape[0] == lz.shape[0] == li.shape[0] == n_loops):
        raise ValueError("loop_a, loop_b, loop_z and loop_info must have one entry per loop")
    if n_loops and (np.any(la < 0) or np.any(lb < 0) or np.any(la >= n) or np.any(lb >= n) or np.any(la == lb)):
        raise ValueError("loop edges must join two different existing nodes")
    info: dict[str, Any] = {"nfev": 0, "rejected_pairwise": 0, "rejected_after_solve": 0, "seconds": 0.0}
    kept = np.ones(n_loops, dtype=bool)
    if n < 2 or n_loops == 0:
        return p0.copy(), kept, info
    a = np.concatenate([np.arange(n - 1), la])
    b = np.concatenate([np.arange(1, n), lb])
    z = np.concatenate([zo, lz])
    lam = 0.5 * (np.concatenate([io, li]) + np.swapaxes(np.concatenate([io, li]), 1, 2))
    cov = np.linalg.inv(lam)
    n_chain = n - 1

    # 0. loops that disagree with the loops around them
    if pairwise_window > 0:
        kept &= _pairwise_consistent(p0, cov[:n_chain], la, lb, lz, cov[n_chain:], pairwise_window, pairwise_chi2)
        info["rejected_pairwise"] = int(n_loops - kept.sum())
        if not kept.any():
            info["seconds"] = time.perf_counter() - t0
            return p0.copy(), kept, info

    # 1. robust linear estimate (graduated Cauchy re-weighting of the loops, down to a wide scale)
    weights = np.concatenate([np.ones(n_chain), kept.astype(np.float64)])
    p_lin = _linear_estimate(p0, a, b, z, cov, n_chain, weights)
    chi2 = loop_chi2(p_lin, la, lb, lz, li)
    floor = _LINEAR_FLOOR * kernel_chi2
    c2 = max(float(chi2[kept].max()), floor)
    for _ in range(60):
        c2 = max(c2 / 4.0, floor)
        new = kept / (1.0 + chi2 / c2)
        done = c2 == floor and float(np.max(np.abs(new - weights[n_chain:]))) < 1e-3
        weights[n_chain:] = new
        p_lin = _linear_estimate(p0, a, b, z, cov, n_chain, weights)
        chi2 = loop_chi2(p_lin, la, lb, lz, li)
        if done:
            break

    # 2. nonlinear solves, re-weighting the loops (Cauchy on each loop's χ², its scale graduated
    # down to kernel_chi2) from their χ² in the previous solution
    def solve(start: F64, loop_weights: F64, nfev: int) -> F64:
        idx = np.concatenate([np.arange(n_chain), n_chain + np.flatnonzero(kept)])
        w = np.concatenate([np.ones(n_chain), loop_weights[kept]])
        out, sinfo = _nonlinear_solve(start, a[idx], b[idx], z[idx], lam[idx] * w[:, None, None], nfev, tolerance)
        info["nfev"] += sinfo["nfev"]
        return out

    p = p_lin
    scales = [_LINEAR_FLOOR]
    while scales[-1] > 1.0:
        scales.append(max(scales[-1] / _GNC_RATIO, 1.0))
    for scale in scales:  # (only the weights matter: a few steps each)
        p = solve(p, weights[n_chain:], min(max_nfev, _RESTART_NFEV))
        weights[n_chain:] = kept / (1.0 + loop_chi2(p, la, lb, lz, li) / (scale * kernel_chi2))

    # 3. loops that still do not fit are dropped, all above reject_chi2 at once (their weights kept
    # a false loop from raising the others' χ²), and the graph solved with the rest at full weight
    for _ in range(max_rejection_rounds + 1):
        idx = np.flatnonzero(kept)
        chi2 = loop_chi2(p, la[idx], lb[idx], lz[idx], li[idx])
        bad = idx[chi2 > reject_chi2]
        if bad.size:
            log.info("loop closure: %d of %d loops dropped after the solve (χ² %.1f to %.1f)", bad.size, n_loops,
                     float(chi2[chi2 > reject_chi2].min()), float(chi2.max()))
            kept[bad] = False
            info["rejected_after_solve"] += int(bad.size)
        if not kept.any():
            p = p0.copy()
            break
        if bad.size == 0 and np.all(weights[n_chain:][kept] == 1.0):
            break
        weights[n_chain:] = kept.astype(np.float64)
        p = solve(p, weights[n_chain:], max_nfev)
    info["seconds"] = time.perf_counter() - t0
    return p, kept, info


# ---------------------------------------------------------------------------------------------
# The loop closer


@dataclass(frozen=True)
class _Loop:
    a: int  # keyframe numbers, a older than b
    b: int
    z: F64  # T_a_b
    info: F64  # 3x3
    kind: str  # "tracked", "position", "descriptor" or "external"


class _Buffer:
    """A growing (n, width) array (amortised doubling)."""

    def __init__(self, width: int, dtype: Any = np.float64) -> None:
        self._data = np.zeros((64, width), dtype=dtype)
        self.n = 0

    def append(self, row: ArrayLike) -> None:
        if self.n == self._data.shape[0]:
            self._data = np.concatenate([self._data, np.zeros_like(self._data)])
        self._data[self.n] = row
        self.n += 1

    @property
    def view(self) -> NDArray[Any]:
        return self._data[: self.n]

    @property
    def nbytes(self) -> int:
        return int(self._data.nbytes)


def _blend_corrections(before: F64, kf: NDArray[np.int64], kf_scan: NDArray[np.int64], raw: F64, solved: F64) -> F64:
    """Every scan's corrected pose: its registered pose ``before`` moved by the correction of its keyframe
    (``solved · raw⁻¹``, in the map frame), blended linearly into the next keyframe's by the scan's place
    between the two (scan numbers). A scan moved rigidly with its keyframe would jump against the next
    keyframe's scans wherever the corrections of two keyframes differ, doubling walls at cell scale."""
    corr = se2_compose(solved, se2_inverse(raw))  # (K, 3): T_corrected_registered of each keyframe
    n = before.shape[0]
    k0 = np.asarray(kf, np.intp)
    k1 = np.minimum(k0 + 1, corr.shape[0] - 1)
    s0 = np.asarray(kf_scan, np.float64)[k0]
    s1 = np.asarray(kf_scan, np.float64)[k1]
    idx = np.arange(n, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(s1 > s0, (idx - s0) / (s1 - s0), 0.0)
    f = np.clip(f, 0.0, 1.0)[:, None]
    c0, c1 = corr[k0], corr[k1]
    d = c1 - c0
    d[:, 2] = wrap_angle(d[:, 2])
    c = c0 + f * d
    return se2_compose(c, before)


@dataclass(frozen=True)
class ScanRecord:
    """What :class:`KeyframeSelector` makes of one registered scan for :meth:`LoopCloser.add_record`.

    Every scan: its ``index``, ``pose`` (``T_map_base``) and ``keyframe`` flag; a scan that is not a
    keyframe, its pose ``rel`` in the last keyframe's frame. A keyframe also carries what the loop
    search needs of it: the distance driven up to it (``dist``) and the heading variance accumulated
    (``var_yaw``), its step edge from the keyframe before (``step_z``, ``step_info``; None for the first
    keyframe) and whether that edge was re-matched (``rematched``), its down-sampled points with their
    line-normal directions (``points``, (M, 3) float32), the ICP source (``source``) and the points
    fitted (``dense``), in float64, and the older keyframes its descriptor matched (``descriptor_matches``,
    (D, 2): keyframe number and the yaw of this keyframe in its frame, best first; see
    :meth:`KeyframeSelector.descriptor_matches`).
    """

    index: int
    pose: F64
    keyframe: bool
    rel: F64
    dist: float = 0.0
    var_yaw: float = 0.0
    step_z: F64 | None = None
    step_info: F64 | None = None
    rematched: bool | None = None
    points: NDArray[np.float32] | None = None
    source: F64 | None = None
    dense: F64 | None = None
    descriptor_matches: F64 | None = None
    seconds: float = 0.0  # spent on the step edge's re-match


class KeyframeSelector:
    """The loop closer's front end: keyframe selection and each keyframe's own work.

    It takes every registered scan in order (:meth:`make`) and needs only the keyframe before the
    current one, so it can run where the scans are registered while the loop search
    (:meth:`LoopCloser.add_record`) runs in another process: the keyframe's down-sampling, line
    normals and descriptor, the re-match of its step edge to the keyframe before, and the place
    recognition by descriptor, which needs every keyframe's descriptor (1.2 kB each, kept here) but
    nothing the search learns.
    """

    def __init__(self, cfg: LoopConfig, reg_cfg: RegistrationConfig | None = None) -> None:
        self.cfg = cfg
        reg = reg_cfg if reg_cfg is not None else RegistrationConfig()
        self._icp_cfg = reg.model_copy(update={"initial_threshold": cfg.icp_threshold})
        self._prep: Any = None  # a KissMatcher used for down-sampling only (created lazily)
        self._last_pose: F64 | None = None
        self._dist = 0.0
        self._cov = np.zeros((3, 3))  # covariance of the current scan relative to its keyframe
        self._kf_pose: F64 | None = None  # the last keyframe's pose
        self._kf_points: NDArray[np.float32] | None = None  # and its points (x, y, normal direction)
        self._var_yaw = 0.0
        self._keys = _Buffer(cfg.descriptor_rings, np.float32)  # every keyframe's ring key
        self._descs: list[NDArray[np.bool_]] = []  # and descriptor (0/1 cells, kept as bool)

    def make(self, index: int, pose: ArrayLike, points_xy: ArrayLike, info: ArrayLike | None = None) -> ScanRecord:
        """The record of a registered scan; see :meth:`LoopCloser.add` for the arguments."""
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"pose must be a finite (x, y, yaw), got {pose!r}")
        p = np.array([p[0], p[1], wrap_angle(float(p[2]))])
        cfg = self.cfg
        if self._last_pose is not None:
            step = se2_between(self._last_pose, p)
            self._dist += math.hypot(step[0], step[1])
            adj = _adjoint(se2_inverse(step))
            self._cov = adj @ self._cov @ adj.T + self._step_cov(step, info)
        self._last_pose = p
        rel = se2_between(self._kf_pose, p) if self._kf_pose is not None else np.zeros(3)
        if self._kf_pose is not None and math.hypot(rel[0], rel[1]) < cfg.keyframe_distance \
                and abs(rel[2]) < cfg.keyframe_angle:
            return ScanRecord(index, p, False, rel)
        # a new keyframe
        pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        dense, source = self.prepare(pts)
        step_z = step_info = None
        rematched = None
        seconds = 0.0
        if self._kf_pose is not None:
            step_z, step_info = rel, _inverse_spd(self._cov)
            if cfg.rematch:
                t0 = time.perf_counter()
                step_z, step_info, rematched = self._rematch(dense, rel, step_info)
                seconds = time.perf_counter() - t0
            self._var_yaw += float(self._cov[2, 2])
        self._cov = np.zeros((3, 3))
        desc = scan_context(dense, cfg.descriptor_rings, cfg.descriptor_sectors, cfg.descriptor_range)
        self._descs.append(desc > 0.5)
        self._keys.append(ring_key(desc))
        points = np.column_stack([dense, _line_normals(dense)]).astype(np.float32)
        self._kf_pose, self._kf_points = p, points
        return ScanRecord(index, p, True, np.zeros(3), self._dist, self._var_yaw, step_z, step_info, rematched,
                          points, source, dense, self.descriptor_matches(len(self._descs) - 1), seconds)

    def descriptor_matches(self, k: int) -> F64:
        """The keyframes at least ``min_separation`` older than keyframe ``k`` that its descriptor matches:
        (D, 2) keyframe numbers and yaws (of k's frame in theirs, from the best column shift), best first.

        The ``descriptor_preselect`` nearest ring keys (rotation invariant; brute force: exact, and at 20
        dimensions as fast as a KD-tree) are compared column by column; those within
        ``descriptor_threshold`` are kept."""
        cfg = self.cfg
        last = k - cfg.min_separation
        if not cfg.descriptor or last < 0 or cfg.max_candidates == 0:
            return np.zeros((0, 2))
        keys = self._keys.view[: last + 1]
        kd = np.sum((keys - self._keys.view[k]) ** 2, axis=1)
        m = min(cfg.descriptor_preselect, kd.shape[0])
        pre = np.argpartition(kd, m - 1)[:m]
        dd, yaw = descriptor_distance(self._descs[k].astype(np.float32),
                                      np.stack([self._descs[j] for j in pre]).astype(np.float32))
        order = np.argsort(dd)
        order = order[dd[order] <= cfg.descriptor_threshold]
        return np.column_stack([pre[order].astype(np.float64), yaw[order]])

    def memory_bytes(self) -> int:
        """Bytes held: every keyframe's descriptor and ring key, and the last keyframe's points."""
        total = sum(int(d.nbytes) for d in self._descs) + self._keys.nbytes
        return total + (0 if self._kf_points is None else int(self._kf_points.nbytes))

    def prepare(self, pts: F64) -> tuple[F64, F64]:
        """(map points (M, 2), ICP source (S, 2)) as KISS-ICP down-samples them."""
        if pts.shape[0] == 0:
            return np.zeros((0, 2)), np.zeros((0, 2))
        if self._prep is None:
            from .kiss import KissMatcher

            self._prep = KissMatcher(self._icp_cfg)
        prepared = self._prep.prepare(pts)
        return prepared.map_points[:, :2].copy(), prepared.source[:, :2].copy()

    def _step_cov(self, step: F64, info: ArrayLike | None) -> F64:
        if info is not None:
            lam = np.asarray(info, dtype=np.float64).reshape(3, 3)
            if np.all(np.isfinite(lam)):
                try:
                    cov = np.linalg.inv(0.5 * (lam + lam.T))
                    if np.all(np.linalg.eigvalsh(cov) > 0):
                        return np.asarray(cov)
                except np.linalg.LinAlgError:
                    pass
            log.debug("step information %s unusable; the default is used", lam.tolist())
        cfg = self.cfg
        d = math.hypot(step[0], step[1])
        var_xy = cfg.odom_sigma_xy ** 2 + cfg.odom_sigma_xy_per_sqrt_m ** 2 * d
        var_yaw = (cfg.odom_sigma_yaw ** 2 + cfg.odom_sigma_yaw_per_sqrt_m ** 2 * d
                   + cfg.odom_sigma_yaw_per_sqrt_rad ** 2 * abs(step[2]))
        return np.diag([var_xy, var_xy, var_yaw])

    def _rematch(self, dense: F64, rel: F64, info: F64) -> tuple[F64, F64, bool]:
        """The step edge from the last keyframe to the new one: its points (``dense``, base frame) fitted
        point-to-line to the last keyframe's, from the registration's relative pose ``rel``; and whether
        the fit was taken.

        Scan-to-map registration matches each scan to everything seen within range; where that map
        is sparse or holds an earlier pass of the same place, its steps err by decimetres now and
        then. A direct fit to the previous keyframe is the graph-mapping edge (Kümmerle et al. 2009):
        on the Intel log it halves the median step error. Taken when it passes the loop tests
        (inliers, conditioning, RMS); otherwise the registration's step and ``info`` are kept.
        """
        cfg = self.cfg
        assert self._kf_points is not None
        stored = self._kf_points.astype(np.float64)
        if stored.shape[0] < cfg.min_points or dense.shape[0] < cfg.min_points:
            return rel, info, False
        dense = _thin(dense, cfg.max_query_points)
        sub = _Submap(stored[:, :2], stored[:, 2])
        match = _evaluate(sub, dense, _align(sub, dense, rel, cfg), cfg)
        if match.inliers < cfg.min_inliers or match.condition < cfg.min_condition or match.rms > cfg.max_rms:
            return rel, info, False
        return match.pose, _inverse_spd(match.cov), True


class LoopCloser:
    """Keyframes, loop detection and verification while a tour is registered; a robust pose graph at the end.

    >>> closer = LoopCloser(LoopConfig())                           # doctest: +SKIP
    >>> for i, (pose, pts) in enumerate(zip(poses, points)):        # doctest: +SKIP
    ...     closer.add(i, pose, pts)
    >>> result = closer.optimise()                                  # doctest: +SKIP
    >>> result.poses.shape, result.stats["accepted"], result.loops  # doctest: +SKIP

    ``reg_cfg`` supplies KISS-ICP's settings (voxel size, ranges, iterations) for the
    keyframes' down-sampling and the loop ICP; its ``initial_threshold`` is replaced by
    ``cfg.icp_threshold``.
    """

    def __init__(self, cfg: LoopConfig, reg_cfg: RegistrationConfig | None = None) -> None:
        self.cfg = cfg
        reg = reg_cfg if reg_cfg is not None else RegistrationConfig()
        self._icp_cfg = reg.model_copy(update={"initial_threshold": cfg.icp_threshold})
        self._front = KeyframeSelector(cfg, reg)  # for add(); add_record() takes records made elsewhere
        self._verifier: Any = None  # the KissMatcher of the verifications (lazily)
        # (keyframe, first, last) -> the submap verified against there (see _place), the latest last
        self._places: OrderedDict[tuple[int, int, int], tuple[F64, _Submap, _Submap, Any] | None] = OrderedDict()
        # every scan: its index, keyframe and pose in the keyframe's frame
        self._scan_index = _Buffer(1, np.int64)
        self._scan_kf = _Buffer(1, np.int32)
        self._scan_rel = _Buffer(3)
        # keyframes
        self._kf_pose = _Buffer(3)  # T_map_kf from registration
        self._kf_dist = _Buffer(1)  # distance driven up to the keyframe, m
        self._kf_var_yaw = _Buffer(1)  # the registration's heading variance accumulated up to the keyframe, rad²
        self._kf_scan = _Buffer(1, np.int64)  # the keyframe's scan index
        # (M, 3) float32 per keyframe: base-frame x, y (KISS-ICP's map down-sampling) and line-normal direction
        self._kf_points: list[NDArray[np.float32]] = []
        self._odom_z = _Buffer(3)  # T_{kf-1}_kf
        self._odom_info = _Buffer(9)
        self._loops: list[_Loop] = []
        self._last_loop: _Loop | None = None  # the last loop found, carried forward as a candidate
        self._pending: list[_Loop] = []  # loops verified but not yet confirmed by a second one
        self._counts = {"candidates": 0, "verified": 0, "accepted": 0, "rejected_inliers": 0,
                        "rejected_degenerate": 0, "rejected_fit": 0, "rejected_gate": 0, "skipped_gate": 0,
                        "skipped_retry": 0,
                        "unconfirmed": 0, "from_tracked": 0, "from_position": 0, "from_descriptor": 0,
                        "external": 0, "rematched": 0, "rematch_kept": 0}
        self._failed: dict[int, int] = {}  # place (keyframe) -> the keyframe whose verification against it failed
        self._seconds_search = 0.0
        self._seconds_rematch = 0.0

    # -- public ------------------------------------------------------------------------------
    @property
    def keyframes(self) -> int:
        """The number of keyframes so far."""
        return self._kf_pose.n

    @property
    def scans(self) -> int:
        """The number of scans added so far."""
        return self._scan_kf.n

    @property
    def stored_points(self) -> int:
        """Points kept in memory (keyframes only)."""
        return sum(int(p.shape[0]) for p in self._kf_points)

    def memory_bytes(self) -> int:
        """Approximate bytes held: keyframe points and descriptors, per-scan and per-keyframe arrays, and the
        points of the places kept for verification (not their search trees and voxel maps)."""
        total = sum(int(p.nbytes) for p in self._kf_points) + self._front.memory_bytes()
        total += sum(int(pl[0].nbytes + pl[1].points.nbytes + pl[1].normals.nbytes)
                     for pl in self._places.values() if pl is not None)
        for buf in (self._scan_index, self._scan_kf, self._scan_rel, self._kf_pose, self._kf_dist, self._kf_var_yaw,
                    self._kf_scan, self._odom_z, self._odom_info):
            total += buf.nbytes
        return total

    def add(self, index: int, pose: ArrayLike, points_xy: ArrayLike, info: ArrayLike | None = None) -> None:
        """Add a registered scan, in order.

        ``index``: the scan's number (reported in :attr:`LoopResult.loops`); ``pose``: its
        ``T_map_base`` (x, y, yaw) from scan-to-map registration; ``points_xy``: its (N, 2)
        points in the base frame (down-sampled, dynamic points removed); ``info``: the 3x3
        information matrix of the registration step from the previous scan (a right
        perturbation, in this scan's frame), or None for the configured default.
        A keyframe is searched for loops, and its candidates verified, right away.
        """
        self.add_record(self._front.make(index, pose, points_xy, info))

    def add_record(self, rec: ScanRecord) -> None:
        """Add a scan as a :class:`KeyframeSelector` of the same settings made it, in order: what
        :meth:`add` does after the keyframe's own work, which may thus run in another process."""
        cfg = self.cfg
        n_kf = self._kf_pose.n
        if not rec.keyframe:
            if n_kf == 0:
                raise ValueError("the first scan added must be a keyframe")
            self._scan_index.append(rec.index)
            self._scan_kf.append(n_kf - 1)
            self._scan_rel.append(rec.rel)
            return
        assert rec.points is not None and rec.source is not None and rec.dense is not None
        assert rec.descriptor_matches is not None
        if n_kf:
            if rec.step_z is None or rec.step_info is None:
                raise ValueError("a keyframe after the first needs its step edge")
            self._odom_z.append(rec.step_z)
            self._odom_info.append(np.asarray(rec.step_info).ravel())
            if rec.rematched is not None:
                self._counts["rematched" if rec.rematched else "rematch_kept"] += 1
            self._seconds_rematch += rec.seconds
        self._scan_index.append(rec.index)
        self._scan_kf.append(n_kf)
        self._scan_rel.append(np.zeros(3))
        self._kf_pose.append(rec.pose)
        self._kf_dist.append(rec.dist)
        self._kf_var_yaw.append(rec.var_yaw)
        self._kf_scan.append(rec.index)
        self._kf_points.append(rec.points)
        if rec.source.shape[0] >= cfg.min_points:
            t0 = time.perf_counter()
            self._search(n_kf, rec.source, rec.dense, rec.descriptor_matches)
            self._seconds_search += time.perf_counter() - t0

    def add_loop(self, index_a: int, index_b: int, t_a_b: ArrayLike, info: ArrayLike) -> None:
        """Add a loop constraint from elsewhere: ``T_a_b`` between the scans numbered ``index_a``
        and ``index_b`` (already added), with its 3x3 information (right perturbation at b).
        It goes through the same robust solve as the detected loops."""
        ia, ib = self._scan_pos(index_a), self._scan_pos(index_b)
        ka, kb = int(self._scan_kf.view[ia, 0]), int(self._scan_kf.view[ib, 0])
        ra, rb = self._scan_rel.view[ia], self._scan_rel.view[ib]
        if ka == kb:
            raise ValueError("a loop within one keyframe's scans constrains nothing")
        z = se2_compose(se2_compose(ra, np.asarray(t_a_b, dtype=np.float64).reshape(3)), se2_inverse(rb))
        adj = _adjoint(rb)  # X_b exp(ξ) = X_kf exp(Ad_rb ξ) r_b
        adj_inv = np.linalg.inv(adj)
        lam = adj_inv.T @ np.asarray(info, dtype=np.float64).reshape(3, 3) @ adj_inv
        if ka > kb:
            ka, kb = kb, ka
            adj_z = _adjoint(z)
            inv_adj_z = np.linalg.inv(adj_z)
            lam = inv_adj_z.T @ lam @ inv_adj_z
            z = se2_inverse(z)
        self._loops.append(_Loop(ka, kb, z, lam, "external"))
        self._counts["external"] += 1

    def optimise(self) -> LoopResult:
        """Solve the keyframe pose graph; corrected poses for every scan added.

        ``stats``: ``scans``, ``keyframes``; ``candidates`` (places verified) and ``verified``
        (ICP runs); ``accepted`` (loops that passed verification: ``from_tracked``,
        ``from_position``, ``from_descriptor``) and ``external``; rejected at verification:
        ``rejected_inliers``, ``rejected_degenerate``, ``rejected_fit`` (RMS or free space),
        ``rejected_gate``; not verified: ``skipped_gate`` (every guess beyond the gate already),
        ``skipped_retry``; ``unconfirmed`` (never joined the graph);
        rejected by the solve: ``rejected_pairwise``, ``rejected_after_solve``; ``loops``
        (kept); ``seconds_search``, ``seconds_solve``, ``solver_evaluations``;
        ``max_correction_m`` and ``max_correction_rad`` (largest change of a scan's pose);
        ``memory_bytes``. Can be called again after more :meth:`add` calls.
        """
        t0 = time.perf_counter()
        cfg = self.cfg
        stats: dict[str, Any] = {"scans": self.scans, "keyframes": self.keyframes, **self._counts}
        n_kf = self.keyframes
        raw = self._kf_pose.view.copy()
        kept: list[_Loop] = []
        rejected = 0
        nfev = 0
        # the chain's initial poses: the registration's, or its steps re-matched keyframe to keyframe composed
        chain = raw if not self._counts["rematched"] else _compose_chain(raw[0], self._odom_z.view)
        if n_kf >= 2 and (self._loops or self._counts["rematched"]):
            loops = self._loops
            try:
                poses, keep, info = solve_pose_graph(
                    chain, self._odom_z.view, self._odom_info.view.reshape(-1, 3, 3), [lp.a for lp in loops],
                    [lp.b for lp in loops], [lp.z for lp in loops], [lp.info for lp in loops],
                    kernel_chi2=cfg.kernel_chi2, reject_chi2=cfg.reject_chi2,
                    max_rejection_rounds=cfg.max_rejection_rounds, max_nfev=cfg.max_nfev,
                    tolerance=cfg.tolerance, pairwise_window=cfg.pairwise_window, pairwise_chi2=cfg.pairwise_chi2)
            except np.linalg.LinAlgError as exc:  # pragma: no cover - a degenerate graph
                log.warning("loop closure: the pose graph could not be solved (%s); poses left as registered", exc)
                stats["solver_failed"] = True
                poses, keep, info = raw, np.zeros(len(loops), dtype=bool), {"nfev": 0, "rejected_after_solve": 0}
            kept = [lp for lp, k in zip(loops, keep) if k]
            stats["rejected_pairwise"] = int(info.get("rejected_pairwise", 0))
            rejected = int(info["rejected_after_solve"])
            nfev = int(info["nfev"])
        else:
            poses = raw
        kf = self._scan_kf.view[:, 0]
        rel = self._scan_rel.view
        before = se2_compose(raw[kf], rel) if kf.size else np.zeros((0, 3))
        out = _blend_corrections(before, kf, self._kf_scan.view[:, 0], raw, poses) if kf.size else before
        stats.setdefault("rejected_pairwise", 0)
        stats["rejected_after_solve"] = rejected
        stats["loops"] = len(kept)
        stats["seconds_search"] = round(self._seconds_search, 4)
        stats["seconds_rematch"] = round(self._seconds_rematch, 4)
        stats["seconds_solve"] = round(time.perf_counter() - t0, 4)
        stats["solver_evaluations"] = nfev
        if out.shape[0]:
            stats["max_correction_m"] = float(np.max(np.hypot(*(out[:, :2] - before[:, :2]).T)))
            stats["max_correction_rad"] = float(np.max(np.abs(wrap_angle(out[:, 2] - before[:, 2]))))
        else:
            stats["max_correction_m"] = stats["max_correction_rad"] = 0.0
        stats["memory_bytes"] = self.memory_bytes()
        kf_scan = self._kf_scan.view[:, 0]
        return LoopResult(out, stats, [(int(kf_scan[lp.a]), int(kf_scan[lp.b])) for lp in kept])

    # -- keyframes -----------------------------------------------------------------------------
    def _scan_pos(self, index: int) -> int:
        hits = np.flatnonzero(self._scan_index.view[:, 0] == index)
        if hits.size == 0:
            raise KeyError(f"no scan numbered {index} was added")
        return int(hits[-1])

    # -- loop detection ------------------------------------------------------------------------
    def _search(self, k: int, source: F64, dense: F64, descriptor_matches: F64) -> None:
        """Find and verify loop candidates for keyframe ``k`` (ICP source and dense points, base frame; the
        older keyframes its descriptor matched, see :meth:`KeyframeSelector.descriptor_matches`)."""
        cfg = self.cfg
        last = k - cfg.min_separation
        if last < 0 or cfg.max_candidates == 0:
            return
        poses = self._kf_pose.view
        pk = poses[k]
        old = poses[: last + 1]
        # (keyframe j, guess T_j_k, kind), best first
        tracked: list[tuple[int, F64, str]] = []
        if self._last_loop is not None and k - self._last_loop.b <= cfg.track_keyframes:
            follow = self._follow(self._last_loop, k, last)
            if follow is not None:
                tracked.append((follow[0], follow[1], "tracked"))
        dist = np.hypot(old[:, 0] - pk[0], old[:, 1] - pk[1])
        radius = cfg.search_radius + cfg.drift_per_m * (self._kf_dist.view[k, 0] - self._kf_dist.view[: last + 1, 0])
        near_idx = np.flatnonzero(dist <= radius)
        near_idx = near_idx[np.argsort(dist[near_idx] / np.maximum(radius[near_idx], 1e-9))]
        near_idx = near_idx[: 10 * cfg.max_candidates * max(cfg.submap_keyframes, 1)]  # enough for the places
        near_guess = se2_between(old[near_idx], pk)
        by_descriptor = [(int(j), np.array([0.0, 0.0, float(yaw)]), "descriptor") for j, yaw in descriptor_matches]
        self._failed = {j: kf for j, kf in self._failed.items() if k - kf <= cfg.retry_keyframes}
        # places near one that failed a moment ago (the view has hardly changed) are not tried again
        n_sub = cfg.submap_keyframes
        blocked = np.zeros(last + 1 + n_sub, dtype=bool)
        for jf in self._failed:
            blocked[max(0, jf - n_sub): jf + n_sub + 1] = True
        # tracked first, then descriptor and position interleaved; candidates in one neighbourhood
        # form one place, verified once with each of their guesses
        places: list[tuple[int, list[F64], list[str]]] = []

        def merged() -> Iterator[tuple[int, F64, str]]:
            yield from tracked
            for i in range(max(near_idx.shape[0], len(by_descriptor))):
                if i < len(by_descriptor):
                    yield by_descriptor[i]
                if i < near_idx.shape[0]:
                    if (i >= len(by_descriptor) and len(places) >= cfg.max_candidates
                            and all(len(pl[1]) >= 3 or "position" in pl[2] for pl in places)):
                        return  # only position candidates are left, and no place takes another
                    yield int(near_idx[i]), near_guess[i], "position"

        for j, guess, kind in merged():
            home = next((pl for pl in places if abs(pl[0] - j) <= n_sub), None)
            if home is None:
                if len(places) >= cfg.max_candidates:
                    break
                if kind != "tracked" and blocked[j]:
                    self._counts["skipped_retry"] += 1
                    continue
                places.append((j, [guess], [kind]))
            elif len(home[1]) < 3 and kind not in home[2]:  # the guess in the home keyframe's frame
                home[1].append(se2_compose(se2_between(old[home[0]], old[j]), guess))
                home[2].append(kind)
        found = 0
        for j, guesses, kinds in places:
            self._counts["candidates"] += 1
            loop = self._verify(j, k, source, dense, guesses, kinds)
            if loop is None:
                self._failed[j] = k
            else:
                self._keep(loop, k)
                self._counts["accepted"] += 1
                self._counts[f"from_{loop.kind}"] += 1
                if loop.kind != "tracked":
                    self._backfill(loop)
                self._last_loop = loop
                found += 1
                if found >= cfg.max_loops_per_keyframe:
                    break

    def _follow(self, loop: _Loop, k: int, last: int) -> tuple[int, F64] | None:
        """A loop carried to keyframe ``k`` by the registration (``T_a_k = Z · T_b_k``): the keyframe
        up to ``last`` nearest to where it puts k (preferring one that looked the same way, 1 m per
        rad), and the guess ``T_j_k``."""
        poses = self._kf_pose.view
        pred = se2_compose(loop.z, se2_between(poses[loop.b], poses[k]))
        span = 2 * self.cfg.track_keyframes
        lo, hi = max(0, loop.a - span), min(last, loop.a + span)
        if lo > hi:
            return None
        near = se2_between(poses[loop.a], poses[lo: hi + 1])
        cost = np.hypot(near[:, 0] - pred[0], near[:, 1] - pred[1]) + np.abs(wrap_angle(near[:, 2] - pred[2]))
        j = lo + int(np.argmin(cost))
        return j, se2_compose(se2_between(poses[j], poses[loop.a]), pred)

    def _backfill(self, loop: _Loop) -> None:
        """A loop found late: carry it back over the keyframes before it that found none (the drift
        hid the place from them), as long as they match."""
        cfg = self.cfg
        have = {lp.b for lp in self._loops} | {lp.b for lp in self._pending}
        for k in range(loop.b - 1, max(loop.b - cfg.track_keyframes, 0) - 1, -1):
            if k in have:
                break
            follow = self._follow(loop, k, k - cfg.min_separation)
            stored = self._kf_points[k][:, :2].astype(np.float64)
            if follow is None or stored.shape[0] < cfg.min_points:
                break
            source = self._front.prepare(stored)[1]
            self._counts["candidates"] += 1
            found = self._verify(follow[0], k, source, stored, [follow[1]], ["tracked"])
            if found is None:
                break
            self._keep(found, loop.b)
            self._counts["accepted"] += 1
            self._counts["from_tracked"] += 1
            loop = found

    def _keep(self, loop: _Loop, k: int) -> None:
        """Into the graph once confirmed: when it agrees with a loop already kept, or when it and
        the pending loops that agree with it number ``confirm`` (all found within
        ``track_keyframes``). A revisit yields a run of agreeing loops; a place that only looks
        alike rarely does."""
        cfg = self.cfg
        if cfg.confirm <= 1:
            self._loops.append(loop)
            return
        stale = [lp for lp in self._pending if k - lp.b > cfg.track_keyframes]
        self._counts["unconfirmed"] += len(stale)
        self._pending = [lp for lp in self._pending if k - lp.b <= cfg.track_keyframes]
        recent = [lp for lp in self._loops[-cfg.track_keyframes:] if k - lp.b <= cfg.track_keyframes]
        group = [lp for lp in self._pending if self._agree(lp, loop)]
        if any(self._agree(lp, loop) for lp in recent) or len(group) + 1 >= cfg.confirm:
            self._loops.extend(group + [loop])
            self._pending = [p for p in self._pending if not any(p is lp for lp in group)]
        else:
            self._pending.append(loop)

    def _agree(self, first: _Loop, second: _Loop) -> bool:
        """Whether two loops put ``second.b`` at the same place relative to ``first.a`` (through the
        registration's short stretches between the two ends of each)."""
        poses = self._kf_pose.view
        via_first = se2_compose(first.z, se2_between(poses[first.b], poses[second.b]))
        via_second = se2_compose(se2_between(poses[first.a], poses[second.a]), second.z)
        d = via_first - via_second
        return bool(math.hypot(d[0], d[1]) <= self.cfg.confirm_distance
                    and abs(float(wrap_angle(float(d[2])))) <= self.cfg.confirm_angle)

    #: places (submaps) kept for the verifications to come: a revisit verifies the same place for several
    #: keyframes in a row, and a place that failed is tried again a few keyframes later (on the Intel log
    #: 1094 places were built for 1881 verifications keeping 16, 695 keeping 128; each holds about 0.2 MB
    #: with its search trees and voxel map, so 128 cost some 25 MB)
    PLACES_KEPT = 128

    def _place(self, matcher: Any, j: int, lo: int, hi: int) -> tuple[F64, _Submap, _Submap, Any] | None:
        """The submap around keyframe ``j`` (keyframes ``lo`` to ``hi``, in j's frame): its points with their
        normal directions, their search trees (all of them, and the fine fit's) and KISS-ICP's voxel map; kept
        for the next verifications. None: too few points."""
        cfg = self.cfg
        poses = self._kf_pose.view
        rel = se2_between(poses[j], poses[lo: hi + 1])
        stored = [self._kf_points[i] for i in range(lo, hi + 1)]
        counts = np.array([p.shape[0] for p in stored])
        place: tuple[F64, _Submap, _Submap, Any] | None = None
        if counts.sum() >= cfg.min_points:
            pts = np.concatenate(stored).astype(np.float64)
            at = np.repeat(rel, counts, axis=0)  # each point's keyframe pose in j's frame
            c, s = np.cos(at[:, 2]), np.sin(at[:, 2])
            whole = np.column_stack([at[:, 0] + c * pts[:, 0] - s * pts[:, 1],
                                     at[:, 1] + s * pts[:, 0] + c * pts[:, 1], pts[:, 2] + at[:, 2]])
            voxel_map = self._voxel_map(matcher, stored, rel, whole, counts)
            sub = _Submap(whole[:, :2], whole[:, 2])
            # the registration's drift bends a long submap: the final fit is to the candidate's close neighbours
            first = max(lo, j - cfg.refine_keyframes) - lo
            last = min(hi, j + cfg.refine_keyframes) - lo
            if first > 0 or last < hi - lo:
                start = int(counts[:first].sum())
                near = whole[start: start + int(counts[first: last + 1].sum())]
                sub_fine = _Submap(near[:, :2], near[:, 2]) if near.shape[0] else sub
            else:
                sub_fine = sub
            place = (whole, sub, sub_fine, voxel_map)
        self._places[(j, lo, hi)] = place
        if len(self._places) > self.PLACES_KEPT:
            self._places.popitem(last=False)
        return place

    def _voxel_map(self, matcher: Any, stored: list[NDArray[np.float32]], rel: F64, whole: F64,
                   counts: NDArray[np.int64]) -> Any:
        """KISS-ICP's voxel map of a submap, its keyframes inserted in order as the registration would.

        Each insertion also drops the voxels farther than ``max_range`` from that keyframe. When no
        point lies that far from a keyframe inserted after (or with) it, nothing is dropped and the
        points (``whole``, already in the submap's frame) go in with one call; else one by one."""
        from .kiss import PreparedScan

        voxel_map = matcher.new_map()
        owner = np.repeat(np.arange(len(stored)), counts)
        d2 = (whole[:, None, 0] - rel[None, :, 0]) ** 2 + (whole[:, None, 1] - rel[None, :, 1]) ** 2  # (M, K)
        later = np.arange(len(stored))[None, :] >= owner[:, None]
        reach = 0.99 * self._icp_cfg.max_range
        if not np.any(later & (d2 >= reach * reach)):
            p3 = np.zeros((whole.shape[0], 3))
            p3[:, :2] = whole[:, :2]
            voxel_map.add_points(p3)
            return voxel_map
        for pts, r in zip(stored, rel):
            if pts.shape[0]:
                p3 = np.zeros((pts.shape[0], 3))
                p3[:, :2] = pts[:, :2]
                matcher.update_map(PreparedScan(p3, p3), r, voxel_map)
        return voxel_map

    def _verify(self, j: int, k: int, source: F64, dense: F64, guesses: list[F64], kinds: list[str]
                ) -> _Loop | None:
        """ICP of keyframe k's points against the submap around keyframe j; the loop edge, or None."""
        from .kiss import KissMatcher, PreparedScan

        cfg = self.cfg
        n = cfg.submap_keyframes
        lo = max(0, j - n)
        hi = max(j, min(j + n, k - n - 1))
        poses = self._kf_pose.view
        radius = cfg.search_radius + cfg.drift_per_m * (self._kf_dist.view[k, 0] - self._kf_dist.view[j, 0])
        if cfg.gate_factor > 0:
            # a guess already farther from where the registration put keyframe k than the gate allows,
            # by more than the ICP's reach (its correspondences and the fine fit's), cannot pass it:
            # descriptor candidates at the far side of a building, some 7 % of Intel's verifications
            reach = cfg.gate_factor * radius + 3.0 * (cfg.icp_threshold + cfg.inlier_distance)
            said = se2_apply(poses[j], np.array([g[:2] for g in guesses]))
            if np.all(np.hypot(said[:, 0] - poses[k, 0], said[:, 1] - poses[k, 1]) > reach):
                self._counts["skipped_gate"] += 1
                log.debug("loop %d-%d: every guess beyond the gate", j, k)
                return None
        if self._verifier is None:  # one matcher for its settings: each place keeps a map of its own
            self._verifier = KissMatcher(self._icp_cfg)
        matcher = self._verifier
        place = self._places.get((j, lo, hi))
        if place is None:
            place = self._place(matcher, j, lo, hi)
        else:  # verified a moment ago (by the keyframe before, or a backfill): the same submap
            self._places.move_to_end((j, lo, hi))
        if place is None:
            return None
        self._counts["verified"] += 1
        whole, sub, sub_fine, voxel_map = place
        full_query = dense
        dense = _thin(dense, cfg.max_query_points)
        q3 = np.zeros((source.shape[0], 3))
        q3[:, :2] = source
        query = PreparedScan(q3, q3)
        best: _Match | None = None
        best_kind = kinds[0]
        for guess, kind in zip(guesses, kinds):
            icp = matcher.align(query, guess, voxel_map)
            if not np.all(np.isfinite(icp)):
                continue
            share = _overlap(sub, source, icp, cfg)
            if share < 0.5 * cfg.min_inliers:  # hopeless: not worth refining
                quick = _Match(icp, share, 0.0, np.eye(3), float("inf"))
                if best is None or quick.inliers > best.inliers:
                    best, best_kind = quick, kind
                continue
            pose = _align(sub_fine, dense, icp, cfg)
            if sub_fine is not sub and _overlap(sub_fine, dense, pose, cfg) < 0.5 * cfg.min_inliers:
                pose = _align(sub, dense, icp, cfg)  # too little of the keyframe seen by the candidate alone
            match = _evaluate(sub, dense, pose, cfg)
            if best is None or match.inliers > best.inliers:
                best, best_kind = match, kind
            if match.inliers >= cfg.min_inliers and match.condition >= cfg.min_condition:
                break
        if best is None or best.inliers < cfg.min_inliers:
            self._counts["rejected_inliers"] += 1
            log.debug("loop %d-%d: %.0f%% inliers", j, k, 100 * (best.inliers if best else 0.0))
            return None
        if best.condition < cfg.min_condition:
            self._counts["rejected_degenerate"] += 1
            log.debug("loop %d-%d: degenerate match (condition %.3g)", j, k, best.condition)
            return None
        conflicts = _free_space_conflicts(whole[:, :2], full_query, best.pose, cfg)
        if best.rms > cfg.max_rms or conflicts > cfg.max_conflicts:
            self._counts["rejected_fit"] += 1
            log.debug("loop %d-%d: loose fit (rms %.3f m, %.0f%% of the place seen through)", j, k, best.rms,
                      100 * conflicts)
            return None
        if cfg.gate_factor > 0:
            # where the loop puts keyframe k against where the registration did: at most gate_factor
            # times the search radius away, and turned by at most gate_factor times three standard
            # deviations of the registration's heading over the stretch (plus 0.05 rad)
            said = se2_compose(poses[j], best.pose)
            yaw_sd = math.sqrt(max(float(self._kf_var_yaw.view[k, 0] - self._kf_var_yaw.view[j, 0]), 0.0))
            turn = abs(float(wrap_angle(float(said[2] - poses[k, 2]))))
            if (math.hypot(said[0] - poses[k, 0], said[1] - poses[k, 1]) > cfg.gate_factor * radius
                    or turn > cfg.gate_factor * (3.0 * yaw_sd + 0.05)):
                self._counts["rejected_gate"] += 1
                log.debug("loop %d-%d: correction beyond the gate", j, k)
                return None
        log.debug("loop %d-%d accepted (%s): %.0f%% inliers, condition %.3f, rms %.3f m", j, k, best_kind,
                  100 * best.inliers, best.condition, best.rms)
        return _Loop(j, k, best.pose, _inverse_spd(best.cov), best_kind)


def _thin(points: F64, n: int) -> F64:
    """At most ``n`` of ``points``, evenly spread over them (a keyframe's query points)."""
    if points.shape[0] <= n:
        return points
    return points[np.linspace(0, points.shape[0] - 1, n).astype(np.int64)]


def _compose_chain(first: F64, steps: F64) -> F64:
    """The poses (K, 3) of a chain starting at ``first`` with the relative steps ``steps`` (K-1, 3)."""
    out = np.empty((steps.shape[0] + 1, 3))
    out[0] = first
    for i, z in enumerate(steps):
        out[i + 1] = se2_compose(out[i], z)
    return out


def _inverse_spd(cov: F64) -> F64:
    """The inverse of a covariance, symmetrised (tiny eigenvalues floored)."""
    c = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(c)
    w = np.maximum(w, 1e-12 * max(float(w.max()), 1e-12))
    return np.asarray((v / w) @ v.T)
