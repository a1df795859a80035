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
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainValidator,
    PrivateAttr,
    ValidationInfo,
    field_validator,
    model_validator,
)

from ..config import load_model
from ..errors import ConfigError
from ..records import Calibration, CameraIntrinsics
from .yamlio import read_yaml, write_yaml

__all__ = [
    "CalibrationFile",
    "CameraFile",
    "IntrinsicsFile",
    "RosCameraInfoFile",
    "calibration_from_dict",
    "calibration_to_dict",
    "intrinsics_from_dict",
    "intrinsics_to_dict",
    "read_calibration",
    "read_intrinsics",
    "read_intrinsics_report",
    "write_calibration",
    "write_intrinsics",
]

_MAX_IMAGE_PX = 100_000  # wider or taller than any camera: a wrong number, not a camera
_MAX_BASELINE_M = 10.0  # LiDAR and camera sit on one robot: further apart is a unit error (millimetres?)


# ---------------------------------------------------------------------------------------
# The file schemas. Pydantic turns a ValueError raised here into one line naming the file and the
# field (semmap.config.load_model); the records (CameraIntrinsics, Calibration) check what any
# camera and transform must satisfy (finite numbers, K's form, D's length for the model, a rigid
# T_cam_lidar), and their message names the field.


def _pixels(v: Any) -> int:
    """An image size: a whole, positive number of pixels."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ValueError(f"must be a whole number of pixels, got {v!r}")
    if isinstance(v, float):
        if not (math.isfinite(v) and v.is_integer()):
            raise ValueError(f"must be a whole number of pixels, got {v!r}")
        v = int(v)
    if not 0 < v <= _MAX_IMAGE_PX:
        raise ValueError(f"must be between 1 and {_MAX_IMAGE_PX} pixels, got {v}")
    return v


def _numbers(v: Any) -> NDArray[np.float64]:
    """A (nested) list of numbers as a float array; strings, mappings, null and ragged lists are errors."""
    if isinstance(v, str | bytes | dict) or v is None:
        raise ValueError(f"must be a list of numbers, got {type(v).__name__}")
    try:
        return np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError("must be a list of numbers (rows of equal length)") from None


def _frame(v: Any) -> str:
    if not isinstance(v, str) or not v:
        raise ValueError(f"must be a frame name, got {v!r}")
    return v


def _mapping(keys: str) -> Any:
    def check(v: Any) -> Any:
        if not isinstance(v, dict | BaseModel):
            raise ValueError(f"must be a mapping ({keys})")
        return v

    return check


def _shape(rows: int, cols: int) -> Any:
    def check(a: NDArray[np.float64]) -> NDArray[np.float64]:
        if a.shape != (rows, cols):
            raise ValueError(f"must be a {rows}x{cols} matrix, got shape {a.shape}")
        return a

    return check


Pixels = Annotated[int, BeforeValidator(_pixels)]
Numbers = Annotated[NDArray[np.float64], PlainValidator(_numbers)]
FrameName = Annotated[str, BeforeValidator(_frame)]


class _FileModel(BaseModel):
    # Unknown keys (reports, keys of newer files) are ignored: older readers read newer files.
    model_config = ConfigDict(extra="ignore", frozen=True)


def _default_distortion(data: dict[str, Any]) -> NDArray[np.float64]:
    return np.zeros(4 if data.get("model") == "fisheye" else 5)


class IntrinsicsFile(_FileModel):
    """The ``intrinsics`` mapping: the camera model, image size, ``K`` and ``D`` (OpenCV order)."""

    model: Literal["pinhole", "fisheye"] = "pinhole"
    width: Pixels
    height: Pixels
    K: Annotated[Numbers, Field(description="3x3 camera matrix, pixels")]
    D: Numbers = Field(default_factory=_default_distortion, description="distortion; default none")
    _camera: CameraIntrinsics = PrivateAttr()

    _K_3x3 = field_validator("K")(_shape(3, 3))

    @model_validator(mode="after")
    def _record(self) -> IntrinsicsFile:
        self._camera = CameraIntrinsics(self.width, self.height, self.K, self.D, self.model)
        return self

    @property
    def camera(self) -> CameraIntrinsics:
        return self._camera


class CameraFile(_FileModel):
    """A file holding the camera only (``semmap calibrate intrinsics``): ``T_cam_lidar`` may be missing."""

    intrinsics: Annotated[IntrinsicsFile, BeforeValidator(_mapping("model, width, height, K, D"))]


class CalibrationFile(CameraFile):
    """A calibration file: the camera, ``T_cam_lidar`` and the frames it joins."""

    camera_frame: FrameName = "camera_optical_frame"
    lidar_frame: FrameName = "laser"
    T_cam_lidar: Annotated[Numbers, Field(description="4x4, p_cam = T_cam_lidar @ p_lidar")]
    T_lidar_cam: Annotated[NDArray[np.float64] | None, PlainValidator(_numbers),
                           Field(description="optional: the inverse, checked")] = None
    _calibration: Calibration = PrivateAttr()

    _T_4x4 = field_validator("T_cam_lidar")(_shape(4, 4))

    @field_validator("camera_frame", "lidar_frame", mode="before")
    @classmethod
    def _null_is_default(cls, v: Any, info: ValidationInfo) -> Any:
        return cls.model_fields[str(info.field_name)].default if v is None else v

    @model_validator(mode="before")
    @classmethod
    def _has_T_cam_lidar(cls, data: Any) -> Any:
        if isinstance(data, dict) and "T_cam_lidar" not in data:
            if "T_lidar_cam" in data:
                raise ValueError("has T_lidar_cam but no T_cam_lidar; write T_cam_lidar (LiDAR points into the "
                                 "camera), its inverse")
            raise ValueError("missing T_cam_lidar (the transform mapping LiDAR points into the camera); a "
                             "camera-only file from `semmap calibrate intrinsics` needs `semmap calibrate "
                             "extrinsics` or `semmap calibrate target` first")
        return data

    @model_validator(mode="after")
    def _record(self) -> CalibrationFile:
        calib = Calibration(self.intrinsics.camera, self.T_cam_lidar, self.camera_frame, self.lidar_frame)
        baseline = float(np.linalg.norm(calib.T_cam_lidar[:3, 3]))
        if baseline > _MAX_BASELINE_M:
            raise ValueError(f"T_cam_lidar: the camera is {baseline:.4g} m from the LiDAR, more than "
                             f"{_MAX_BASELINE_M:g} m; translations are in metres (millimetres written as metres?)")
        inv = self.T_lidar_cam
        if inv is not None and (inv.shape != (4, 4) or not np.allclose(inv @ calib.T_cam_lidar, np.eye(4),
                                                                       atol=1e-6)):
            raise ValueError("T_lidar_cam is not the inverse of T_cam_lidar")
        self._calibration = calib
        return self

    @property
    def calibration(self) -> Calibration:
        return self._calibration


class _RosMatrix(_FileModel):
    data: Numbers


class _RosCameraMatrix(_RosMatrix):
    @field_validator("data")
    @classmethod
    def _nine(cls, v: NDArray[np.float64]) -> NDArray[np.float64]:
        if v.size != 9:
            raise ValueError(f"must have 9 numbers, got {v.size}")
        return v.reshape(3, 3)


class _RosDistortion(_RosMatrix):
    data: Numbers = Field(default_factory=lambda: np.zeros(5))


class RosCameraInfoFile(_FileModel):
    """ROS ``camera_calibration`` YAML (what ``cameracalibrator`` writes)."""

    image_width: Pixels
    image_height: Pixels
    camera_matrix: Annotated[_RosCameraMatrix, BeforeValidator(_mapping("with 'data'"))]
    distortion_model: Literal["plumb_bob", "rational_polynomial", "equidistant"] = "plumb_bob"
    distortion_coefficients: Annotated[_RosDistortion, BeforeValidator(_mapping("with 'data'")),
                                       BeforeValidator(lambda v: v or {})] = Field(default_factory=_RosDistortion)
    _camera: CameraIntrinsics = PrivateAttr()

    @model_validator(mode="after")
    def _record(self) -> RosCameraInfoFile:
        try:
            self._camera = CameraIntrinsics(self.image_width, self.image_height, self.camera_matrix.data,
                                            self.distortion_coefficients.data,
                                            "fisheye" if self.distortion_model == "equidistant" else "pinhole")
        except ValueError as exc:
            raise ValueError(f"camera info: {exc}") from None
        return self

    @property
    def camera(self) -> CameraIntrinsics:
        return self._camera


_INTRINSICS_KEYS = tuple(IntrinsicsFile.model_fields)


def _load(model: type[_FileModel], data: Any, source: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a calibration file must be a mapping")
    return load_model(model, data, source)


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


def intrinsics_from_dict(data: Any, source: str) -> CameraIntrinsics:
    """The camera from a semmap calibration mapping (with or without ``T_cam_lidar``) or a ROS
    camera-info mapping."""
    if isinstance(data, dict) and "intrinsics" not in data and "camera_matrix" in data:
        return _load(RosCameraInfoFile, data, source).camera
    return _load(CameraFile, data, source).intrinsics.camera


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
    return _load(CalibrationFile, data, source).calibration


def read_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; every error names the file and the field."""
    return calibration_from_dict(_read(path), str(path))
