"""Calibration: camera intrinsics, LiDAR-camera extrinsics and checks."""
