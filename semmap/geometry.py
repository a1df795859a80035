"""SE(2)/SE(3) helpers, angle wrapping and conversions.

Conventions (see README): ``T_a_b`` maps coordinates in frame b into frame a,
``p_a = T_a_b @ p_b``. Floor poses are SE(2) ``(x, y, yaw)`` in metres and
radians; 4x4 matrices appear only at library boundaries.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

__all__ = [
    "wrap_angle",
    "se2_compose",
    "se2_inverse",
    "se2_between",
    "se2_apply",
    "se2_to_matrix",
    "matrix_to_se2",
    "se2_to_se3",
    "se3_to_se2",
    "se3_inverse",
    "se3_from_xyz_rpy",
    "se3_from_translation_quaternion",
    "se3_to_translation_quaternion",
    "se3_apply",
    "yaw_to_quaternion",
    "quaternion_to_yaw",
    "is_rotation",
    "project_points",
]


def _wrap1(a: float) -> float:
    """One angle wrapped to (-pi, pi], in plain floats (the hot path: a pose at a time)."""
    return math.pi - (math.pi - a) % (2.0 * math.pi)


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to (-pi, pi]."""
    if isinstance(angle, float | int):
        return _wrap1(float(angle))
    a = np.asarray(angle, dtype=np.float64)
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return float(w) if w.ndim == 0 else w


def _pose_array(p: ArrayLike) -> NDArray[np.float64]:
    a = np.asarray(p, dtype=np.float64)
    if a.shape[-1] != 3:
        raise ValueError(f"SE(2) pose must have 3 components (x, y, yaw), got shape {a.shape}")
    return a


def se2_compose(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Return ``a ⊕ b``: the pose b (expressed in frame a) in a's parent frame.

    Broadcasts over leading dimensions of (…, 3) arrays.
    """
    a = _pose_array(a)
    b = _pose_array(b)
    if a.shape == (3,) and b.shape == (3,):  # one pose: plain floats are 10x faster than numpy ufuncs
        ax, ay, at = a.tolist()
        bx, by, bt = b.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([ax + c * bx - s * by, ay + s * bx + c * by, _wrap1(at + bt)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    yaw = wrap_angle(a[..., 2] + b[..., 2])
    return np.stack([x, y, yaw], axis=-1)


def se2_inverse(a: ArrayLike) -> NDArray[np.float64]:
    """Return the inverse pose ``a⁻¹``."""
    a = _pose_array(a)
    if a.shape == (3,):
        ax, ay, at = a.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([-c * ax - s * ay, s * ax - c * ay, _wrap1(-at)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def se2_between(a: ArrayLike, b: ArrayLike) -> NDArray[np.float64]:
    """Return ``a⁻¹ ⊕ b``: pose b expressed in frame a (the relative motion a→b)."""
    return se2_compose(se2_inverse(a), b)


def se2_apply(pose: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Map (N, 2) points from the pose's frame into its parent frame."""
    p = _pose_array(pose)
    pts = np.asarray(points, dtype=np.float64)
    c, s = np.cos(p[2]), np.sin(p[2])
    out = np.empty_like(pts)
    out[..., 0] = p[0] + c * pts[..., 0] - s * pts[..., 1]
    out[..., 1] = p[1] + s * pts[..., 0] + c * pts[..., 1]
    return out


def se2_to_matrix(pose: ArrayLike) -> NDArray[np.float64]:
    """(x, y, yaw) → 3x3 homogeneous matrix."""
    x, y, yaw = _pose_array(pose)
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def matrix_to_se2(m: ArrayLike) -> NDArray[np.float64]:
    """3x3 homogeneous matrix → (x, y, yaw)."""
    m = np.asarray(m, dtype=np.float64)
    return np.array([m[0, 2], m[1, 2], np.arctan2(m[1, 0], m[0, 0])])


def se2_to_se3(pose: ArrayLike, z: float = 0.0) -> NDArray[np.float64]:
    """(x, y, yaw) → 4x4 transform in the plane z = ``z``."""
    x, y, yaw = (float(v) for v in _pose_array(pose).reshape(3))
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, float(z)], [0.0, 0.0, 0.0, 1.0]])


def se3_to_se2(t: ArrayLike) -> NDArray[np.float64]:
    """4x4 transform → (x, y, yaw), projecting onto the floor plane."""
    t = np.asarray(t, dtype=np.float64)
    return np.array([t[0, 3], t[1, 3], np.arctan2(t[1, 0], t[0, 0])])


def se3_inverse(t: ArrayLike) -> NDArray[np.float64]:
    """Inverse of a rigid 4x4 transform."""
    t = np.asarray(t, dtype=np.float64)
    out = np.eye(4)
    r = t[:3, :3]
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t[:3, 3]
    return out


def se3_from_xyz_rpy(xyz: ArrayLike, rpy: ArrayLike = (0.0, 0.0, 0.0)) -> NDArray[np.float64]:
    """4x4 transform from a translation and roll-pitch-yaw (URDF convention, fixed axes XYZ)."""
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("xyz", np.asarray(rpy, dtype=np.float64)).as_matrix()
    t[:3, 3] = np.asarray(xyz, dtype=np.float64)
    return t


def se3_from_translation_quaternion(
    translation: ArrayLike, quaternion_xyzw: ArrayLike
) -> NDArray[np.float64]:
    """4x4 transform from a translation and a quaternion in ROS order (x, y, z, w)."""
    t = np.eye(4)
    t[:3, :3] = Rotation.from_quat(np.asarray(quaternion_xyzw, dtype=np.float64)).as_matrix()
    t[:3, 3] = np.asarray(translation, dtype=np.float64)
    return t


def se3_to_translation_quaternion(
    t: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """4x4 transform → (translation, quaternion (x, y, z, w))."""
    t = np.asarray(t, dtype=np.float64)
    return t[:3, 3].copy(), Rotation.from_matrix(t[:3, :3]).as_quat()


def se3_apply(t: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Map (N, 3) points with a 4x4 transform."""
    t = np.asarray(t, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float64)
    return pts @ t[:3, :3].T + t[:3, 3]


def yaw_to_quaternion(yaw: ArrayLike) -> NDArray[np.float64]:
    """Yaw angle(s) → quaternion(s) (x, y, z, w) about +z."""
    h = 0.5 * np.asarray(yaw, dtype=np.float64)
    zeros = np.zeros_like(h)
    return np.stack([zeros, zeros, np.sin(h), np.cos(h)], axis=-1)


def quaternion_to_yaw(q_xyzw: ArrayLike) -> NDArray[np.float64] | float:
    """Quaternion(s) (x, y, z, w) → yaw about +z (the heading of the rotated x axis)."""
    if isinstance(q_xyzw, list | tuple) and len(q_xyzw) == 4 and all(isinstance(v, float | int) for v in q_xyzw):
        x, y, z, w = (float(v) for v in q_xyzw)  # one quaternion (an odometry message): no arrays
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    q = np.asarray(q_xyzw, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return float(yaw) if np.ndim(yaw) == 0 else yaw


def is_rotation(r: ArrayLike, tol: float = 1e-6) -> bool:
    """True if ``r`` is a proper 3x3 rotation matrix (orthonormal, det = +1)."""
    r = np.asarray(r, dtype=np.float64)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        return False
    return bool(np.allclose(r.T @ r, np.eye(3), atol=tol) and abs(np.linalg.det(r) - 1.0) < tol)


def project_points(
    K: ArrayLike,
    D: ArrayLike,
    points_cam: ArrayLike,
    width: int,
    height: int,
    model: str = "pinhole",
    min_depth: float = 1e-3,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Project (N, 3) camera-optical-frame points to pixels with OpenCV's camera models.

    Returns pixel coordinates (N, 2) and a mask of points in front of the camera
    (z > ``min_depth``) that land inside the image.
    """
    import cv2

    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    uv = np.full((pts.shape[0], 2), np.nan)
    front = pts[:, 2] > min_depth
    if front.any():
        obj = pts[front].reshape(-1, 1, 3)
        zero = np.zeros(3)
        k = np.asarray(K, dtype=np.float64)
        d = np.asarray(D, dtype=np.float64).ravel()
        if model == "fisheye":
            img, _ = cv2.fisheye.projectPoints(obj, zero, zero, k, d)
        else:
            img, _ = cv2.projectPoints(obj, zero, zero, k, d)
        uv[front] = img.reshape(-1, 2)
    inside = front & (uv[:, 0] >= -0.5) & (uv[:, 0] < width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < height - 0.5)
    return uv, inside
