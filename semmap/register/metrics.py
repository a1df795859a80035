"""Trajectory accuracy: absolute trajectory error (ATE) after SE(2) alignment.

The estimate and the reference usually live in different frames (map vs world),
so the estimate is first rigidly aligned to the reference with the closed-form
2D Kabsch/Umeyama solution (rotation + translation, no scale), then the RMSE of
the position differences is taken. Timestamps are associated by interpolating
the reference at the estimate's stamps (linear in x, y and unwrapped yaw).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..geometry import se2_compose, wrap_angle

__all__ = ["align_se2", "associate", "ate_errors", "ate_rmse", "interpolate_poses"]


def interpolate_poses(stamps_ns: ArrayLike, poses: ArrayLike, query_ns: ArrayLike) -> NDArray[np.float64]:
    """SE(2) poses (N, 3) at integer-ns ``stamps_ns`` → poses at ``query_ns`` (linear; NaN outside the span)."""
    t = np.asarray(stamps_ns, dtype=np.int64)
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(query_ns, dtype=np.int64)
    if t.size == 0:
        return np.full((q.size, 3), np.nan)
    order = np.argsort(t, kind="stable")
    t, p = t[order], p[order]
    # interpolate in float seconds relative to the first stamp (int64 ns would lose precision as float)
    ts = (t - t[0]).astype(np.float64) * 1e-9
    qs = (q - t[0]).astype(np.float64) * 1e-9
    out = np.column_stack([np.interp(qs, ts, p[:, 0]), np.interp(qs, ts, p[:, 1]),
                           wrap_angle(np.interp(qs, ts, np.unwrap(p[:, 2])))]).reshape(-1, 3)
    outside = (q < t[0]) | (q > t[-1])
    out[outside] = np.nan
    return out


def associate(est_stamps: ArrayLike, ref_stamps: ArrayLike, ref_poses: ArrayLike,
              max_gap_ns: int = 100_000_000) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Reference poses at the estimate's stamps.

    Returns ``(valid, ref_at_est)``: ``valid`` marks estimate stamps inside the
    reference's span whose nearest reference stamp is at most ``max_gap_ns`` away.
    """
    est = np.asarray(est_stamps, dtype=np.int64)
    ref = np.sort(np.asarray(ref_stamps, dtype=np.int64))
    interp = interpolate_poses(ref_stamps, ref_poses, est)
    valid = np.all(np.isfinite(interp), axis=1)
    if ref.size:
        i = np.clip(np.searchsorted(ref, est), 1, max(ref.size - 1, 1))
        gap = np.minimum(np.abs(est - ref[i - 1]), np.abs(ref[np.minimum(i, ref.size - 1)] - est))
        valid &= gap <= max_gap_ns
    return valid, interp


def align_se2(src_xy: ArrayLike, dst_xy: ArrayLike) -> NDArray[np.float64]:
    """The SE(2) pose ``T`` minimising ``Σ |T·src_i - dst_i|²`` (2D Kabsch, no scale), as (x, y, yaw)."""
    a = np.asarray(src_xy, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(dst_xy, dtype=np.float64).reshape(-1, 2)
    if a.shape != b.shape or a.shape[0] == 0:
        raise ValueError(f"need matching non-empty point sets, got {a.shape} and {b.shape}")
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ma).T @ (b - mb)  # 2x2 cross-covariance
    yaw = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    t = mb - np.array([c * ma[0] - s * ma[1], s * ma[0] + c * ma[1]])
    return np.array([t[0], t[1], yaw])


def ate_errors(est_stamps: ArrayLike, est_poses: ArrayLike, ref_stamps: ArrayLike, ref_poses: ArrayLike,
               max_gap_ns: int = 100_000_000) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-pose position errors (m) after SE(2) alignment, and the alignment ``T_ref_est`` (x, y, yaw).

    Only estimate poses with an associated reference pose (see :func:`associate`) count.
    """
    est = np.asarray(est_poses, dtype=np.float64).reshape(-1, 3)
    valid, ref = associate(est_stamps, ref_stamps, ref_poses, max_gap_ns)
    valid &= np.all(np.isfinite(est), axis=1)
    if valid.sum() < 2:
        raise ValueError(f"only {int(valid.sum())} estimate poses overlap the reference in time")
    t_ref_est = align_se2(est[valid, :2], ref[valid, :2])
    aligned = se2_compose(t_ref_est, est[valid])
    return np.linalg.norm(aligned[:, :2] - ref[valid, :2], axis=1), t_ref_est


def ate_rmse(est_stamps: ArrayLike, est_poses: ArrayLike, ref_stamps: ArrayLike, ref_poses: ArrayLike,
             max_gap_ns: int = 100_000_000) -> float:
    """Absolute trajectory error: RMSE (m) of positions after SE(2) alignment of the estimate to the reference.

    ``est_stamps``/``ref_stamps`` are integer nanoseconds; poses are (N, 3) ``(x, y, yaw)``.
    The reference is interpolated at the estimate's stamps; estimate poses outside
    the reference's span, or more than ``max_gap_ns`` from a reference stamp, are skipped.
    """
    err, _ = ate_errors(est_stamps, est_poses, ref_stamps, ref_poses, max_gap_ns)
    return float(np.sqrt(np.mean(err ** 2)))
