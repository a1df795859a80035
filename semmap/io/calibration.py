"""The calibration file: camera intrinsics and ``T_cam_lidar`` (LiDAR points into the camera), as YAML.

.. code-block:: yaml

    camera_frame: camera_optical_frame
    lidar_frame: laser
    intrinsics:
      model: pinhole            # or fisheye
      width: 640
      height: 480
      K: [[601.8, 0, 328.17], [0, 600.12, 240.45], [0, 0, 1]]
      D: [0, 0, 0, 0, 0]        # OpenCV order; fisheye: k1 k2 k3 k4
      rms_px: 0.21              # optional, from `semmap calibrate intrinsics` (with board, images, skipped)
    T_cam_lidar:                # p_cam = T_cam_lidar @ p_lidar
      - [...4 values...]
    T_lidar_cam: ...            # optional; the inverse, checked if present
    extrinsics: {...}           # optional: how T_cam_lidar was found and how well it fits

A file written by ``semmap calibrate intrinsics`` has no ``T_cam_lidar`` yet: read it with
:func:`read_intrinsics`. :func:`read_intrinsics` also reads ROS ``camera_calibration`` YAML
(``camera_matrix``, ``distortion_coefficients``, ``image_width``...). Unknown keys are kept
out of the records and ignored, so older readers read newer files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..records import Calibration, CameraIntrinsics
from .yamlio import read_yaml, write_yaml

__all__ = [
    "write_calibration",
    "read_calibration",
    "calibration_to_dict",
    "calibration_from_dict",
    "intrinsics_to_dict",
    "intrinsics_from_dict",
    "write_intrinsics",
    "read_intrinsics",
    "read_intrinsics_report",
]

_INTRINSICS_KEYS = ("model", "width", "height", "K", "D")


def _num(v: float) -> float:
    r = round(float(v), 10)
    return 0.0 if abs(r) < 1e-9 else r


def _rows(m: np.ndarray) -> list[list[float]]:
    return [[_num(v) for v in r] for r in m]


def intrinsics_to_dict(intr: CameraIntrinsics, report: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``intrinsics`` mapping; ``report`` (RMS, per-image errors...) is appended after K and D."""
    out: dict[str, Any] = {
        "model": intr.model,
        "width": intr.width,
        "height": intr.height,
        "K": _rows(intr.K),
        "D": [float(v) for v in intr.D],
    }
    for k, v in (report or {}).items():
        if k not in _INTRINSICS_KEYS:
            out[k] = v
    return out


def calibration_to_dict(calib: Calibration, extra: dict[str, Any] | None = None,
                        intrinsics_report: dict[str, Any] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {
        "camera_frame": calib.camera_frame,
        "lidar_frame": calib.lidar_frame,
        "intrinsics": intrinsics_to_dict(calib.intrinsics, intrinsics_report),
        "T_cam_lidar": _rows(calib.T_cam_lidar),
        "T_lidar_cam": _rows(calib.T_lidar_cam),
    }
    if extra:
        out.update(extra)
    return out


def write_calibration(path: str | Path, calib: Calibration, extra: dict[str, Any] | None = None,
                      intrinsics_report: dict[str, Any] | None = None) -> Path:
    """Write a calibration file. ``extra`` adds top-level keys (e.g. an ``extrinsics`` report);
    ``intrinsics_report`` adds keys to the ``intrinsics`` mapping (e.g. ``rms_px``)."""
    header = ("# semmap calibration. T_cam_lidar maps LiDAR-frame points into the camera optical frame\n"
              "# (p_cam = T_cam_lidar @ p_lidar); T_lidar_cam is its inverse.\n")
    return write_yaml(path, calibration_to_dict(calib, extra, intrinsics_report), header)


def write_intrinsics(path: str | Path, intrinsics: CameraIntrinsics, report: dict[str, Any] | None = None,
                     camera_frame: str = "camera_optical_frame") -> Path:
    """Write a calibration file holding only the camera (no ``T_cam_lidar`` yet)."""
    header = ("# semmap calibration: camera intrinsics only. Add T_cam_lidar (LiDAR points into the camera)\n"
              "# with `semmap calibrate extrinsics` or `semmap calibrate target`.\n")
    data = {"camera_frame": camera_frame, "intrinsics": intrinsics_to_dict(intrinsics, report)}
    return write_yaml(path, data, header)


def _ros_camera_info(data: dict[str, Any], source: str) -> CameraIntrinsics:
    """ROS ``camera_calibration`` YAML (what ``cameracalibrator`` writes)."""
    try:
        K = np.asarray(data["camera_matrix"]["data"], dtype=np.float64).reshape(3, 3)
        D = np.asarray(data.get("distortion_coefficients", {}).get("data", [0.0] * 5), dtype=np.float64)
        model = str(data.get("distortion_model", "plumb_bob"))
        if model not in ("plumb_bob", "rational_polynomial", "equidistant"):
            raise ConfigError(f"{source}: distortion_model {model!r} is not supported "
                              "(plumb_bob, rational_polynomial or equidistant)")
        return CameraIntrinsics(int(data["image_width"]), int(data["image_height"]), K, D,
                                "fisheye" if model == "equidistant" else "pinhole")
    except KeyError as exc:
        raise ConfigError(f"{source}: camera info: missing key {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: camera info: {exc}") from None


def intrinsics_from_dict(data: Any, source: str) -> CameraIntrinsics:
    """The camera from a semmap calibration mapping (with or without ``T_cam_lidar``) or a ROS
    camera-info mapping."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a calibration file must be a mapping")
    if "intrinsics" not in data and "camera_matrix" in data:
        return _ros_camera_info(data, source)
    try:
        intr_d = data["intrinsics"]
        return CameraIntrinsics(
            width=int(intr_d["width"]),
            height=int(intr_d["height"]),
            K=np.asarray(intr_d["K"], dtype=np.float64),
            D=np.asarray(intr_d.get("D", [0.0] * 5), dtype=np.float64),
            model=str(intr_d.get("model", "pinhole")),  # type: ignore[arg-type]
        )
    except KeyError as exc:
        raise ConfigError(f"{source}: intrinsics: missing key {exc}") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise ConfigError(f"{source}: intrinsics: {exc}") from None


def read_intrinsics(path: str | Path) -> CameraIntrinsics:
    """The camera of any calibration file (also one without ``T_cam_lidar``, or ROS camera-info YAML)."""
    return intrinsics_from_dict(read_yaml(path, "calibration"), str(path))


def read_intrinsics_report(path: str | Path) -> dict[str, Any]:
    """The optional keys of a file's ``intrinsics`` mapping (``rms_px``, ``board``, ``images``...)."""
    data = read_yaml(path, "calibration")
    intr = data.get("intrinsics") if isinstance(data, dict) else None
    if not isinstance(intr, dict):
        return {}
    return {k: v for k, v in intr.items() if k not in _INTRINSICS_KEYS}


def calibration_from_dict(data: Any, source: str) -> Calibration:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a calibration file must be a mapping")
    if "intrinsics" not in data:
        raise ConfigError(f"{source}: intrinsics: missing key 'intrinsics'")
    intr = intrinsics_from_dict(data, source)
    if "T_cam_lidar" not in data:
        if "T_lidar_cam" in data:
            raise ConfigError(f"{source}: has T_lidar_cam but no T_cam_lidar; write T_cam_lidar "
                              "(LiDAR points into the camera), its inverse")
        raise ConfigError(f"{source}: missing T_cam_lidar (the transform mapping LiDAR points into the camera); "
                          "a camera-only file from `semmap calibrate intrinsics` needs `semmap calibrate "
                          "extrinsics` or `semmap calibrate target` first")
    try:
        calib = Calibration(
            intrinsics=intr,
            T_cam_lidar=np.asarray(data["T_cam_lidar"], dtype=np.float64),
            camera_frame=str(data.get("camera_frame", "camera_optical_frame")),
            lidar_frame=str(data.get("lidar_frame", "laser")),
        )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: T_cam_lidar: {exc}") from None
    if "T_lidar_cam" in data:
        inv = np.asarray(data["T_lidar_cam"], dtype=np.float64)
        if inv.shape != (4, 4) or not np.allclose(inv @ calib.T_cam_lidar, np.eye(4), atol=1e-6):
            raise ConfigError(f"{source}: T_lidar_cam is not the inverse of T_cam_lidar")
    return calib


def read_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; every error names the file and the field."""
    return calibration_from_dict(read_yaml(path, "calibration"), str(path))
