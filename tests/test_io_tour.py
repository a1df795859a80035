"""Reading tours the general way: message decoding, topic detection, transform chains."""

from types import SimpleNamespace as NS

import cv2
import numpy as np
import pytest

from semmap.config import BuildConfig
from semmap.errors import BagError
from semmap.geometry import se3_from_xyz_rpy
from semmap.io.messages import camera_info_from_msg, compressed_image_from_msg, image_from_msg
from semmap.io.tf import TfTree
from semmap.io.tour import resolve_topics


def _hdr(sec=5, nsec=7, frame="cam"):
    return NS(stamp=NS(sec=sec, nanosec=nsec), frame_id=frame)


def test_raw_images_with_row_padding_and_byte_order():
    rgb = np.arange(4 * 3 * 3, dtype=np.uint8).reshape(4, 3, 3)
    bgr = rgb[:, :, ::-1]
    padded = np.zeros((4, 12), np.uint8)  # step 12 > 9 bytes per row
    padded[:, :9] = bgr.reshape(4, 9)
    img = image_from_msg(NS(header=_hdr(), height=4, width=3, encoding="bgr8", is_bigendian=0, step=12,
                            data=padded.reshape(-1)))
    assert img.encoding == "rgb8" and np.array_equal(img.data, rgb)
    assert img.stamp_ns == 5_000_000_007
    lab = np.array([[1, 300], [65535, 0]], np.uint16)
    big = image_from_msg(NS(header=_hdr(), height=2, width=2, encoding="16UC1", is_bigendian=1, step=4,
                            data=lab.astype(">u2").view(np.uint8).reshape(-1)))
    assert np.array_equal(big.data, lab)


def test_jpeg_and_png_compressed_images():
    rgb = np.zeros((20, 30, 3), np.uint8)
    rgb[:, :15] = (200, 30, 30)
    _, jpg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    img = compressed_image_from_msg(NS(header=_hdr(), format="rgb8; jpeg compressed bgr8", data=jpg.reshape(-1)))
    assert img.encoding == "rgb8" and np.abs(img.data[5, 5].astype(int) - (200, 30, 30)).max() < 12
    lab = np.array([[0, 1], [2, 80]], np.uint8)
    _ok, png = cv2.imencode(".png", lab)
    img = compressed_image_from_msg(NS(header=_hdr(), format="mono8; png compressed", data=png.reshape(-1)))
    assert img.encoding == "mono8" and np.array_equal(img.data, lab)


def test_camera_info_ros1_and_ros2_field_names():
    k = [500.0, 0, 320, 0, 500, 240, 0, 0, 1]
    ros1 = NS(K=k, D=[0.1, 0, 0, 0, 0], width=640, height=480, distortion_model="plumb_bob")
    ros2 = NS(k=k, d=[0.1, 0, 0, 0], width=640, height=480, distortion_model="equidistant")
    assert camera_info_from_msg(ros1).K[0, 2] == 320 and camera_info_from_msg(ros1).model == "pinhole"
    assert camera_info_from_msg(ros2).model == "fisheye"


def test_transform_chain_through_a_full_tree():
    tree = TfTree()
    a = se3_from_xyz_rpy([0.0, 0.0, 0.1], [0, 0, 0])  # base_footprint -> base_link
    b = se3_from_xyz_rpy([0.3, 0.2, 0.15], [0, 0, 0.785])  # base_link -> laser_mount
    c = se3_from_xyz_rpy([0.0, 0.0, 0.05], [3.14159265, 0, 0])  # laser mounted upside down
    tree.add("base_footprint", "base_link", a)
    tree.add("base_link", "laser_mount", b)
    tree.add("laser_mount", "laser", c)
    tree.add("base_link", "camera_link", se3_from_xyz_rpy([0.4, 0, 0.5]))
    assert np.allclose(tree.lookup("base_footprint", "laser"), a @ b @ c)
    assert np.allclose(tree.lookup("camera_link", "laser"),
                       np.linalg.inv(se3_from_xyz_rpy([0.4, 0, 0.5])) @ b @ c)
    with pytest.raises(BagError, match="no transform"):
        tree.lookup("base_link", "imu")


TYPES = {
    "/front/scan": "sensor_msgs/msg/LaserScan",
    "/cam/color/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
    "/cam/segmentation/labels": "sensor_msgs/msg/Image",
    "/wheel/odom": "nav_msgs/msg/Odometry",
    "/ground_truth/odom": "nav_msgs/msg/Odometry",
    "/tf_static": "tf2_msgs/msg/TFMessage",
}


def test_topics_are_detected_when_unambiguous(tmp_path):
    t = resolve_topics(BuildConfig(), TYPES, tmp_path, {}, consumes="labels")
    assert (t.scan, t.odometry, t.image) == ("/front/scan", "/wheel/odom", "/cam/segmentation/labels")
    t = resolve_topics(BuildConfig(), TYPES, tmp_path, {}, consumes="rgb")
    assert t.image == "/cam/color/image_raw/compressed" and t.image_kind == "rgb"


def test_ambiguous_or_missing_topics_name_the_candidates(tmp_path):
    types = dict(TYPES, **{"/rear/scan": "sensor_msgs/msg/LaserScan"})
    with pytest.raises(BagError, match=r"several scan topics \(/front/scan, /rear/scan\).*topics.scan"):
        resolve_topics(BuildConfig(), types, tmp_path, {}, consumes="labels")
    cfg = BuildConfig.model_validate({"topics": {"scan": "/rear/scan", "odometry": "/odom"}})
    with pytest.raises(BagError, match="topic /odom"):
        resolve_topics(cfg, types, tmp_path, {}, consumes="labels")
    cfg = BuildConfig.model_validate({"topics": {"scan": "/rear/scan", "odometry": "none"}})
    assert resolve_topics(cfg, types, tmp_path, {}, consumes="labels").odometry is None


def test_segmentation_files_in_a_config_are_relative_to_it(tmp_path):
    from semmap.io.tour import load_build_config

    site = tmp_path / "site"
    site.mkdir()
    (site / "build.yaml").write_text("segmentation: {backend: folder, folder: labels}\n")
    cfg, _base = load_build_config(site / "build.yaml")
    assert cfg.segmentation.folder == site.resolve() / "labels"
    (site / "onnx.yaml").write_text("segmentation: {backend: onnx, model: m.onnx, cache_dir: /abs/cache}\n")
    onnx, _ = load_build_config(site / "onnx.yaml")
    assert onnx.segmentation.model == site.resolve() / "m.onnx"
    assert str(onnx.segmentation.cache_dir) == "/abs/cache"
    # a path given as an override (the command line) stays as given: relative to the working directory
    cfg, _ = load_build_config(site / "build.yaml", {"segmentation": {"folder": "other"}})
    assert str(cfg.segmentation.folder) == "other"
