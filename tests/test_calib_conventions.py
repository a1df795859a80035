"""The calibration file and the transform names: T_cam_lidar maps LiDAR points into the camera."""

import copy

import numpy as np
import pytest
import yaml
from file_errors import DROP, assert_one_line_error, set_key

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


ROS_INFO = {"image_width": 640, "image_height": 480, "camera_name": "front",
            "camera_matrix": {"rows": 3, "cols": 3, "data": [519.3, 0, 331.1, 0, 518.9, 229.4, 0, 0, 1]},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.114, 0.193, -0.0027, 0.0037, -1.095]}}


_NOT_RIGID = [[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
_FAR = [[1.0, 0, 0, 420.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


@pytest.mark.parametrize("key, value, message", [
    ("intrinsics.width", 640.5, "intrinsics.width: must be a whole number of pixels, got 640.5"),
    ("intrinsics.height", 0, "intrinsics.height: must be between 1 and 100000 pixels, got 0"),
    ("intrinsics.height", "480", "intrinsics.height: must be a whole number of pixels"),
    ("intrinsics.model", "kannala", "intrinsics.model: Input should be 'pinhole' or 'fisheye'"),
    ("intrinsics.K", [[600.0, 0, 320], [0, 600, 240]], r"intrinsics.K: must be a 3x3 matrix, got shape \(2, 3\)"),
    ("intrinsics.K", [[-600.0, 0, 320], [0, 600, 240], [0, 0, 1]], "intrinsics: K must have positive focal lengths"),
    ("intrinsics.K", DROP, "intrinsics.K: Field required"),
    ("intrinsics.D", [0.1, 0.0, 0.0], "intrinsics: pinhole distortion needs 4, 5, 8, 12 or 14 coefficients, got 3"),
    ("intrinsics.D", "none", "intrinsics.D: must be a list of numbers, got str"),
    ("intrinsics", [640, 480], r"intrinsics: must be a mapping \(model, width, height, K, D\)"),
    ("T_cam_lidar", [[1.0, 0, 0], [0, 1, 0], [0, 0, 1]], r"T_cam_lidar: must be a 4x4 matrix, got shape \(3, 3\)"),
    ("T_cam_lidar", _NOT_RIGID, r"T_cam_lidar rotation is not orthonormal with det \+1"),
    ("T_cam_lidar", _FAR, r"T_cam_lidar: the camera is 420 m from the LiDAR, more than 10 m"),
    ("T_lidar_cam", _FAR, "T_lidar_cam is not the inverse of T_cam_lidar"),
    ("T_lidar_cam", "inverse", "T_lidar_cam: must be a list of numbers, got str"),
    ("camera_frame", "", "camera_frame: must be a frame name, got ''"),
    ("lidar_frame", 7, "lidar_frame: must be a frame name, got 7"),
])
def test_a_bad_field_of_a_calibration_file_is_one_line_naming_the_file_and_the_field(tmp_path, key, value, message):
    good = write_calibration(tmp_path / "good.yaml", Calibration(sim_intrinsics(), sim_calibration_truth()))
    data = yaml.safe_load(good.read_text())
    if key == "T_cam_lidar" and value is _FAR:
        del data["T_lidar_cam"]
    set_key(data, key, value)
    assert_one_line_error(read_calibration, tmp_path / "calibration.yaml", message, data)


@pytest.mark.parametrize("key, value, message", [
    ("image_width", DROP, "image_width: Field required"),
    ("image_height", 1e6, "image_height: must be between 1 and 100000 pixels"),
    ("camera_matrix.data", [519.3, 0, 331.1, 0, 518.9, 229.4, 0, 1], "camera_matrix.data: must have 9 numbers, got 8"),
    ("camera_matrix", [519.3, 0, 331.1], r"camera_matrix: must be a mapping \(with 'data'\)"),
    ("distortion_model", "kb4", "distortion_model: Input should be 'plumb_bob', 'rational_polynomial' or "
                                "'equidistant'"),
    ("distortion_model", "equidistant", "camera info: fisheye distortion needs 4 coefficients, got 5"),
    ("distortion_coefficients.data", [0.1, "x", 0, 0, 0], "distortion_coefficients.data: must be a list of numbers"),
])
def test_a_bad_field_of_a_ros_camera_info_file_is_one_line_naming_the_file_and_the_field(tmp_path, key, value,
                                                                                          message):
    data = copy.deepcopy(ROS_INFO)
    set_key(data, key, value)
    assert_one_line_error(read_intrinsics, tmp_path / "ost.yaml", message, data)


def test_unknown_keys_and_defaults_of_a_calibration_file(tmp_path):
    """A newer file's keys are ignored (top level and in ``intrinsics``); D and the frames have defaults."""
    calib = Calibration(sim_intrinsics(), sim_calibration_truth(), camera_frame="cam", lidar_frame="front_laser")
    path = write_calibration(tmp_path / "calibration.yaml", calib, {"extrinsics": {"rms_m": 0.01}}, {"rms_px": 0.2})
    data = yaml.safe_load(path.read_text())
    data["written_by"] = {"semmap": "9.9"}
    data["intrinsics"]["lens"] = "wide"
    path.write_text(yaml.safe_dump(data))
    back = read_calibration(path)
    assert (back.camera_frame, back.lidar_frame) == ("cam", "front_laser")
    assert np.allclose(back.T_cam_lidar, calib.T_cam_lidar, atol=1e-9)
    assert np.allclose(back.intrinsics.K, calib.intrinsics.K)
    assert read_intrinsics_report(path) == {"rms_px": 0.2, "lens": "wide"}

    for key in ("camera_frame", "lidar_frame", "intrinsics.D", "T_lidar_cam"):
        set_key(data, key, DROP)
    data["intrinsics"]["model"] = "fisheye"
    path.write_text(yaml.safe_dump(data))
    back = read_calibration(path)
    assert (back.camera_frame, back.lidar_frame) == ("camera_optical_frame", "laser")
    assert back.intrinsics.model == "fisheye" and back.intrinsics.D.tolist() == [0.0] * 4
