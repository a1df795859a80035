"""Synthetic calibration data with known truth: point–pixel pairs, board observations, board images.

Used by the tests and ``tools/bench_calib.py``; handy for trying a calibration set-up before
recording one. The default truth is the simulator's sensor layout: the LiDAR on the robot's
front-left corner (yawed 45°), the camera at the front centre, so
``T_cam_lidar = inv(T_base_cam) @ T_base_lidar``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ..geometry import se3_from_xyz_rpy, se3_inverse
from ..records import CameraIntrinsics
from .boards import BoardSpec, board_texture
from .common import normalize_pixels, project
from .pairs import PointPixelPairs

__all__ = [
    "SyntheticBoardView",
    "board_poses_in_view",
    "render_board_image",
    "scan_of_segments",
    "sim_calibration_truth",
    "sim_intrinsics",
    "simulate_board_views",
    "simulate_pairs",
]


def sim_intrinsics() -> CameraIntrinsics:
    """The simulator's camera: 640×480 with the research's K, no distortion."""
    from ..config import SimCameraConfig

    c = SimCameraConfig()
    return CameraIntrinsics(c.width, c.height, np.array(c.K), np.zeros(5), "pinhole")


def sim_calibration_truth() -> NDArray[np.float64]:
    """``T_cam_lidar`` of the simulator's default mounts (corner LiDAR, centre camera)."""
    from ..config import SimCameraConfig, SimLidarConfig

    lid, cam = SimLidarConfig().mount, SimCameraConfig().mount
    T_base_lidar = se3_from_xyz_rpy(lid.xyz, lid.rpy)
    T_base_cam = se3_from_xyz_rpy(cam.xyz, cam.rpy)
    return se3_inverse(T_base_cam) @ T_base_lidar


def simulate_pairs(
    T_cam_lidar: NDArray[np.float64],
    intrinsics: CameraIntrinsics,
    n: int = 30,
    noise_px: float = 1.0,
    outlier_fraction: float = 0.0,
    range_m: tuple[float, float] = (0.8, 4.0),
    margin_px: float = 20.0,
    seed: int = 0,
) -> tuple[PointPixelPairs, NDArray[np.bool_]]:
    """``n`` pairs of a LiDAR point (in the scan plane, within ``range_m`` of the LiDAR) and its
    pixel with Gaussian noise ``noise_px`` (per axis); a fraction replaced by gross outliers
    (a pixel anywhere in the image, at least 30 px from the truth).

    Returns the pairs and the mask of true inliers.
    """
    rng = np.random.default_rng(seed)
    pts: list[NDArray[np.float64]] = []
    uvs: list[NDArray[np.float64]] = []
    w, h = intrinsics.width, intrinsics.height
    while sum(len(p) for p in pts) < n:
        r = rng.uniform(*range_m, 4 * n)
        a = rng.uniform(-np.pi, np.pi, 4 * n)
        p = np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(4 * n)])
        pc = p @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
        front = pc[:, 2] > 0.3
        uv = np.full((len(p), 2), -1e9)
        uv[front] = project(intrinsics, pc[front])
        ok = front & (uv[:, 0] > margin_px) & (uv[:, 0] < w - margin_px) & (uv[:, 1] > margin_px) & (
            uv[:, 1] < h - margin_px)
        pts.append(p[ok, :2])
        uvs.append(uv[ok])
    xy = np.concatenate(pts)[:n]
    uv = np.concatenate(uvs)[:n] + rng.normal(0.0, noise_px, (n, 2))
    inlier = np.ones(n, bool)
    k = int(round(outlier_fraction * n))
    if k:
        idx = rng.choice(n, k, replace=False)
        for i in idx:
            while True:
                cand = rng.uniform([0, 0], [w, h])
                if np.hypot(*(cand - uv[i])) > 30.0:
                    break
            uv[i] = cand
        inlier[idx] = False
    return PointPixelPairs(xy, uv, source="simulated"), inlier


@dataclass(frozen=True)
class SyntheticBoardView:
    """One simulated observation of a board: its pose, corner pixels, and the scan of it.

    ``T_cam_board``: board frame (x along the pattern's columns, y along rows, z into the
    board) into the camera. ``corners_px`` (M, 2) noisy pixels of ``object_points`` (M, 3).
    ``scan_xy`` (K, 2): the LiDAR scan (LiDAR frame) of the room with the board in it.
    ``board_mask`` (K,): which scan points hit the board.
    """

    T_cam_board: NDArray[np.float64]
    object_points: NDArray[np.float64]
    corners_px: NDArray[np.float64]
    scan_xy: NDArray[np.float64]
    board_mask: NDArray[np.bool_]


def scan_of_segments(segments: NDArray[np.float64], fov_deg: float = 270.0, step_deg: float = 0.5,
                     noise_m: float = 0.01, max_range: float = 20.0,
                     rng: np.random.Generator | None = None) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Ray-cast a 2D scan from the origin against (S, 4) segments ``x0 y0 x1 y1``.

    Returns the hit points (K, 2) and, per point, the index of the segment it hit.
    """
    rng = rng or np.random.default_rng(0)
    ang = np.radians(np.arange(-fov_deg / 2, fov_deg / 2 + 1e-9, step_deg))
    d = np.column_stack([np.cos(ang), np.sin(ang)])
    a, b = segments[:, :2], segments[:, 2:]
    e = b - a
    # solve  s·d = a + u·e  for s (range) and u in [0, 1]
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (a[None, :, 0] * e[None, :, 1] - a[None, :, 1] * e[None, :, 0]) / den
        u = (a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]) / den
    valid = np.isfinite(s) & (s > 0.05) & (u >= 0) & (u <= 1) & (s < max_range)
    s = np.where(valid, s, np.inf)
    hit = np.argmin(s, axis=1)
    r = s[np.arange(len(ang)), hit]
    ok = np.isfinite(r)
    r = r[ok] + rng.normal(0.0, noise_m, ok.sum())
    return d[ok] * r[:, None], hit[ok]


def _board_pose(rng: np.random.Generator, centre_lidar: NDArray[np.float64],
                T_cam_lidar: NDArray[np.float64], tilt_deg: tuple[float, float]) -> NDArray[np.float64]:
    """A board pose (in the camera) standing on the scan plane at ``centre_lidar``, roughly facing
    the camera: turned up to ±35° about the vertical (the LiDAR's z), leaning forward or back
    by ``tilt_deg[0]``–``tilt_deg[1]``, and rolled up to ±15° in its own plane."""
    from scipy.spatial.transform import Rotation

    c_cam = T_cam_lidar[:3, :3] @ centre_lidar + T_cam_lidar[:3, 3]
    up = T_cam_lidar[:3, 2]
    z_axis = c_cam - (c_cam @ up) * up  # horizontal, away from the camera
    z_axis /= np.linalg.norm(z_axis)
    x_axis = np.cross(-up, z_axis)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)  # points down
    R0 = np.column_stack([x_axis, y_axis, z_axis])
    lean = rng.uniform(*tilt_deg) * rng.choice([-1.0, 1.0])
    yaw, tilt, roll = np.radians([rng.uniform(-35, 35), lean, rng.uniform(-15, 15)])
    R = R0 @ Rotation.from_euler("YXZ", [yaw, tilt, roll]).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c_cam
    return T


def simulate_board_views(
    T_cam_lidar: NDArray[np.float64],
    intrinsics: CameraIntrinsics,
    board: BoardSpec,
    n_views: int = 20,
    tilt_deg: tuple[float, float] = (10.0, 40.0),
    range_noise_m: float = 0.01,
    pixel_noise_px: float = 0.3,
    distance_m: tuple[float, float] = (1.0, 2.5),
    panel_margin_m: float = 0.1,
    seed: int = 0,
) -> list[SyntheticBoardView]:
    """Board observations as the target method needs them, with known truth.

    Each view: a rigid panel carrying the pattern (``panel_margin_m`` around it) stands
    ``distance_m`` in front of the camera where the scan plane cuts it (through the middle
    40 % of its height), leaning forward or back by ``tilt_deg[0]``–``tilt_deg[1]`` degrees;
    the camera sees the pattern's corners (pixel noise ``pixel_noise_px``), the LiDAR scans a
    6 × 5 m room with the panel in it (range noise ``range_noise_m``). ``tilt_deg=(0, 0)``
    gives vertical boards, the degenerate case for a level LiDAR.
    """
    rng = np.random.default_rng(seed)
    obj = board.object_points()
    lo, hi = obj[:, :2].min(axis=0) - (board.square_m + panel_margin_m), obj[:, :2].max(axis=0) + (
        board.square_m + panel_margin_m)
    T_lidar_cam = se3_inverse(T_cam_lidar)
    room = np.array([[-2.0, -2.5, 4.0, -2.5], [4.0, -2.5, 4.0, 2.5], [4.0, 2.5, -2.0, 2.5],
                     [-2.0, 2.5, -2.0, -2.5]])
    views: list[SyntheticBoardView] = []
    tries = 0
    while len(views) < n_views:
        tries += 1
        if tries > 200 * n_views:
            raise RuntimeError("could not place boards in view; check the camera and LiDAR poses")
        # a point in the scan plane in front of the camera
        cam_dir = np.array([rng.uniform(-0.35, 0.35), 0.0, 1.0])
        cam_dir /= np.linalg.norm(cam_dir)
        dist = rng.uniform(*distance_m)
        p_cam = cam_dir * dist
        # move it into the scan plane along the camera's vertical
        p_l = T_lidar_cam[:3, :3] @ p_cam + T_lidar_cam[:3, 3]
        p_l[2] = 0.0
        T_cb = _board_pose(rng, p_l, T_cam_lidar, tilt_deg)
        centre_board = 0.5 * (lo + hi)
        # slide the board in its plane so the scan cuts it at a random height
        cut = rng.uniform(lo[1] + 0.3 * (hi[1] - lo[1]), lo[1] + 0.7 * (hi[1] - lo[1]))
        T_cb[:3, 3] -= T_cb[:3, :3] @ np.array([centre_board[0], cut, 0.0])
        pc = obj @ T_cb[:3, :3].T + T_cb[:3, 3]
        if np.any(pc[:, 2] < 0.2):
            continue
        uv = project(intrinsics, pc)
        if np.any(uv < 5) or np.any(uv[:, 0] > intrinsics.width - 5) or np.any(uv[:, 1] > intrinsics.height - 5):
            continue
        # the panel's cut by the scan plane, in the LiDAR frame
        T_lb = T_lidar_cam @ T_cb
        corners_b = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0.0]])
        cl = corners_b @ T_lb[:3, :3].T + T_lb[:3, 3]
        seg = []
        for i in range(4):
            a, b = cl[i], cl[(i + 1) % 4]
            if (a[2] > 0) != (b[2] > 0):
                s = a[2] / (a[2] - b[2])
                seg.append(a + s * (b - a))
        if len(seg) != 2:
            continue
        s2 = np.array([[seg[0][0], seg[0][1], seg[1][0], seg[1][1]]])
        scan, hit = scan_of_segments(np.vstack([room, s2]), noise_m=range_noise_m, rng=rng)
        mask = hit == len(room)
        if mask.sum() < 10:
            continue
        views.append(SyntheticBoardView(T_cb, obj, uv + rng.normal(0, pixel_noise_px, uv.shape), scan, mask))
    return views


def render_board_image(
    board: BoardSpec,
    intrinsics: CameraIntrinsics,
    T_cam_board: NDArray[np.float64],
    background: int = 110,
    blur_px: float = 0.6,
    noise: float = 2.0,
    seed: int = 0,
) -> NDArray[np.uint8]:
    """A grey image of the board seen through the camera (distortion included), for tests.

    Every pixel's ray (undistorted with the camera model) is intersected with the board
    plane and looks up the board's texture; the image is slightly blurred and noisy.
    """
    rng = np.random.default_rng(seed)
    # texture resolution: about two texels per image pixel where the board is nearest
    depth = float(np.min((board.object_points() @ T_cam_board[:3, :3].T + T_cam_board[:3, 3])[:, 2]))
    square_px = intrinsics.fx * board.square_m / max(depth, 1e-3)
    tex, mpp, offset = board_texture(board, px_per_square=int(np.clip(2 * square_px, 16, 160)))
    w, h = intrinsics.width, intrinsics.height
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xn = normalize_pixels(intrinsics, np.column_stack([uu.ravel(), vv.ravel()]))
    rays = np.column_stack([xn, np.ones(len(xn))])
    R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
    n = R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (n @ t) / (rays @ n)
    pb = (rays * s[:, None] - t) @ R  # ray hits, in the board frame
    mx = ((pb[:, 0] - offset[0]) / mpp - 0.5).reshape(h, w)
    my = ((pb[:, 1] - offset[1]) / mpp - 0.5).reshape(h, w)
    bad = ~np.isfinite(s.reshape(h, w)) | (s.reshape(h, w) <= 0) | ~np.isfinite(mx) | ~np.isfinite(my)
    mx[bad] = -1e6
    my[bad] = -1e6
    # supersample 2x2 per pixel by averaging four shifted lookups (cheap anti-aliasing)
    img = np.zeros((h, w), np.float32)
    dx = np.gradient(mx, axis=1)
    dy = np.gradient(my, axis=0)
    for sx, sy in ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)):
        img += cv2.remap(tex, (mx + sx * dx).astype(np.float32), (my + sy * dy).astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=background).astype(np.float32)
    img /= 4.0
    if blur_px > 0:
        img = cast("NDArray[np.float32]", cv2.GaussianBlur(img, (0, 0), blur_px))  # float32 in, float32 out
    img += rng.normal(0.0, noise, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def board_poses_in_view(
    board: BoardSpec,
    intrinsics: CameraIntrinsics,
    n: int,
    distance_m: tuple[float, float] = (0.5, 1.0),
    max_angle_deg: float = 35.0,
    margin_px: float = 10.0,
    seed: int = 0,
) -> list[NDArray[np.float64]]:
    """``n`` random ``T_cam_board`` with the whole board inside the image, turned up to
    ``max_angle_deg`` about its x and y axes and spread over the field of view (where lens
    distortion shows)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    obj = board.object_points()
    centre = 0.5 * (obj.min(axis=0) + obj.max(axis=0))
    w, h = board.size_m
    corners = centre + np.array([[-w / 2, -h / 2, 0], [w / 2, -h / 2, 0], [w / 2, h / 2, 0], [-w / 2, h / 2, 0]])
    poses: list[NDArray[np.float64]] = []
    for _ in range(1000 * n):
        if len(poses) == n:
            break
        a = max_angle_deg
        R = Rotation.from_euler("xyz", [rng.uniform(-a, a), rng.uniform(-a, a), rng.uniform(-20, 20)],
                                degrees=True).as_matrix()
        z = rng.uniform(*distance_m)
        xn = normalize_pixels(intrinsics, rng.uniform([0, 0], [intrinsics.width, intrinsics.height])[None])[0]
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = np.array([xn[0] * z, xn[1] * z, z]) - R @ centre
        pc = corners @ R.T + T[:3, 3]
        if np.any(pc[:, 2] < 0.05):
            continue
        uv = project(intrinsics, pc)
        if np.all((uv > margin_px) & (uv < np.array([intrinsics.width, intrinsics.height]) - margin_px)):
            poses.append(T)
    if len(poses) < n:
        raise RuntimeError("could not place the board in view; move it further away")
    return poses
