"""Camera intrinsics from images of a board: pinhole with OpenCV distortion, or fisheye.

Images where the board is not found are reported and skipped. The result carries the RMS
reprojection error over all images and the error of each image, so a bad image (motion
blur, a mis-detected board) stands out.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..records import CameraIntrinsics
from .boards import BoardDetection, BoardSpec, detect_board, parse_board_spec

__all__ = ["MIN_IMAGES", "ImageReport", "IntrinsicsCalibration", "calibrate_intrinsics"]

log = logging.getLogger(__name__)

MIN_IMAGES = 3

Model = Literal["pinhole", "fisheye"]


@dataclass(frozen=True)
class ImageReport:
    """One image: its name, the board points used and their RMS reprojection error (px)."""

    name: str
    points: int
    rms_px: float


@dataclass(frozen=True)
class IntrinsicsCalibration:
    """The camera model, the overall RMS reprojection error (px), each image's error, the
    images skipped (name, reason), and each used image's board pose ``T_cam_board``."""

    intrinsics: CameraIntrinsics
    rms_px: float
    images: tuple[ImageReport, ...]
    skipped: tuple[tuple[str, str], ...]
    board: BoardSpec
    T_cam_board: tuple[NDArray[np.float64], ...] = field(default_factory=tuple)

    def report(self) -> dict[str, Any]:
        """What goes into the calibration file's ``intrinsics`` section besides K and D."""
        return {
            "rms_px": round(self.rms_px, 4),
            "board": str(self.board),
            "images": [{"file": r.name, "points": r.points, "rms_px": round(r.rms_px, 4)} for r in self.images],
            "skipped": [{"file": n, "reason": why} for n, why in self.skipped],
        }


def _fisheye_flag(name: str) -> int:
    """OpenCV 4 keeps the fisheye flags in ``cv2.fisheye``, OpenCV 5 in ``cv2``."""
    return int(getattr(cv2.fisheye, f"CALIB_{name}", None) or getattr(cv2, f"CALIB_{name}"))


ImageSource = str | Path | NDArray[np.generic]


def _load(src: ImageSource, index: int) -> tuple[str, NDArray[np.generic] | None, str]:
    if isinstance(src, str | Path):
        p = Path(src)
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        return p.name, img, "" if img is not None else "not an image OpenCV can read"
    return f"image {index}", np.asarray(src), ""


def calibrate_intrinsics(
    images: Sequence[ImageSource],
    board: BoardSpec | str,
    *,
    model: Model = "pinhole",
    distortion_coefficients: int = 5,
    fix_aspect_ratio: bool = False,
    zero_tangential: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> IntrinsicsCalibration:
    """Calibrate a camera from board images (file paths or arrays).

    ``model``: ``pinhole`` (OpenCV ``k1 k2 p1 p2 [k3 [k4 k5 k6]]``, ``distortion_coefficients``
    4, 5 or 8) or ``fisheye`` (OpenCV's equidistant model, ``k1 k2 k3 k4``). All images must
    have the same size.
    """
    spec = parse_board_spec(board)
    if model not in ("pinhole", "fisheye"):
        raise ConfigError(f"camera model must be 'pinhole' or 'fisheye', got {model!r}")
    if model == "pinhole" and distortion_coefficients not in (4, 5, 8):
        raise ConfigError(f"pinhole distortion needs 4, 5 or 8 coefficients, got {distortion_coefficients}")
    if not images:
        raise ConfigError("no images given")
    names: list[str] = []
    dets: list[BoardDetection] = []
    skipped: list[tuple[str, str]] = []
    size: tuple[int, int] | None = None
    for k, src in enumerate(images):
        name, img, why = _load(src, k)
        if progress:
            progress(k + 1, len(images))
        if img is None:
            skipped.append((name, why))
            log.warning("%s: skipped (%s)", name, why)
            continue
        wh = (int(img.shape[1]), int(img.shape[0]))
        if size is None:
            size = wh
        elif wh != size:
            raise ConfigError(f"{name}: image is {wh[0]}x{wh[1]}, the first was {size[0]}x{size[1]}; "
                              "calibrate one camera (one image size) at a time")
        det = detect_board(img, spec)
        if det is None or len(det) < spec.min_points:
            skipped.append((name, f"board {spec} not found"))
            log.info("%s: board %s not found; skipped", name, spec)  # counted in the result
            continue
        names.append(name)
        dets.append(det)
    if len(dets) < MIN_IMAGES:
        raise ConfigError(f"board {spec} found in {len(dets)} of {len(images)} images; need at least "
                          f"{MIN_IMAGES} (check the board SPEC: inner corners for a chessboard, squares for ChArUco)")
    assert size is not None
    obj = [d.object_points.astype(np.float32).reshape(-1, 1, 3) for d in dets]
    img_pts = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in dets]
    w, h = size
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)
    try:
        if model == "pinhole":
            flags = 0
            if distortion_coefficients == 4:
                flags |= cv2.CALIB_FIX_K3
            if distortion_coefficients == 8:
                flags |= cv2.CALIB_RATIONAL_MODEL
            if fix_aspect_ratio:
                flags |= cv2.CALIB_FIX_ASPECT_RATIO
            if zero_tangential:
                flags |= cv2.CALIB_ZERO_TANGENT_DIST
            K0 = np.eye(3)
            rms, K_cv, D, rvecs, tvecs = cv2.calibrateCamera(obj, img_pts, size, K0, None, flags=flags,
                                                            criteria=criteria)
            D = np.asarray(D, dtype=np.float64).ravel()[: distortion_coefficients]
        else:
            flags = _fisheye_flag("RECOMPUTE_EXTRINSIC") | _fisheye_flag("FIX_SKEW")
            rms, K_cv, D, rvecs, tvecs = cv2.fisheye.calibrate(
                [o.reshape(1, -1, 3).astype(np.float64) for o in obj],
                [p.reshape(1, -1, 2).astype(np.float64) for p in img_pts], size, np.eye(3), np.zeros(4),
                flags=flags, criteria=criteria)
            D = np.asarray(D, dtype=np.float64).ravel()
    except cv2.error as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "failed"
        raise ConfigError(f"calibration did not converge ({msg}); use more images with the board "
                          "at different angles, or another camera model") from None
    K = np.asarray(K_cv, dtype=np.float64)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise ConfigError("calibration gave a non-finite camera matrix; use more images at different angles")
    intr = CameraIntrinsics(w, h, K, D, model)
    reports = []
    poses = []
    sq_sum, n_sum = 0.0, 0
    for name, o, p, r, t in zip(names, obj, img_pts, rvecs, tvecs):
        if model == "fisheye":
            proj, _ = cv2.fisheye.projectPoints(o.reshape(1, -1, 3).astype(np.float64), r, t, K, D)
        else:
            proj, _ = cv2.projectPoints(o.astype(np.float64), r, t, K, D)
        e2 = np.sum((proj.reshape(-1, 2) - p.reshape(-1, 2)) ** 2, axis=1)
        reports.append(ImageReport(name, int(len(e2)), float(math.sqrt(e2.mean()))))
        sq_sum += float(e2.sum())
        n_sum += len(e2)
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(np.asarray(r, dtype=np.float64))[0]
        T[:3, 3] = np.asarray(t, dtype=np.float64).ravel()
        poses.append(T)
    overall = math.sqrt(sq_sum / max(n_sum, 1))
    log.info("intrinsics from %d images: RMS %.3f px (OpenCV reports %.3f)", len(reports), overall, rms)
    return IntrinsicsCalibration(intr, overall, tuple(reports), tuple(skipped), spec, tuple(poses))
