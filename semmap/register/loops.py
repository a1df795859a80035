"""Loop closure: keyframes, place recognition, ICP verification and a robust pose graph.

Scan-to-map registration drifts; on a long tour the walls of a place seen twice double.
:class:`LoopCloser` takes every registered scan in order (:meth:`LoopCloser.add`) and at
the end returns corrected poses for all of them (:meth:`LoopCloser.optimise`).

* **Keyframes.** A scan becomes a keyframe after ``keyframe_distance`` m or
  ``keyframe_angle`` rad since the last one. Only keyframes keep points (float32, KISS-ICP's
  map down-sampling); every other scan keeps its keyframe's number and its pose relative to
  it (four numbers), so memory stays small on long tours and the graph has keyframe nodes only.
* **Place recognition**, each time a keyframe is added, among keyframes at least
  ``min_separation`` keyframes older:

  - by position: within ``search_radius`` + ``drift_per_m`` · (distance driven since them)
    of the drifted estimate;
  - with ``descriptor``, by a scan-context-style polar descriptor (rings × sectors; a cell
    is 1 inside the farthest return of its sector, so the descriptor is the visible area,
    which changes smoothly with position). Its ring key (share of sectors reaching each
    ring) is rotation invariant and pre-selects ``descriptor_preselect`` keyframes; the
    column-shift comparison (1 - mean column cosine) ranks them and yields a yaw guess.

* **Verification** against a submap of the candidate and its ``submap_keyframes``
  neighbours on each side (placed by the registration's relative poses): KISS-ICP
  (:class:`~semmap.register.kiss.KissMatcher`) from the current relative estimate and,
  for descriptor candidates, from the descriptor's yaw guess; then a point-to-line
  refinement. A match is a loop when ``min_inliers`` of the query points lie within
  ``inlier_distance`` of the submap and the point-to-line Hessian is well conditioned
  (smallest / largest eigenvalue ≥ ``min_condition``, rotation scaled by the points' RMS
  range): a corridor match that can slide is not a loop. The loop edge's covariance is
  the Hessian's inverse scaled by the residual variance, counted as
  ``loop_effective_points`` independent points (scan residuals are correlated). A loop
  whose correction exceeds ``gate_factor`` times the search radius is implausible.
* **Pose graph** (:func:`solve_pose_graph`): keyframe nodes; odometry edges between
  consecutive keyframes with the registration's relative poses and a covariance
  propagated from every step (the caller's information matrices, or a random-walk
  default); loop edges. Solved by :func:`scipy.optimize.least_squares` with an analytic
  sparse Jacobian, parametrised by the keyframes' increments along the chain (the first
  node fixed), which keeps the problem well conditioned for the iterative LSMR solver.
* **False loops**: the graph is solved with all loops, then with switchable constraints
  (Sünderhauf & Protzel 2012; a switch in [0, 1] per loop, a prior that makes a loop more
  off than on beyond χ² = ``switch_chi2``); loops switched off are dropped, and then,
  one at a time, the loop with the largest χ² above ``reject_chi2``, re-solving each time.

Frames: poses are ``T_map_base`` as SE(2) ``(x, y, yaw)``; a loop or odometry measurement
between keyframes i and j is ``T_i_j``; covariances are of a right perturbation (in the
frame of j), errors ``e = t2v(Z⁻¹ · X_i⁻¹ · X_j)``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import RegistrationConfig
from ..geometry import se2_apply, se2_between, se2_compose, se2_inverse, wrap_angle

__all__ = [
    "LoopCloser",
    "LoopConfig",
    "LoopResult",
    "descriptor_distance",
    "ring_key",
    "scan_context",
    "solve_pose_graph",
]

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]


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
    descriptor_threshold: float = 0.15  # descriptor distance (1 - mean column cosine) below which a place matches
    max_candidates: int = 3  # candidate places verified per new keyframe
    max_loops_per_keyframe: int = 1  # stop verifying a keyframe's candidates after this many loops
    # verification
    submap_keyframes: int = 5  # each side: the candidate's neighbours form the map a keyframe is matched against
    min_points: int = 20  # fewer down-sampled points in the keyframe: not matched
    icp_threshold: float = 0.5  # m, KISS-ICP kernel σ for loop ICP (correspondences within 3σ)
    refine_iterations: int = 20  # point-to-line Gauss-Newton steps after KISS-ICP
    min_inliers: float = 0.6  # share of the query points within inlier_distance of the submap after ICP
    inlier_distance: float = 0.1  # m
    min_condition: float = 0.05  # smallest / largest eigenvalue of the scaled point-to-line Hessian
    gate_factor: float = 2.0  # a loop correcting more than this × the search radius is rejected (0: off)
    loop_sigma_min: float = 0.01  # m, floor of the residual σ in the loop covariance
    loop_effective_points: float = 10.0  # the query points count as this many independent ones
    # odometry edges: default covariance of one registration step (random walk in the distance driven)
    odom_sigma_xy: float = 0.002  # m per step
    odom_sigma_yaw: float = 0.001  # rad per step
    odom_sigma_xy_per_sqrt_m: float = 0.02  # m per √m driven
    odom_sigma_yaw_per_sqrt_m: float = 0.02  # rad per √m driven
    odom_sigma_yaw_per_sqrt_rad: float = 0.02  # rad per √rad turned
    # robust solve
    switchable: bool = True  # switchable constraints on loop edges
    switch_chi2: float = 25.0  # χ² at which a loop's switch is half off
    reject_chi2: float = 50.0  # after the solve, the worst loop above this χ² is dropped and the graph re-solved
    max_rejection_rounds: int = 10
    max_nfev: int = 100  # least_squares evaluations per solve
    tolerance: float = 1e-10  # least_squares ftol / xtol

    def __post_init__(self) -> None:
        positive = ("keyframe_distance", "keyframe_angle", "descriptor_range", "icp_threshold",
                    "inlier_distance", "loop_sigma_min", "loop_effective_points", "switch_chi2",
                    "reject_chi2", "tolerance")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"LoopConfig.{name} must be > 0, got {getattr(self, name)}")
        at_least_one = ("descriptor_rings", "descriptor_sectors", "descriptor_preselect", "max_loops_per_keyframe",
                        "min_points", "max_nfev")
        for name in at_least_one:
            if getattr(self, name) < 1:
                raise ValueError(f"LoopConfig.{name} must be >= 1, got {getattr(self, name)}")
        non_negative = ("min_separation", "search_radius", "drift_per_m", "descriptor_threshold", "max_candidates",
                        "submap_keyframes", "refine_iterations", "min_condition", "gate_factor", "odom_sigma_xy",
                        "odom_sigma_yaw", "odom_sigma_xy_per_sqrt_m", "odom_sigma_yaw_per_sqrt_m",
                        "odom_sigma_yaw_per_sqrt_rad", "max_rejection_rounds")
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
    ``loops``: the accepted loops as (scan index a, scan index b), a older than b.
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

    The distance is 1 - the mean cosine similarity of the columns present in both (scan
    context); it is 1 when no column pairs up. Returns (distances (C,), yaw (C,)), the yaw
    being that of the query's frame in the other's frame implied by the best shift.
    """
    q = np.asarray(query, dtype=np.float64)
    c = np.asarray(others, dtype=np.float64).reshape(-1, *q.shape)
    n_sec = q.shape[1]
    if c.shape[0] == 0:
        return np.zeros(0), np.zeros(0)
    qn = q / np.maximum(np.linalg.norm(q, axis=0, keepdims=True), 1e-12)
    cn = c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)
    shifts = (np.arange(n_sec)[:, None] + np.arange(n_sec)[None, :]) % n_sec  # [k, s] = s + k
    q_rolled = qn[:, shifts]  # (R, K, S): query column s + k
    q_present = (q.sum(axis=0) > 0)[shifts]  # (K, S)
    c_present = c.sum(axis=1) > 0  # (C, S)
    cos = np.einsum("rks,crs->cks", q_rolled, cn)  # (C, K, S)
    both = q_present[None, :, :] & c_present[:, None, :]
    n_both = both.sum(axis=2)
    sim = np.where(n_both > 0, (cos * both).sum(axis=2) / np.maximum(n_both, 1), 0.0)  # (C, K)
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


class _Submap:
    """Submap points with a KD-tree and line normals (PCA of each point's neighbours)."""

    def __init__(self, points: F64, neighbours: int = 6, max_spread: float = 0.5) -> None:
        from scipy.spatial import cKDTree

        self.points = points
        self.tree = cKDTree(points)
        k = min(neighbours, points.shape[0])
        d, idx = self.tree.query(points, k=k)
        d = d.reshape(points.shape[0], k)
        idx = idx.reshape(points.shape[0], k)
        nb = points[idx]  # (M, k, 2)
        centred = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("mki,mkj->mij", centred, centred) / k
        w, v = np.linalg.eigh(cov)  # ascending
        self.normals = v[:, :, 0]
        # a line: the neighbours spread along one direction, and they are near
        self.good = (w[:, 0] <= 0.05 * np.maximum(w[:, 1], 1e-12)) & (d[:, -1] <= max_spread) & (k >= 3)


def _refine(sub: _Submap, src: F64, guess: F64, cfg: LoopConfig) -> _Match:
    """Point-to-line ICP (Cauchy weights) of ``src`` onto ``sub`` from ``guess``; the match's quality."""
    pose = np.asarray(guess, dtype=np.float64).copy()
    d_max = 3.0 * cfg.inlier_distance
    c = 0.5 * cfg.inlier_distance

    def linearise(p: F64, radius: float) -> tuple[F64, F64, F64, NDArray[np.bool_], NDArray[np.bool_]]:
        q = se2_apply(p, src)
        d, idx = sub.tree.query(q, distance_upper_bound=radius)
        found = np.isfinite(d)
        use = found.copy()
        use[found] = sub.good[idx[found]]
        i = idx[use]
        nrm = sub.normals[i]
        r = np.sum(nrm * (q[use] - sub.points[i]), axis=1)
        v = q[use] - p[:2]
        jac = np.column_stack([nrm, nrm[:, 1] * v[:, 0] - nrm[:, 0] * v[:, 1]])
        return r, jac, v, use, found

    for _ in range(cfg.refine_iterations):
        r, jac, _, use, _ = linearise(pose, d_max)
        if use.sum() < 3:
            break
        w = 1.0 / (1.0 + (r / c) ** 2)
        h = (jac * w[:, None]).T @ jac
        g = (jac * w[:, None]).T @ r
        try:
            step = -np.linalg.solve(h + 1e-9 * np.eye(3), g)
        except np.linalg.LinAlgError:
            break
        pose = pose + step
        pose[2] = wrap_angle(float(pose[2]))
        if np.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-5:
            break

    r, jac, v, use, found = linearise(pose, cfg.inlier_distance)
    inliers = float(found.mean()) if found.size else 0.0
    n = int(use.sum())
    if n < 3:
        return _Match(pose, inliers, 0.0, np.eye(3), float("inf"))
    h = jac.T @ jac / n
    scale = math.sqrt(float(np.mean(np.sum(v * v, axis=1)))) or 1.0
    d = np.array([1.0, 1.0, 1.0 / scale])
    ev = np.linalg.eigvalsh(h * d[:, None] * d[None, :])
    condition = float(ev[0] / ev[-1]) if ev[-1] > 0 else 0.0
    rms = math.sqrt(float(np.mean(r * r)))
    sigma2 = max(rms, cfg.loop_sigma_min) ** 2
    try:
        cov_add = sigma2 * np.linalg.inv(h) / cfg.loop_effective_points
    except np.linalg.LinAlgError:
        return _Match(pose, inliers, 0.0, np.eye(3), rms)
    # (t, yaw) additive -> right perturbation (t = R ρ)
    a = _rot3(-pose[2])
    return _Match(pose, inliers, condition, a @ cov_add @ a.T, rms)


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


def solve_pose_graph(poses: ArrayLike, odom_z: ArrayLike, odom_info: ArrayLike, loop_a: ArrayLike,
                     loop_b: ArrayLike, loop_z: ArrayLike, loop_info: ArrayLike, *, switchable: bool = False,
                     switch_chi2: float = 25.0, max_nfev: int = 100, tolerance: float = 1e-10,
                     loss: str = "linear", f_scale: float = 1.0) -> tuple[F64, F64, dict[str, Any]]:
    """Solve a pose graph whose nodes form a chain, with extra (loop) edges.

    ``poses`` (K, 3): the initial node poses; node 0 stays fixed (gauge). ``odom_z`` (K-1, 3):
    the measurement ``T_{i-1}_i`` of each chain edge, ``odom_info`` (K-1, 3, 3) its information.
    ``loop_a``, ``loop_b`` (L,) node numbers, ``loop_z`` (L, 3) ``T_a_b``, ``loop_info`` (L, 3, 3).
    With ``switchable``, each loop residual is multiplied by a switch s in [0, 1] with the prior
    residual √switch_chi2 · (1 - s) (a loop is more off than on beyond χ² = switch_chi2).

    The unknowns are the chain's increments ``T_{i-1}_i``, with an analytic sparse Jacobian:
    an odometry residual depends on its increment only, a loop (a, b) on the increments
    a+1 … b. This is far better conditioned than absolute poses for LSMR, which
    :func:`scipy.optimize.least_squares` uses with sparse Jacobians.
    Returns (poses (K, 3), switches (L,) (ones without ``switchable``), solver info).
    """
    from scipy.optimize import least_squares
    from scipy.sparse import csr_matrix

    p0 = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    k = p0.shape[0]
    zo = np.asarray(odom_z, dtype=np.float64).reshape(-1, 3)
    la = np.asarray(loop_a, dtype=np.int64).reshape(-1)
    lb = np.asarray(loop_b, dtype=np.int64).reshape(-1)
    zl = np.asarray(loop_z, dtype=np.float64).reshape(-1, 3)
    n_loops = la.shape[0]
    if zo.shape[0] != k - 1:
        raise ValueError(f"{k} nodes need {k - 1} chain edges, got {zo.shape[0]}")
    if n_loops and (np.any(la < 0) or np.any(lb >= k) or np.any(la == lb)):
        raise ValueError("loop edges must join two different existing nodes")
    if k < 2 or n_loops == 0:
        return p0.copy(), np.ones(n_loops), {"nfev": 0, "cost": 0.0, "seconds": 0.0}
    t0 = time.perf_counter()
    # orient every loop forward (a < b): Z and the right-perturbation covariance at b become those of the inverse
    flip = la > lb
    if np.any(flip):
        la, lb, zl = la.copy(), lb.copy(), zl.copy()
        info_l = np.asarray(loop_info, dtype=np.float64).reshape(-1, 3, 3).copy()
        for i in np.flatnonzero(flip):
            adj = _adjoint(zl[i])  # e' = -Ad_Z e
            adj_inv = np.linalg.inv(adj)
            info_l[i] = adj_inv.T @ info_l[i] @ adj_inv
            zl[i] = se2_inverse(zl[i])
            la[i], lb[i] = lb[i], la[i]
    else:
        info_l = np.asarray(loop_info, dtype=np.float64).reshape(-1, 3, 3)
    uo = _upper_factors(np.asarray(odom_info, dtype=np.float64).reshape(-1, 3, 3))
    ul = _upper_factors(info_l)
    n_edges = k - 1
    n_var = 3 * n_edges + (n_loops if switchable else 0)

    # sparsity structure: chain edge e -> increment e; loop l -> increments la+1 .. lb (node m = increment m-1)
    three = np.arange(3)
    ro = (3 * np.arange(n_edges)[:, None, None] + three[None, :, None] + 0 * three[None, None, :]).ravel()
    co = (3 * np.arange(n_edges)[:, None, None] + 0 * three[None, :, None] + three[None, None, :]).ravel()
    spans = lb - la
    loop_of = np.repeat(np.arange(n_loops), spans)
    node = (np.arange(loop_of.shape[0]) - np.repeat(np.cumsum(spans) - spans, spans)) + la[loop_of] + 1
    rl = (3 * n_edges + 3 * loop_of[:, None, None] + three[None, :, None] + 0 * three[None, None, :]).ravel()
    cl = (3 * (node - 1)[:, None, None] + 0 * three[None, :, None] + three[None, None, :]).ravel()
    rows = [ro, rl]
    cols = [co, cl]
    if switchable:  # d(loop residual)/d(switch), then the switch priors
        rows += [(3 * n_edges + 3 * np.arange(n_loops)[:, None] + three[None, :]).ravel(),
                 3 * (n_edges + n_loops) + np.arange(n_loops)]
        cols += [np.repeat(3 * n_edges + np.arange(n_loops), 3), 3 * n_edges + np.arange(n_loops)]
    rows_a = np.concatenate(rows)
    cols_a = np.concatenate(cols)
    n_res = 3 * (n_edges + n_loops) + (n_loops if switchable else 0)
    czo, szo = np.cos(zo[:, 2]), np.sin(zo[:, 2])
    b_odom = np.zeros((n_edges, 3, 3))
    b_odom[:, 0, 0], b_odom[:, 0, 1], b_odom[:, 1, 0], b_odom[:, 1, 1] = czo, szo, -szo, czo
    b_odom[:, 2, 2] = 1.0
    j_odom = np.einsum("eij,ejk->eik", uo, b_odom).ravel()  # constant
    prior = math.sqrt(switch_chi2)

    def chain(x: F64) -> F64:
        inc = x[: 3 * n_edges].reshape(-1, 3)
        th = p0[0, 2] + np.concatenate([[0.0], np.cumsum(inc[:, 2])])
        c, s = np.cos(th[:-1]), np.sin(th[:-1])
        out = np.empty((k, 3))
        out[:, 0] = p0[0, 0] + np.concatenate([[0.0], np.cumsum(c * inc[:, 0] - s * inc[:, 1])])
        out[:, 1] = p0[0, 1] + np.concatenate([[0.0], np.cumsum(s * inc[:, 0] + c * inc[:, 1])])
        out[:, 2] = th
        return out

    def fun(x: F64) -> F64:
        inc = x[: 3 * n_edges].reshape(-1, 3)
        ux, uy = inc[:, 0] - zo[:, 0], inc[:, 1] - zo[:, 1]
        eo = np.column_stack([czo * ux + szo * uy, -szo * ux + czo * uy, wrap_angle(inc[:, 2] - zo[:, 2])])
        p = chain(x)
        rl_ = np.einsum("eij,ej->ei", ul, _edge_errors(p[la], p[lb], zl))
        parts = [np.einsum("eij,ej->ei", uo, eo).ravel()]
        if switchable:
            s = x[3 * n_edges:]
            parts += [(rl_ * s[:, None]).ravel(), prior * (1.0 - s)]
        else:
            parts.append(rl_.ravel())
        return np.concatenate(parts)

    def jac(x: F64) -> Any:
        p = chain(x)
        a_of = la[loop_of]
        ang = p[node - 1, 2] - p[a_of, 2] - zl[loop_of, 2]  # R_z^T R_a^T R_{m-1}
        c, s = np.cos(ang), np.sin(ang)
        rot = p[a_of, 2] + zl[loop_of, 2]
        ca, sa = np.cos(rot), np.sin(rot)
        vx = p[lb[loop_of], 0] - p[node, 0]
        vy = p[lb[loop_of], 1] - p[node, 1]
        jl = np.zeros((loop_of.shape[0], 3, 3))
        jl[:, 0, 0], jl[:, 0, 1], jl[:, 1, 0], jl[:, 1, 1] = c, -s, s, c
        jl[:, 0, 2] = -ca * vy + sa * vx  # R(-rot) · S · (t_b - t_m)
        jl[:, 1, 2] = sa * vy + ca * vx
        jl[:, 2, 2] = 1.0
        jl = np.einsum("eij,ejk->eik", ul[loop_of], jl)
        data = [j_odom]
        if switchable:
            sw = x[3 * n_edges:]
            data.append((jl * sw[loop_of, None, None]).ravel())
            el = np.einsum("eij,ej->ei", ul, _edge_errors(p[la], p[lb], zl))
            data += [el.ravel(), np.full(n_loops, -prior)]
        else:
            data.append(jl.ravel())
        return csr_matrix((np.concatenate(data), (rows_a, cols_a)), shape=(n_res, n_var))

    x0 = se2_between(p0[:-1], p0[1:]).ravel()
    lower = np.full(n_var, -np.inf)
    upper = np.full(n_var, np.inf)
    if switchable:
        x0 = np.concatenate([x0, np.ones(n_loops)])
        lower[3 * n_edges:] = 0.0
        upper[3 * n_edges:] = 1.0
    res = least_squares(fun, x0, jac=jac, bounds=(lower, upper) if switchable else (-np.inf, np.inf),
                        method="trf", tr_solver="lsmr", ftol=tolerance, xtol=tolerance, gtol=tolerance,
                        max_nfev=max_nfev, loss=loss, f_scale=f_scale, tr_options={"atol": 1e-12, "btol": 1e-12})
    out = chain(res.x)
    out[:, 2] = wrap_angle(out[:, 2])
    switches = res.x[3 * n_edges:].copy() if switchable else np.ones(n_loops)
    info = {"nfev": int(res.nfev), "cost": float(res.cost), "status": int(res.status),
            "seconds": time.perf_counter() - t0}
    return out, switches, info


# ---------------------------------------------------------------------------------------------
# The loop closer


@dataclass(frozen=True)
class _Loop:
    a: int  # keyframe numbers, a older than b
    b: int
    z: F64  # T_a_b
    info: F64  # 3x3
    kind: str  # "position", "descriptor" or "external"


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
        self._prep: Any = None  # a KissMatcher used for down-sampling only (created lazily)
        # every scan: its index, keyframe and pose in the keyframe's frame
        self._scan_index = _Buffer(1, np.int64)
        self._scan_kf = _Buffer(1, np.int32)
        self._scan_rel = _Buffer(3)
        # keyframes
        self._kf_pose = _Buffer(3)  # T_map_kf from registration
        self._kf_dist = _Buffer(1)  # distance driven up to the keyframe, m
        self._kf_scan = _Buffer(1, np.int64)  # the keyframe's scan index
        self._kf_key = _Buffer(cfg.descriptor_rings, np.float32)
        self._kf_desc: list[NDArray[np.float32]] = []
        self._kf_points: list[NDArray[np.float32]] = []  # (M, 2) base frame, KISS-ICP map down-sampling
        self._odom_z = _Buffer(3)  # T_{kf-1}_kf
        self._odom_info = _Buffer(9)
        self._loops: list[_Loop] = []
        # the running state
        self._last_pose: F64 | None = None
        self._dist = 0.0
        self._cov = np.zeros((3, 3))  # covariance of the current scan relative to its keyframe
        self._counts = {"candidates": 0, "verified": 0, "accepted": 0, "rejected_inliers": 0,
                        "rejected_degenerate": 0, "rejected_gate": 0, "from_position": 0, "from_descriptor": 0,
                        "external": 0}
        self._seconds_search = 0.0

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
        """Approximate bytes held: keyframe points and descriptors, per-scan and per-keyframe arrays."""
        total = sum(int(p.nbytes) for p in self._kf_points) + sum(int(d.nbytes) for d in self._kf_desc)
        for buf in (self._scan_index, self._scan_kf, self._scan_rel, self._kf_pose, self._kf_dist, self._kf_scan,
                    self._kf_key, self._odom_z, self._odom_info):
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
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"pose must be a finite (x, y, yaw), got {pose!r}")
        p = np.array([p[0], p[1], wrap_angle(float(p[2]))])
        cfg = self.cfg
        if self._last_pose is not None:
            step = se2_between(self._last_pose, p)
            d = math.hypot(step[0], step[1])
            self._dist += d
            adj = _adjoint(se2_inverse(step))
            self._cov = adj @ self._cov @ adj.T + self._step_cov(step, info)
        self._last_pose = p
        n_kf = self._kf_pose.n
        rel = se2_between(self._kf_pose.view[-1], p) if n_kf else np.zeros(3)
        if n_kf and math.hypot(rel[0], rel[1]) < cfg.keyframe_distance and abs(rel[2]) < cfg.keyframe_angle:
            self._scan_index.append(index)
            self._scan_kf.append(n_kf - 1)
            self._scan_rel.append(rel)
            return
        # a new keyframe
        if n_kf:
            self._odom_z.append(rel)
            self._odom_info.append(_inverse_spd(self._cov).ravel())
        self._cov = np.zeros((3, 3))
        self._scan_index.append(index)
        self._scan_kf.append(n_kf)
        self._scan_rel.append(np.zeros(3))
        pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        prepared = self._prepare(pts)
        self._kf_pose.append(p)
        self._kf_dist.append(self._dist)
        self._kf_scan.append(index)
        desc = scan_context(prepared[0], cfg.descriptor_rings, cfg.descriptor_sectors, cfg.descriptor_range)
        self._kf_desc.append(desc)
        self._kf_key.append(ring_key(desc))
        self._kf_points.append(prepared[0].astype(np.float32))
        if prepared[1].shape[0] >= cfg.min_points:
            t0 = time.perf_counter()
            self._search(n_kf, prepared[1])
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

        ``stats``: ``scans``, ``keyframes``, ``candidates`` (candidate places verified or
        skipped), ``verified`` (ICP runs), ``accepted`` (loops found by verification),
        ``external``, ``rejected_inliers`` / ``rejected_degenerate`` / ``rejected_gate`` (at
        verification), ``rejected_after_solve`` (dropped by the robust solve), ``loops``
        (kept), ``seconds_search``, ``seconds_solve``, ``max_correction_m``,
        ``max_correction_rad``, ``solver_evaluations``, ``memory_bytes``.
        """
        t0 = time.perf_counter()
        cfg = self.cfg
        stats: dict[str, Any] = {"scans": self.scans, "keyframes": self.keyframes, **self._counts}
        n_kf = self.keyframes
        raw = self._kf_pose.view.copy()
        kept: list[_Loop] = []
        rejected = 0
        nfev = 0
        if n_kf >= 2 and self._loops:
            loops = self._loops
            la = np.array([lp.a for lp in loops])
            lb = np.array([lp.b for lp in loops])
            lz = np.array([lp.z for lp in loops])
            li = np.array([lp.info for lp in loops])
            zo = self._odom_z.view
            io = self._odom_info.view.reshape(-1, 3, 3)
            active = np.ones(len(loops), dtype=bool)
            kw: dict[str, Any] = {"max_nfev": cfg.max_nfev, "tolerance": cfg.tolerance}

            def solve(start: F64, switchable: bool = False) -> tuple[F64, F64]:
                nonlocal nfev
                idx = np.flatnonzero(active)
                if idx.size == 0:  # the chain alone: the registration's poses
                    return raw.copy(), np.ones(0)
                out, sw, info = solve_pose_graph(start, zo, io, la[idx], lb[idx], lz[idx], li[idx],
                                                 switchable=switchable, switch_chi2=cfg.switch_chi2, **kw)
                nfev += info["nfev"]
                return out, sw

            poses, _ = solve(raw)
            if cfg.switchable:  # from the all-loops solution, which true loops agree with
                poses, sw = solve(poses, switchable=True)
                off = np.flatnonzero(active)[sw < 0.5]
                if off.size:
                    log.info("loop closure: %d of %d loops switched off", off.size, len(loops))
                    active[off] = False
                    rejected += int(off.size)
                    poses, _ = solve(poses)
            for _ in range(cfg.max_rejection_rounds):
                idx = np.flatnonzero(active)
                if idx.size == 0:
                    break
                chi2 = loop_chi2(poses, la[idx], lb[idx], lz[idx], li[idx])
                worst = int(np.argmax(chi2))
                if chi2[worst] <= cfg.reject_chi2:
                    break
                log.info("loop closure: loop %d-%d dropped after the solve (χ² %.1f)", int(la[idx[worst]]),
                         int(lb[idx[worst]]), float(chi2[worst]))
                active[idx[worst]] = False
                rejected += 1
                poses, _ = solve(poses)
            kept = [lp for lp, a in zip(loops, active) if a]
        else:
            poses = raw
        kf = self._scan_kf.view[:, 0]
        rel = self._scan_rel.view
        out = se2_compose(poses[kf], rel) if kf.size else np.zeros((0, 3))
        before = se2_compose(raw[kf], rel) if kf.size else np.zeros((0, 3))
        stats["rejected_after_solve"] = rejected
        stats["loops"] = len(kept)
        stats["seconds_search"] = round(self._seconds_search, 4)
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

    def _prepare(self, pts: F64) -> tuple[F64, F64]:
        """(map points (M, 2), ICP source (S, 2)) as KISS-ICP down-samples them."""
        if pts.shape[0] == 0:
            return np.zeros((0, 2)), np.zeros((0, 2))
        if self._prep is None:
            from .kiss import KissMatcher

            self._prep = KissMatcher(self._icp_cfg)
        prepared = self._prep.prepare(pts)
        return prepared.map_points[:, :2].copy(), prepared.source[:, :2].copy()

    def _scan_pos(self, index: int) -> int:
        hits = np.flatnonzero(self._scan_index.view[:, 0] == index)
        if hits.size == 0:
            raise KeyError(f"no scan numbered {index} was added")
        return int(hits[-1])

    # -- loop detection ------------------------------------------------------------------------
    def _search(self, k: int, source: F64) -> None:
        """Find and verify loop candidates for keyframe ``k`` (with ICP source points ``source``)."""
        cfg = self.cfg
        last = k - cfg.min_separation
        if last < 0 or cfg.max_candidates == 0:
            return
        poses = self._kf_pose.view
        pk = poses[k]
        old = poses[: last + 1]
        # (keyframe, guess T_j_k, kind), best first
        by_position: list[tuple[int, F64, str]] = []
        dist = np.hypot(old[:, 0] - pk[0], old[:, 1] - pk[1])
        radius = cfg.search_radius + cfg.drift_per_m * (self._kf_dist.view[k, 0] - self._kf_dist.view[: last + 1, 0])
        near = np.flatnonzero(dist <= radius)
        for j in near[np.argsort(dist[near] / np.maximum(radius[near], 1e-9))]:
            by_position.append((int(j), se2_between(old[j], pk), "position"))
        by_descriptor: list[tuple[int, F64, str]] = []
        if cfg.descriptor:
            keys = self._kf_key.view[: last + 1]
            # brute force over the ring keys: exact, and at 20 dimensions as fast as a KD-tree
            kd = np.sum((keys - self._kf_key.view[k]) ** 2, axis=1)
            m = min(cfg.descriptor_preselect, kd.shape[0])
            pre = np.argpartition(kd, m - 1)[:m]
            dd, yaw = descriptor_distance(self._kf_desc[k], np.stack([self._kf_desc[j] for j in pre]))
            order = np.argsort(dd)
            for i in order:
                if dd[i] <= cfg.descriptor_threshold:
                    by_descriptor.append((int(pre[i]), np.array([0.0, 0.0, float(yaw[i])]), "descriptor"))
        # interleave, then group candidates of one neighbourhood into one place with several guesses
        merged: list[tuple[int, F64, str]] = []
        for i in range(max(len(by_position), len(by_descriptor))):
            merged += [lst[i] for lst in (by_descriptor, by_position) if i < len(lst)]
        places: list[tuple[int, list[F64], set[str]]] = []
        for j, guess, kind in merged:
            home = next((pl for pl in places if abs(pl[0] - j) <= cfg.submap_keyframes), None)
            if home is None:
                if len(places) >= cfg.max_candidates:
                    continue
                places.append((j, [guess], {kind}))
            elif len(home[1]) < 3:  # the guess in the home keyframe's frame
                home[1].append(se2_compose(se2_between(old[home[0]], old[j]), guess))
                home[2].add(kind)
        found = 0
        for j, guesses, kinds in places:
            self._counts["candidates"] += 1
            loop = self._verify(j, k, source, guesses, kinds)
            if loop is not None:
                self._loops.append(loop)
                self._counts["accepted"] += 1
                self._counts["from_descriptor" if loop.kind == "descriptor" else "from_position"] += 1
                found += 1
                if found >= cfg.max_loops_per_keyframe:
                    break

    def _verify(self, j: int, k: int, source: F64, guesses: list[F64], kinds: set[str]) -> _Loop | None:
        """ICP of keyframe k's points against the submap around keyframe j; the loop edge, or None."""
        from .kiss import KissMatcher, PreparedScan

        cfg = self.cfg
        n = cfg.submap_keyframes
        lo = max(0, j - n)
        hi = max(j, min(j + n, k - n - 1))
        poses = self._kf_pose.view
        rel = se2_between(poses[j], poses[lo: hi + 1])
        matcher = KissMatcher(self._icp_cfg)
        parts = []
        for i, r in zip(range(lo, hi + 1), rel):
            pts = self._kf_points[i].astype(np.float64)
            if pts.shape[0] == 0:
                continue
            p3 = np.zeros((pts.shape[0], 3))
            p3[:, :2] = pts
            matcher.update_map(PreparedScan(p3, p3), r)
            parts.append(se2_apply(r, pts))
        if not parts or sum(p.shape[0] for p in parts) < cfg.min_points:
            return None
        self._counts["verified"] += 1
        sub = _Submap(np.concatenate(parts))
        q3 = np.zeros((source.shape[0], 3))
        q3[:, :2] = source
        query = PreparedScan(q3, q3)
        best: _Match | None = None
        for guess in guesses:
            icp = matcher.align(query, guess)
            if not np.all(np.isfinite(icp)):
                continue
            match = _refine(sub, source, icp, cfg)
            if best is None or match.inliers > best.inliers:
                best = match
        if best is None or best.inliers < cfg.min_inliers:
            self._counts["rejected_inliers"] += 1
            log.debug("loop %d-%d: %.0f%% inliers", j, k, 100 * (best.inliers if best else 0.0))
            return None
        if best.condition < cfg.min_condition:
            self._counts["rejected_degenerate"] += 1
            log.debug("loop %d-%d: degenerate match (condition %.3g)", j, k, best.condition)
            return None
        if cfg.gate_factor > 0:
            said = se2_compose(poses[j], best.pose)
            radius = cfg.search_radius + cfg.drift_per_m * (self._kf_dist.view[k, 0] - self._kf_dist.view[j, 0])
            if math.hypot(said[0] - poses[k, 0], said[1] - poses[k, 1]) > cfg.gate_factor * radius:
                self._counts["rejected_gate"] += 1
                log.debug("loop %d-%d: correction beyond the gate", j, k)
                return None
        kind = "descriptor" if kinds == {"descriptor"} else "position"
        log.debug("loop %d-%d accepted (%s): %.0f%% inliers, condition %.3f, rms %.3f m", j, k, kind,
                  100 * best.inliers, best.condition, best.rms)
        return _Loop(j, k, best.pose, _inverse_spd(best.cov), kind)


def _inverse_spd(cov: F64) -> F64:
    """The inverse of a covariance, symmetrised (tiny eigenvalues floored)."""
    c = 0.5 * (cov + cov.T)
    w, v = np.linalg.eigh(c)
    w = np.maximum(w, 1e-12 * max(float(w.max()), 1e-12))
    return np.asarray((v / w) @ v.T)
