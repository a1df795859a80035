"""Calibration: camera intrinsics, ``T_cam_lidar`` (LiDAR points into the camera), and checks.

``T_cam_lidar`` maps points in the LiDAR frame into the camera optical frame
(``p_cam = T_cam_lidar @ p_lidar``); ``T_lidar_cam`` is its inverse. The research this
project implements printed ``T_C→L`` (camera into LiDAR, our ``T_lidar_cam``) and inverted it
to project points (its eq. 5); semmap writes both, named.

* :func:`calibrate_intrinsics`: board images → :class:`~semmap.records.CameraIntrinsics` + errors.
* :func:`calibrate_from_pairs`: manual LiDAR-point ↔ pixel pairs (Hong et al.) → ``T_cam_lidar``.
* :func:`calibrate_target`: board planes + scan lines (Zhang & Pless) → ``T_cam_lidar``.
* :func:`check_calibration`: the scan drawn on the image, coloured by range.
* :mod:`semmap.calib.workflow`: the same on files, as ``semmap calibrate`` runs them.
"""

from .boards import BoardDetection, BoardSpec, detect_board, parse_board_spec
from .check import CheckResult, check_calibration, draw_scan_on_image
from .common import pose_error
from .extrinsics import PairsCalibration, calibrate_from_pairs
from .intrinsics import IntrinsicsCalibration, calibrate_intrinsics
from .pairs import PointPixelPairs, read_pairs, write_pairs
from .scans import read_scan_points
from .target import BoardPlane, TargetCalibration, TargetObservation, board_plane, calibrate_target
from .workflow import calibrate_extrinsics_file, calibrate_intrinsics_file, calibrate_target_files

__all__ = [
    "BoardDetection",
    "BoardPlane",
    "BoardSpec",
    "CheckResult",
    "IntrinsicsCalibration",
    "PairsCalibration",
    "PointPixelPairs",
    "TargetCalibration",
    "TargetObservation",
    "board_plane",
    "calibrate_extrinsics_file",
    "calibrate_from_pairs",
    "calibrate_intrinsics",
    "calibrate_intrinsics_file",
    "calibrate_target",
    "calibrate_target_files",
    "check_calibration",
    "detect_board",
    "draw_scan_on_image",
    "parse_board_spec",
    "pose_error",
    "read_pairs",
    "read_scan_points",
    "write_pairs",
]
