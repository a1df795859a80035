"""SE(2)/SE(3) helpers, angle wrapping and conversions.

Conventions (see docs/conventions.md): ``T_a_b`` maps coordinates in frame b into frame a,
``p_a = T_a_b @ p_b``. Floor poses are SE(2) ``(x, y, yaw)`` in metres and
radians; 4x4 matrices appear only at library boundaries.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

__all__ = [
    "dilate_mask",
    "disk_kernel",
    "is_rotation",
    "matrix_to_se2",
    "project_points",
    "quaternion_to_yaw",
    "se2_apply",
    "se2_between",
    "se2_compose",
    "se2_inverse",
    "se2_to_matrix",
    "se2_to_se3",
    "se3_apply",
    "se3_from_translation_quaternion",
    "se3_from_xyz_rpy",
    "se3_inverse",
    "se3_to_se2",
    "se3_to_translation_quaternion",
    "unproject_pixels",
    "wrap_angle",
    "yaw_to_quaternion",
]


def _wrap1(a: float) -> float:
    """One angle wrapped to (-pi, pi], in plain floats (the hot path: a pose at a time)."""
    w = math.pi - (math.pi - a) % (2.0 * math.pi)
    # the modulo of a tiny negative number rounds up to 2 pi (a = pi + 1 ulp gives -pi): that is +pi
    return math.pi if w == -math.pi else w


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles to (-pi, pi]."""
    if isinstance(angle, float | int):
        return _wrap1(float(angle))
    a = np.asarray(angle, dtype=np.float64)
    w = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    w = np.where(w == -np.pi, np.pi, w)  # as in _wrap1: a modulo rounded up to 2 pi
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
        ca, sa = math.cos(at), math.sin(at)
        return np.array([ax + ca * bx - sa * by, ay + sa * bx + ca * by, _wrap1(at + bt)])
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
        ca, sa = math.cos(at), math.sin(at)
        return np.array([-ca * ax - sa * ay, sa * ax - ca * ay, _wrap1(-at)])
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
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return float(yaw) if np.ndim(yaw) == 0 else yaw


def is_rotation(r: ArrayLike, tol: float = 1e-6) -> bool:
    """True if ``r`` is a proper 3x3 rotation matrix (orthonormal, det = +1)."""
    r = np.asarray(r, dtype=np.float64)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        return False
    return bool(np.allclose(r.T @ r, np.eye(3), atol=tol) and abs(np.linalg.det(r) - 1.0) < tol)


@lru_cache(maxsize=64)
def _radial_table(model: str, d: tuple[float, ...]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Undistorted normalised radius r (x/z, y/z) → distorted one, sampled up to where the model's radial
    distortion stops being one-to-one (or to 89.5 deg): both increasing. Only the radial terms count
    (tangential and thin-prism terms are small in real lenses)."""
    theta = np.radians(np.linspace(0.0, 89.5, 4000))
    r = np.tan(theta)
    if model == "fisheye":  # distorted radius theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
        k = (list(d) + [0.0] * 4)[:4]
        t2 = theta * theta
        dist = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
        den = np.ones_like(theta)
    else:  # r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
        k = (list(d) + [0.0] * 8)[:8]
        r2 = r * r
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            num = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
            den = 1.0 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
            dist = r * num / den
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(dist[1:]) | (den[1:] <= 0.0) | (np.diff(dist) <= 0.0)
    n = int(np.argmax(bad)) + 1 if bad.any() else r.size  # samples before the turn
    r, dist = r[:n].copy(), dist[:n].copy()
    r.setflags(write=False)
    dist.setflags(write=False)
    return r, dist


def _fold_radius(model: str, d: tuple[float, ...]) -> float:
    """The normalised radius (x/z, y/z) up to which a camera model's radial distortion is one-to-one.

    Past it, OpenCV's distortion polynomial turns back (barrel distortion, large |k1|) and folds
    points far outside the field of view back into the image. ``inf``: no fold before 89.5 deg.
    """
    r, _ = _radial_table(model, d)
    return math.inf if r.size == 4000 else float(r[-1])


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
    (z > ``min_depth``) that land inside the image. Points behind the camera, and points
    beyond the angle where the distortion polynomial turns back (which OpenCV would fold
    into the image), have NaN pixels and are never inside.
    """
    import cv2

    pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    uv = np.full((pts.shape[0], 2), np.nan)
    d = np.asarray(D, dtype=np.float64).ravel()
    z = pts[:, 2]
    front = z > min_depth
    r_fold = _fold_radius(model, tuple(d.tolist())) if d.any() else math.inf
    if r_fold < math.inf:
        front &= pts[:, 0] ** 2 + pts[:, 1] ** 2 < (r_fold * np.where(front, z, 0.0)) ** 2
    if front.any():
        obj = pts[front].reshape(-1, 1, 3)
        zero = np.zeros(3)
        k = np.asarray(K, dtype=np.float64)
        if model == "fisheye":
            img, _ = cv2.fisheye.projectPoints(obj, zero, zero, k, d)
        else:
            img, _ = cv2.projectPoints(obj, zero, zero, k, d)
        uv[front] = img.reshape(-1, 2)
    inside = front & (uv[:, 0] >= -0.5) & (uv[:, 0] < width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < height - 0.5)
    return uv, inside


def unproject_pixels(
    K: ArrayLike,
    D: ArrayLike,
    uv: ArrayLike,
    depth: ArrayLike,
    model: str = "pinhole",
) -> NDArray[np.float64]:
    """The inverse of :func:`project_points`: (N, 2) pixels at camera depths z (N,) → (N, 3) points
    in the camera optical frame.

    The radial distortion is inverted on a table of the model (one-to-one up to its fold, see
    :func:`project_points`), then Newton steps on OpenCV's projection remove the rest. Unlike
    OpenCV's fixed-point undistortion this converges in the image corners of strongly distorted
    and wide fisheye lenses. Pixels the model cannot reach from in front of the camera get the
    ray at the edge of its valid field of view.
    """
    import cv2

    px = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    z = np.broadcast_to(np.asarray(depth, dtype=np.float64).reshape(-1), (px.shape[0],))
    if px.shape[0] == 0:
        return np.zeros((0, 3))
    k = np.asarray(K, dtype=np.float64)
    d = np.asarray(D, dtype=np.float64).ravel()
    yd = (px[:, 1] - k[1, 2]) / k[1, 1]
    xd = (px[:, 0] - k[0, 2] - k[0, 1] * yd) / k[0, 0]
    xn = np.column_stack([xd, yd])
    if d.any() or model == "fisheye":  # (a fisheye without distortion is still equidistant, not pinhole)
        r_tab, rd_tab = _radial_table(model, tuple(d.tolist()))
        rd = np.hypot(xd, yd)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(rd > 0, np.interp(rd, rd_tab, r_tab) / rd, 1.0)
        xn *= scale[:, None]
        r_max = float(r_tab[-1])
        zero = np.zeros(3)
        proj = cv2.fisheye.projectPoints if model == "fisheye" else cv2.projectPoints

        def pixels(x: NDArray[np.float64]) -> NDArray[np.float64]:
            obj = np.column_stack([x, np.ones(len(x))]).reshape(-1, 1, 3)
            return np.asarray(proj(obj, zero, zero, k, d)[0], np.float64).reshape(-1, 2)

        h = 1e-7
        at = pixels(xn)
        err = np.hypot(*(px - at).T)
        for _ in range(20):
            if not np.nanmax(err) > 1e-10:
                break
            res = px - at
            jx = (pixels(xn + [h, 0.0]) - at) / h
            jy = (pixels(xn + [0.0, h]) - at) / h
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.column_stack([jy[:, 1] * res[:, 0] - jy[:, 0] * res[:, 1],
                                        jx[:, 0] * res[:, 1] - jx[:, 1] * res[:, 0]]) / det[:, None]
            step[~np.isfinite(step)] = 0.0
            # damped: a step must lower the pixel error and stay inside the model's one-to-one region
            for _ in range(6):
                cand = xn + step
                at_c = pixels(cand)
                err_c = np.hypot(*(px - at_c).T)
                better = (err_c < err) & (np.hypot(*cand.T) < r_max)
                xn[better], at[better], err[better] = cand[better], at_c[better], err_c[better]
                step[better] = 0.0
                if not step.any():
                    break
                step *= 0.5
    return np.column_stack([xn[:, 0] * z, xn[:, 1] * z, z])


def disk_kernel(radius_cells: float) -> NDArray[np.uint8]:
    """A round structuring element: the cells within ``radius_cells`` of the centre cell (uint8 0/1)."""
    r = max(0, int(math.floor(radius_cells + 1e-6)))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return (xx * xx + yy * yy <= radius_cells * radius_cells + 1e-6).astype(np.uint8)


def dilate_mask(mask: NDArray[np.bool_], radius_cells: float) -> NDArray[np.bool_]:
    """``mask`` grown by ``radius_cells`` (a disc); a copy when the radius is 0 or the mask empty."""
    if radius_cells <= 0 or not mask.any():
        return np.array(mask, dtype=bool, copy=True)
    import cv2

    return np.asarray(cv2.dilate(mask.astype(np.uint8), disk_kernel(radius_cells)) > 0)
