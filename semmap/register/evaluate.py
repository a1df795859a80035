"""Trajectory errors against reference poses, with evo: ``semmap eval-traj``.

* **RPE**, as Kümmerle et al. 2009 ("On measuring the accuracy of SLAM algorithms") measure SLAM on
  the Radish logs: the relative motion between every pair of scans ``δ`` scans apart, estimated
  against reference, its translational (m) and rotational (°) error; mean and standard deviation. At ``δ = 1``
  the error barely separates odometry from good SLAM on those logs; at ``δ = 10`` it does.
* **ATE**: the RMSE of positions after the rigid (SE(3), here planar) alignment of the whole
  trajectory to the reference (Umeyama, no scale).

Poses are paired by stamp (nearest within ``max_diff_s``). evo computes every figure
(:mod:`evo.core.metrics`); evo is an optional dependency (``pip install 'semmap[eval]'``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError

__all__ = ["TrajectoryErrors", "trajectory_errors"]


@dataclass(frozen=True)
class TrajectoryErrors:
    """A trajectory's errors against the reference (metres and degrees)."""

    poses: int
    rpe: dict[int, dict[str, float]]  # delta -> trans_mean, trans_std, rot_mean_deg, rot_std_deg, pairs
    ate_rmse: float
    ate_max: float

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["rpe"] = {str(k): v for k, v in self.rpe.items()}
        return d


def _evo() -> Any:
    try:
        from evo.core import metrics, sync, trajectory
    except ImportError:
        raise ConfigError("eval-traj needs evo: pip install -c constraints.txt 'semmap[eval]'") from None
    return metrics, sync, trajectory


def _trajectory(stamps_ns: NDArray[np.int64], poses: NDArray[np.float64]) -> Any:
    _, _, trajectory = _evo()
    # in time order, one pose a stamp (a log may stamp two scans alike: the first is kept)
    stamps_ns = np.asarray(stamps_ns, np.int64)
    order = np.argsort(stamps_ns, kind="stable")
    _, first = np.unique(stamps_ns[order], return_index=True)
    keep = order[first]
    stamps_ns = stamps_ns[keep]
    poses = np.asarray(poses, np.float64).reshape(-1, 3)[keep]
    half = poses[:, 2] / 2.0
    xyz = np.stack([poses[:, 0], poses[:, 1], np.zeros(len(poses))], axis=1)
    quat_wxyz = np.stack([np.cos(half), np.zeros(len(poses)), np.zeros(len(poses)), np.sin(half)], axis=1)
    return trajectory.PoseTrajectory3D(positions_xyz=xyz, orientations_quat_wxyz=quat_wxyz,
                                       timestamps=np.asarray(stamps_ns, np.float64) * 1e-9)


def trajectory_errors(stamps_ns: NDArray[np.int64], poses: NDArray[np.float64], ref_stamps_ns: NDArray[np.int64],
                      ref_poses: NDArray[np.float64], deltas: tuple[int, ...] = (1, 10),
                      max_diff_s: float = 0.01) -> TrajectoryErrors:
    """RPE at each step in ``deltas`` (scans) and ATE of ``poses`` (N, 3) against ``ref_poses``."""
    metrics, sync, _ = _evo()
    from evo.core.units import Unit

    est = _trajectory(stamps_ns, poses)
    ref = _trajectory(ref_stamps_ns, ref_poses)
    try:
        ref, est = sync.associate_trajectories(ref, est, max_diff=max_diff_s)
    except Exception as exc:  # evo raises its own SyncException
        raise ConfigError(f"cannot pair the trajectory with the reference by stamp within {max_diff_s} s: {exc}") \
            from None
    n = est.num_poses
    if n < 2:
        raise ConfigError(f"only {n} poses pair with the reference by stamp (within {max_diff_s} s)")
    rpe: dict[int, dict[str, float]] = {}
    for delta in deltas:
        if delta >= n:
            continue
        row: dict[str, float] = {}
        for rel, key, scale in ((metrics.PoseRelation.translation_part, "trans", 1.0),
                                (metrics.PoseRelation.rotation_angle_deg, "rot", 1.0)):
            m = metrics.RPE(rel, delta=delta, delta_unit=Unit.frames, all_pairs=True)
            m.process_data((ref, est))
            err = np.asarray(m.error, np.float64) * scale
            suffix = "" if key == "trans" else "_deg"
            row[f"{key}_mean{suffix}"] = float(err.mean())
            row[f"{key}_std{suffix}"] = float(err.std())
            row["pairs"] = float(err.size)
        rpe[delta] = row
    aligned = est.__class__(poses_se3=est.poses_se3, timestamps=est.timestamps)
    aligned.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    err = np.asarray(ape.error, np.float64)
    return TrajectoryErrors(n, rpe, float(np.sqrt(np.mean(err ** 2))), float(err.max()))
