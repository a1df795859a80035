"""The calibration file: camera intrinsics and the LiDAR→camera extrinsic, as YAML.

.. code-block:: yaml

    camera_frame: camera_optical_frame
    lidar_frame: laser
    intrinsics:
      model: pinhole            # or fisheye
      width: 640
      height: 480
      K: [[601.8, 0, 328.17], [0, 600.12, 240.45], [0, 0, 1]]
      D: [0, 0, 0, 0, 0]        # OpenCV order; fisheye: k1 k2 k3 k4
    T_cam_lidar:                # p_cam = T_cam_lidar @ p_lidar
      - [...4 values...]
    T_lidar_cam: ...            # optional; the inverse, checked if present
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..records import Calibration, CameraIntrinsics
from .yamlio import read_yaml, write_yaml

__all__ = ["write_calibration", "read_calibration", "calibration_to_dict", "calibration_from_dict"]


def calibration_to_dict(calib: Calibration, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    intr = calib.intrinsics

    def rows(m: np.ndarray) -> list[list[float]]:
        return [[round(float(v), 10) for v in r] for r in m]

    out: dict[str, Any] = {
        "camera_frame": calib.camera_frame,
        "lidar_frame": calib.lidar_frame,
        "intrinsics": {
            "model": intr.model,
            "width": intr.width,
            "height": intr.height,
            "K": rows(intr.K),
            "D": [float(v) for v in intr.D],
        },
        "T_cam_lidar": rows(calib.T_cam_lidar),
        "T_lidar_cam": rows(calib.T_lidar_cam),
    }
    if extra:
        out.update(extra)
    return out


def write_calibration(path: str | Path, calib: Calibration, extra: dict[str, Any] | None = None) -> Path:
    header = ("# semmap calibration. T_cam_lidar maps LiDAR-frame points into the camera optical frame\n"
              "# (p_cam = T_cam_lidar @ p_lidar); T_lidar_cam is its inverse.\n")
    return write_yaml(path, calibration_to_dict(calib, extra), header)


def calibration_from_dict(data: Any, source: str) -> Calibration:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a calibration file must be a mapping")
    try:
        intr_d = data["intrinsics"]
        intr = CameraIntrinsics(
            width=int(intr_d["width"]),
            height=int(intr_d["height"]),
            K=np.asarray(intr_d["K"], dtype=np.float64),
            D=np.asarray(intr_d.get("D", [0.0] * 5), dtype=np.float64),
            model=str(intr_d.get("model", "pinhole")),  # type: ignore[arg-type]
        )
    except KeyError as exc:
        raise ConfigError(f"{source}: intrinsics: missing key {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: intrinsics: {exc}") from None
    if "T_cam_lidar" not in data:
        raise ConfigError(f"{source}: missing T_cam_lidar (the transform mapping LiDAR points into the camera)")
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
