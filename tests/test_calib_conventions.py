"""The calibration file and the transform names: T_cam_lidar maps LiDAR points into the camera."""

import numpy as np
import pytest

from semmap.calib.synth import sim_calibration_truth, sim_intrinsics
from semmap.errors import ConfigError
from semmap.geometry import project_points
from semmap.io.calibration import (
    read_calibration,
    read_intrinsics,
    read_intrinsics_report,
    write_calibration,
    write_intrinsics,
)
from semmap.records import Calibration


def test_eq5_inverting_the_published_camera_to_lidar_transform(tmp_path):
    """The research printed ``R_C→L`` and ``t_C→L`` (camera points into the LiDAR frame) and
    projected LiDAR points with the inverse (its eq. 5): ``p_C = R_C→Lᵀ (p_L − t_C→L)``.

    The paper's published numbers are not available to this project, so the stand-in here is
    the simulator's sensor layout (LiDAR on the front-left corner yawed 45°, camera at the front
    centre): ``R_C→L, t_C→L`` = its ``T_lidar_cam``. The published values would replace
    ``R_CL`` and ``t_CL`` below unchanged; the checks are the same.
    """
    T_CL = np.linalg.inv(sim_calibration_truth())  # stand-in for the published T_C→L
    R_CL, t_CL = T_CL[:3, :3], T_CL[:3, 3]
    # eq. 5: T_L→C = [R_C→Lᵀ | −R_C→Lᵀ t_C→L]
    T_LC = np.eye(4)
    T_LC[:3, :3] = R_CL.T
    T_LC[:3, 3] = -R_CL.T @ t_CL

    calib = Calibration(sim_intrinsics(), T_cam_lidar=T_LC)
    assert np.allclose(calib.T_cam_lidar, T_LC, atol=1e-12)  # T_cam_lidar is the research's T_L→C
    assert np.allclose(calib.T_lidar_cam, T_CL, atol=1e-12)  # and T_lidar_cam its printed T_C→L

    # a wall point 2 m ahead of the robot, seen by both sensors
    p_lidar = np.array([[1.2, -1.3, 0.0]])
    p_cam_eq5 = (R_CL.T @ (p_lidar[0] - t_CL))[None]
    p_cam = p_lidar @ calib.T_cam_lidar[:3, :3].T + calib.T_cam_lidar[:3, 3]
    assert np.allclose(p_cam, p_cam_eq5, atol=1e-12)
    intr = calib.intrinsics
    _uv, inside = project_points(intr.K, intr.D, p_cam, intr.width, intr.height)
    assert inside[0]

    # the file writes both directions, named, and reads back the same
    path = write_calibration(tmp_path / "calibration.yaml", calib)
    text = path.read_text()
    assert "T_cam_lidar:" in text and "T_lidar_cam:" in text
    back = read_calibration(path)
    assert np.allclose(back.T_cam_lidar, T_LC, atol=1e-9)
    assert np.allclose(back.T_lidar_cam, T_CL, atol=1e-9)


def test_a_file_holding_the_inverse_as_T_cam_lidar_is_caught(tmp_path):
    calib = Calibration(sim_intrinsics(), T_cam_lidar=sim_calibration_truth())
    path = write_calibration(tmp_path / "c.yaml", calib)
    text = path.read_text()
    # a user pastes T_C→L under T_cam_lidar but keeps the old T_lidar_cam: the pair no longer inverts
    lines = text.splitlines()
    i = lines.index("T_cam_lidar:")
    lines[i + 1] = "- [1.0, 0.0, 0.0, 0.5]"
    lines[i + 2] = "- [0.0, 1.0, 0.0, 0.0]"
    lines[i + 3] = "- [0.0, 0.0, 1.0, 0.0]"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError, match="c.yaml: T_lidar_cam is not the inverse of T_cam_lidar"):
        read_calibration(path)


def test_camera_only_file_roundtrip_and_clear_error_when_used_as_full_calibration(tmp_path):
    intr = sim_intrinsics()
    path = write_intrinsics(tmp_path / "camera.yaml", intr, {"rms_px": 0.21, "board": "chessboard:9x6:0.03"})
    back = read_intrinsics(path)
    assert np.allclose(back.K, intr.K) and back.model == "pinhole" and (back.width, back.height) == (640, 480)
    assert read_intrinsics_report(path) == {"rms_px": 0.21, "board": "chessboard:9x6:0.03"}
    with pytest.raises(ConfigError, match="camera.yaml: missing T_cam_lidar.*semmap calibrate extrinsics"):
        read_calibration(path)


def test_ros_camera_info_yaml_is_accepted_as_intrinsics(tmp_path):
    p = tmp_path / "ost.yaml"
    p.write_text("image_width: 640\nimage_height: 480\ncamera_name: front\n"
                 "camera_matrix: {rows: 3, cols: 3, data: [519.3, 0, 331.1, 0, 518.9, 229.4, 0, 0, 1]}\n"
                 "distortion_model: plumb_bob\n"
                 "distortion_coefficients: {rows: 1, cols: 5, data: [0.114, 0.193, -0.0027, 0.0037, -1.095]}\n")
    intr = read_intrinsics(p)
    assert intr.fx == pytest.approx(519.3) and intr.D[4] == pytest.approx(-1.095) and intr.model == "pinhole"
