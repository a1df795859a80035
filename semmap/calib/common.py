"""Small helpers shared by the calibration modules: camera models, pose parameters, pose errors.

Conventions (see docs/conventions.md): ``T_a_b`` maps points in frame b into frame a. Here ``T_cam_lidar``
maps LiDAR-frame points into the camera optical frame, ``T_lidar_cam`` is its inverse.
"""

from __future__ import annotations

import math
from typing import cast

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from ..records import CameraIntrinsics

__all__ = [
    "ideal_intrinsics",
    "normalize_pixels",
    "pose_error",
    "project",
    "rotvec_translation",
    "se3_from_rotvec",
]


def se3_from_rotvec(rotvec: ArrayLike, translation: ArrayLike) -> NDArray[np.float64]:
    """4x4 transform from a rotation vector (axis × angle, rad) and a translation (m)."""
    t = np.eye(4)
    t[:3, :3] = Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_matrix()
    t[:3, 3] = np.asarray(translation, dtype=np.float64)
    return t


def rotvec_translation(t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """4x4 transform → (rotation vector, translation)."""
    m = np.asarray(t, dtype=np.float64)
    return Rotation.from_matrix(m[:3, :3]).as_rotvec(), m[:3, 3].copy()


def pose_error(T_est: ArrayLike, T_true: ArrayLike) -> tuple[float, float]:
    """Rotation error (degrees, the angle of ``R_est Rᵀ_true``) and translation error (m)."""
    a = np.asarray(T_est, dtype=np.float64)
    b = np.asarray(T_true, dtype=np.float64)
    r = a[:3, :3] @ b[:3, :3].T
    angle = math.degrees(math.acos(float(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))
    return angle, float(np.linalg.norm(a[:3, 3] - b[:3, 3]))


def ideal_intrinsics(intr: CameraIntrinsics) -> CameraIntrinsics:
    """The same camera with its distortion removed (what an undistorted image with matrix K shows)."""
    return CameraIntrinsics(intr.width, intr.height, intr.K, np.zeros(4 if intr.model == "fisheye" else 5),
                            intr.model)


def project(intr: CameraIntrinsics, points_cam: ArrayLike) -> NDArray[np.float64]:
    """Project (N, 3) camera-frame points to (N, 2) pixels with the camera's model.

    Unlike :func:`semmap.geometry.project_points` this does not mask points behind the
    camera: it is meant for residuals of points already known to be in front.
    """
    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 1, 3)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    zero = np.zeros(3)
    if intr.model == "fisheye":
        uv, _ = cv2.fisheye.projectPoints(pts, zero, zero, intr.K, intr.D)
    else:
        uv, _ = cv2.projectPoints(pts, zero, zero, intr.K, intr.D)
    return cast("NDArray[np.float64]", uv).reshape(-1, 2)  # float64 in, float64 out: cv2's stubs carry no dtype


def normalize_pixels(intr: CameraIntrinsics, pixels: ArrayLike) -> NDArray[np.float64]:
    """(N, 2) pixels → (N, 2) normalised image coordinates (x/z, y/z), distortion removed."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if px.shape[0] == 0:
        return np.zeros((0, 2))
    if intr.model == "fisheye":
        xn = cv2.fisheye.undistortPoints(px, intr.K, intr.D)
    else:
        xn = cv2.undistortPoints(px, intr.K, intr.D)
    return cast("NDArray[np.float64]", xn).reshape(-1, 2)  # float64 in, float64 out: cv2's stubs carry no dtype
