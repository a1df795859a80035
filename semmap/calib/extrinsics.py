"""``T_cam_lidar`` from manual LiDAR-point ↔ pixel pairs (Hong et al.'s method), robustly.

The LiDAR points all lie in the scan plane (z = 0 in the LiDAR frame), so each random
sample of four pairs gives the pose in closed form through the plane's homography
(OpenCV's IPPE): no initial guess is needed. RANSAC keeps the pose most pairs agree
with; Levenberg–Marquardt then minimises the pixel reprojection error over the inliers,
in the image the pixels were picked on (raw, or already undistorted as in Hong's tool).

The result maps LiDAR points into the camera: ``p_cam = T_cam_lidar @ p_lidar``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, cast

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from ..errors import ConfigError
from ..geometry import se3_inverse
from ..records import CameraIntrinsics
from .common import ideal_intrinsics, normalize_pixels, project, rotvec_translation, se3_from_rotvec
from .pairs import PointPixelPairs

__all__ = ["MIN_PAIRS", "PairsCalibration", "calibrate_from_pairs"]

log = logging.getLogger(__name__)

MIN_PAIRS = 6


@dataclass(frozen=True)
class PairResidual:
    """One pair's reprojection error at the solution."""

    index: int
    line: int
    lidar_xy: tuple[float, float]
    pixel: tuple[float, float]
    residual_px: float
    inlier: bool


@dataclass(frozen=True)
class PairsCalibration:
    """``T_cam_lidar`` solved from point–pixel pairs, with the evidence to judge it.

    * ``residuals_px`` (N,): each pair's reprojection error at the solution, pixels.
    * ``inliers`` (N,): pairs kept by RANSAC (error below ``threshold_px``).
    * ``rms_px``: RMS reprojection error over the inliers (what Hong's tool and the research report).
    * ``rotation_std_deg`` / ``translation_std_m``: 1-σ uncertainty from the fit's covariance.
    """

    T_cam_lidar: NDArray[np.float64]
    rms_px: float
    residuals_px: NDArray[np.float64]
    inliers: NDArray[np.bool_]
    threshold_px: float
    rotation_std_deg: float
    translation_std_m: float
    pairs: PointPixelPairs
    undistorted: bool

    @property
    def T_lidar_cam(self) -> NDArray[np.float64]:
        """The inverse: maps camera-frame points into the LiDAR frame."""
        return se3_inverse(self.T_cam_lidar)

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())

    def per_pair(self) -> list[PairResidual]:
        return [PairResidual(i, self.pairs.lines[i], (float(x), float(y)), (float(u), float(v)),
                             float(self.residuals_px[i]), bool(self.inliers[i]))
                for i, ((x, y), (u, v)) in enumerate(zip(self.pairs.lidar_xy, self.pairs.pixels))]

    def worst(self, k: int = 5) -> list[PairResidual]:
        """The ``k`` pairs with the largest reprojection error, worst first."""
        return sorted(self.per_pair(), key=lambda r: -r.residual_px)[:k]

    def report(self) -> dict[str, Any]:
        """What goes into the calibration file's ``extrinsics`` section."""
        return {
            "method": "pairs_pnp",
            "source": self.pairs.source,
            "pixels_undistorted": self.undistorted,
            "pairs": len(self.pairs),
            "inliers": self.n_inliers,
            "ransac_threshold_px": round(self.threshold_px, 3),
            "rms_px": round(self.rms_px, 4),
            "rotation_std_deg": round(self.rotation_std_deg, 4),
            "translation_std_m": round(self.translation_std_m, 5),
            "residuals_px": [round(float(r), 3) for r in self.residuals_px],
            "outlier_lines": [r.line for r in self.per_pair() if not r.inlier],
            "worst_pairs": [{"line": r.line, "residual_px": round(r.residual_px, 3), "inlier": r.inlier}
                            for r in self.worst(5)],
        }


def _errors_px(rvec_R: NDArray[np.float64], t: NDArray[np.float64], obj: NDArray[np.float64],
               xn: NDArray[np.float64], f: float) -> NDArray[np.float64]:
    """Reprojection error in normalised coordinates, scaled to pixels by ``f``; inf behind the camera."""
    pc = obj @ rvec_R.T + t
    z = pc[:, 2]
    err = np.full(obj.shape[0], np.inf)
    ok = z > 1e-6
    err[ok] = f * np.hypot(pc[ok, 0] / z[ok] - xn[ok, 0], pc[ok, 1] / z[ok] - xn[ok, 1])
    return err


def _ransac(obj: NDArray[np.float64], xn: NDArray[np.float64], f: float, threshold_px: float,
            iterations: int, confidence: float, rng: np.random.Generator
            ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    n = obj.shape[0]
    best_T: NDArray[np.float64] | None = None
    best_inl = np.zeros(n, bool)
    best_cost = np.inf
    eye = np.eye(3)
    needed = iterations
    i = 0
    while i < min(needed, iterations):
        i += 1
        idx = rng.choice(n, 4, replace=False)
        o4 = obj[idx]
        # skip near-collinear samples: the smallest triangle of the four must have some area
        d = o4[:, :2] - o4[:, :2].mean(axis=0)
        sv = np.linalg.svd(d, compute_uv=False)
        if sv[1] < 1e-3 * max(sv[0], 1e-12):
            continue
        try:
            nsol, rvecs, tvecs, _ = cv2.solvePnPGeneric(o4, xn[idx].reshape(-1, 1, 2), eye, None,
                                                        flags=cv2.SOLVEPNP_IPPE)
        except cv2.error:
            continue
        for r, t in zip(rvecs[:nsol], tvecs[:nsol]):
            R = cast("NDArray[np.float64]", cv2.Rodrigues(r)[0])  # float64 (cv2's stubs carry no dtype)
            err = _errors_px(R, cast("NDArray[np.float64]", t).ravel(), obj, xn, f)
            inl = err < threshold_px
            # MSAC cost: inliers pay their squared error, outliers the threshold
            cost = float(np.sum(np.minimum(err, threshold_px) ** 2))
            if inl.sum() > best_inl.sum() or (inl.sum() == best_inl.sum() and cost < best_cost):
                best_inl, best_cost = inl, cost
                best_T = np.eye(4)
                best_T[:3, :3], best_T[:3, 3] = R, t.ravel()
                w = inl.mean()
                if w >= 1.0:
                    needed = 0
                elif w > 0:
                    needed = int(math.ceil(math.log(1 - confidence) / math.log(1 - w**4)))
    if best_T is None or best_inl.sum() < 4:
        raise ConfigError("pairs: no pose agrees with at least 4 pairs "
                          f"(within {threshold_px:g} px); check the pairs' units (m, px) and order (x y u v)")
    return best_T, best_inl


def _refine(T0: NDArray[np.float64], obj: NDArray[np.float64], pixels: NDArray[np.float64],
            model: CameraIntrinsics) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """LM on the pixel reprojection error; returns the pose and the Jacobian at it (2N × 6)."""
    r0, t0 = rotvec_translation(T0)

    def residuals(x: NDArray[np.float64]) -> NDArray[np.float64]:
        T = se3_from_rotvec(x[:3], x[3:])
        return (project(model, obj @ T[:3, :3].T + T[:3, 3]) - pixels).ravel()

    x0 = np.concatenate([r0, t0])
    method = "lm" if obj.shape[0] * 2 >= 6 else "trf"
    sol = least_squares(residuals, x0, method=method, x_scale="jac")
    return se3_from_rotvec(sol.x[:3], sol.x[3:]), sol.jac


def calibrate_from_pairs(
    pairs: PointPixelPairs,
    intrinsics: CameraIntrinsics,
    *,
    undistorted: bool = False,
    threshold_px: float = 8.0,
    iterations: int = 2000,
    confidence: float = 0.999,
    seed: int = 0,
) -> PairsCalibration:
    """Solve ``T_cam_lidar`` from LiDAR-point ↔ pixel pairs: RANSAC + Levenberg–Marquardt.

    ``undistorted``: the pixels were picked on an image already undistorted with camera
    matrix ``K`` (Hong's tool works that way); otherwise on the raw image, through ``D``.
    ``threshold_px``: the RANSAC inlier threshold; after refinement it grows to three times
    the inliers' robust RMS if that is larger, so honest pairs with a few pixels of picking
    error are kept.
    """
    n = len(pairs)
    src = pairs.source or "pairs"
    if n < MIN_PAIRS:
        raise ConfigError(f"{src}: {n} pairs; need at least {MIN_PAIRS} (the research used about 30)")
    xy = pairs.lidar_xy
    spread = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
    if spread[1] < 1e-3 * max(spread[0], 1e-9) or spread[0] < 1e-6:
        raise ConfigError(f"{src}: the LiDAR points lie on one line; pick points at different "
                          "distances and directions")
    model = ideal_intrinsics(intrinsics) if undistorted else intrinsics
    obj = pairs.lidar_points
    px = np.asarray(pairs.pixels, dtype=np.float64)
    xn = normalize_pixels(model, px)
    f = 0.5 * (intrinsics.fx + intrinsics.fy)
    rng = np.random.default_rng(seed)
    T, inl = _ransac(obj, xn, f, threshold_px, iterations, confidence, rng)
    log.info("RANSAC: %d of %d pairs within %.1f px", inl.sum(), n, threshold_px)
    thr = threshold_px
    for _ in range(3):
        T, jac = _refine(T, obj[inl], px[inl], model)
        err = np.linalg.norm(project(model, obj @ T[:3, :3].T + T[:3, 3]) - px, axis=1)
        front = (obj @ T[:3, :3].T + T[:3, 3])[:, 2] > 0
        err[~front] = np.inf
        robust_rms = 1.2 * float(np.median(err[inl]))
        thr = max(threshold_px, 3.0 * robust_rms)
        new = err < thr
        if new.sum() < 4:
            break
        if np.array_equal(new, inl):
            break
        inl = new
    T, jac = _refine(T, obj[inl], px[inl], model)
    pc = obj @ T[:3, :3].T + T[:3, 3]
    err = np.linalg.norm(project(model, pc) - px, axis=1)
    err[pc[:, 2] <= 0] = np.inf
    m = int(inl.sum())
    rms = float(np.sqrt(np.mean(err[inl] ** 2)))
    # covariance of (rotvec, t) from the Jacobian, with the residual variance per coordinate
    dof = max(2 * m - 6, 1)
    sigma2 = float(np.sum(err[inl] ** 2)) / dof
    try:
        cov = np.linalg.inv(jac.T @ jac) * sigma2
        rot_std = math.degrees(math.sqrt(max(np.trace(cov[:3, :3]), 0.0)))
        trans_std = math.sqrt(max(np.trace(cov[3:, 3:]), 0.0))
    except np.linalg.LinAlgError:
        rot_std = trans_std = math.inf
    return PairsCalibration(
        T_cam_lidar=T, rms_px=rms, residuals_px=err, inliers=inl, threshold_px=thr,
        rotation_std_deg=rot_std, translation_std_m=trans_std, pairs=pairs, undistorted=undistorted,
    )
