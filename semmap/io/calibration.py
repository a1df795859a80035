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

import math
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
_MAX_IMAGE_PX = 100_000  # wider or taller than any camera: a wrong number, not a camera
_MAX_BASELINE_M = 10.0  # LiDAR and camera sit on one robot: further apart is a unit error (millimetres?)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _pixels(v: Any, name: str) -> int:
    """An image size: a whole, positive number of pixels."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise TypeError(f"{name} must be a whole number of pixels, got {v!r}")
    if isinstance(v, float):
        if not (math.isfinite(v) and v.is_integer()):
            raise ValueError(f"{name} must be a whole number of pixels, got {v!r}")
        v = int(v)
    if not 0 < v <= _MAX_IMAGE_PX:
        raise ValueError(f"{name} must be between 1 and {_MAX_IMAGE_PX} pixels, got {v}")
    return v


def _numbers(v: Any, name: str) -> np.ndarray:
    """A (nested) list of numbers as a float array; strings, mappings and ragged lists are errors."""
    if isinstance(v, str | bytes | dict) or v is None:
        raise TypeError(f"{name} must be a list of numbers, got {type(v).__name__}")
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a list of numbers (rows of equal length)") from None
    return a


def _frame(data: dict[str, Any], key: str, default: str) -> str:
    v = data.get(key)
    if v is None:
        return default
    if not isinstance(v, str) or not v:
        raise TypeError(f"{key} must be a frame name, got {v!r}")
    return v


def _read(path: str | Path) -> Any:
    return read_yaml(path, "calibration")


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
        cm = data["camera_matrix"]
        if not isinstance(cm, dict):
            raise TypeError("camera_matrix must be a mapping with 'data'")
        K = _numbers(cm["data"], "camera_matrix.data")
        if K.size != 9:
            raise ValueError(f"camera_matrix.data must have 9 numbers, got {K.size}")
        dc = data.get("distortion_coefficients") or {}
        if not isinstance(dc, dict):
            raise TypeError("distortion_coefficients must be a mapping with 'data'")
        D = _numbers(dc.get("data", [0.0] * 5), "distortion_coefficients.data")
        model = str(data.get("distortion_model", "plumb_bob"))
        if model not in ("plumb_bob", "rational_polynomial", "equidistant"):
            raise ConfigError(f"{source}: distortion_model {model!r} is not supported "
                              "(plumb_bob, rational_polynomial or equidistant)")
        return CameraIntrinsics(_pixels(data["image_width"], "image_width"),
                                _pixels(data["image_height"], "image_height"), K.reshape(3, 3), D,
                                "fisheye" if model == "equidistant" else "pinhole")
    except KeyError as exc:
        raise ConfigError(f"{source}: camera info: missing key {exc}") from None
    except (TypeError, ValueError, OverflowError) as exc:
        raise ConfigError(f"{source}: camera info: {_one_line(exc)}") from None


def intrinsics_from_dict(data: Any, source: str) -> CameraIntrinsics:
    """The camera from a semmap calibration mapping (with or without ``T_cam_lidar``) or a ROS
    camera-info mapping."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a calibration file must be a mapping")
    if "intrinsics" not in data and "camera_matrix" in data:
        return _ros_camera_info(data, source)
    try:
        intr_d = data["intrinsics"]
        if not isinstance(intr_d, dict):
            raise TypeError("must be a mapping (model, width, height, K, D)")
        model = intr_d.get("model", "pinhole")
        if model not in ("pinhole", "fisheye"):
            raise ValueError(f"model must be 'pinhole' or 'fisheye', got {model!r}")
        return CameraIntrinsics(
            width=_pixels(intr_d["width"], "width"),
            height=_pixels(intr_d["height"], "height"),
            K=_numbers(intr_d["K"], "K"),
            D=_numbers(intr_d.get("D", [0.0] * (4 if model == "fisheye" else 5)), "D"),
            model=model,
        )
    except KeyError as exc:
        raise ConfigError(f"{source}: intrinsics: missing key {exc}") from None
    except (TypeError, ValueError, AttributeError, OverflowError) as exc:
        raise ConfigError(f"{source}: intrinsics: {_one_line(exc)}") from None


def read_intrinsics(path: str | Path) -> CameraIntrinsics:
    """The camera of any calibration file (also one without ``T_cam_lidar``, or ROS camera-info YAML)."""
    return intrinsics_from_dict(_read(path), str(path))


def read_intrinsics_report(path: str | Path) -> dict[str, Any]:
    """The optional keys of a file's ``intrinsics`` mapping (``rms_px``, ``board``, ``images``...)."""
    data = _read(path)
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
        camera_frame = _frame(data, "camera_frame", "camera_optical_frame")
        lidar_frame = _frame(data, "lidar_frame", "laser")
    except TypeError as exc:
        raise ConfigError(f"{source}: {_one_line(exc)}") from None
    try:
        calib = Calibration(
            intrinsics=intr,
            T_cam_lidar=_numbers(data["T_cam_lidar"], "T_cam_lidar"),
            camera_frame=camera_frame,
            lidar_frame=lidar_frame,
        )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: T_cam_lidar: {_one_line(exc)}") from None
    baseline = float(np.linalg.norm(calib.T_cam_lidar[:3, 3]))
    if baseline > _MAX_BASELINE_M:
        raise ConfigError(f"{source}: T_cam_lidar: the camera is {baseline:.4g} m from the LiDAR, more than "
                          f"{_MAX_BASELINE_M:g} m; translations are in metres (millimetres written as metres?)")
    if "T_lidar_cam" in data:
        try:
            inv = _numbers(data["T_lidar_cam"], "T_lidar_cam")
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: {_one_line(exc)}") from None
        if inv.shape != (4, 4) or not np.allclose(inv @ calib.T_cam_lidar, np.eye(4), atol=1e-6):
            raise ConfigError(f"{source}: T_lidar_cam is not the inverse of T_cam_lidar")
    return calib


def read_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; every error names the file and the field."""
    return calibration_from_dict(_read(path), str(path))
