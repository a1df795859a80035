"""One topic picker: `semmap build`, `semmap segment` and `semmap calibrate check` read the same camera
topic from the same bag, and an ambiguous bag is one error naming the candidates and the setting."""

from __future__ import annotations

import json

import numpy as np
import pytest

from semmap.cli.main import main
from semmap.config import PLUGIN_SEGMENTATION
from semmap.geometry import se3_from_xyz_rpy
from semmap.records import CameraIntrinsics, Image, Scan, Segmentation
from semmap.segment import base

W, H = 64, 48


class _Bright:
    """An RGB backend that labels bright pixels 1 (a person): which topic it read shows in its labels."""

    name = "test-bright"
    consumes = "rgb"
    names = ("person",)

    def __init__(self, cfg):
        self.cfg = cfg

    def segment(self, image):
        assert image.encoding == "rgb8"
        return Segmentation(image.stamp_ns, (image.data[:, :, 0] > 128).astype(np.uint16), self.names)

    def close(self):
        pass


@pytest.fixture
def bright_backend():
    base._load_backends()
    base.register("test-bright")(_Bright)
    yield _Bright
    base.SEGMENTERS.pop("test-bright", None)
    base.CONSUMES.pop("test-bright", None)
    PLUGIN_SEGMENTATION.pop("test-bright", None)


def _bag(path, cameras):
    """A 3 s ROS1 bag: scans of a room, and each of ``cameras`` (topic -> image kind) at 5 Hz, with a
    camera_info and /tf_static holding the camera's pose, so a build needs no calibration file. The
    colour camera's images are bright, the depth camera's dark: a label image says which was read."""
    from semmap.io.bag import BagWriter

    n = 181
    angles = np.linspace(-np.pi / 2, np.pi / 2, n)
    ranges = np.minimum(3.0 / np.maximum(np.abs(np.cos(angles)), 1e-3),
                        3.0 / np.maximum(np.abs(np.sin(angles)), 1e-3)).astype(np.float32)
    K = np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]])
    t0 = 100 * 1_000_000_000
    with BagWriter(path, "ros1") as w:
        T_base_laser = se3_from_xyz_rpy([0.1, 0, 0.2])
        T_laser_cam = se3_from_xyz_rpy([0.05, 0, 0.1], [-np.pi / 2, 0, -np.pi / 2])  # optical: z forward
        w.transforms("/tf_static", t0, [(t0, "base_link", "laser", T_base_laser), (t0, "laser", "camera", T_laser_cam)],
                     static=True)
        for k in range(30):
            t = t0 + k * 100_000_000
            w.scan("/scan", t, Scan(t, "laser", -np.pi / 2, np.pi / (n - 1), ranges, 0.05, 10.0, 0.0, 0.1))
            if k % 2 == 0:
                for topic, kind in cameras.items():
                    if kind == "rgb":
                        w.image(topic, t, Image(t, "camera", np.full((H, W, 3), 200, np.uint8), "rgb8"))
                    else:
                        w.image(topic, t, Image(t, "camera", np.full((H, W), 1500, np.uint16), "16UC1"))
                w.camera_info("/camera/camera_info", t, t, "camera", CameraIntrinsics(W, H, K))
    return path


def _calibration(path):
    from semmap.io.calibration import write_calibration
    from semmap.records import Calibration

    K = np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]])
    T_laser_cam = se3_from_xyz_rpy([0.05, 0, 0.1], [-np.pi / 2, 0, -np.pi / 2])
    write_calibration(path, Calibration(CameraIntrinsics(W, H, K), np.linalg.inv(T_laser_cam), "camera", "laser"))
    return path


def test_build_segment_and_check_pick_the_same_camera_topic(tmp_path, bright_backend, capsys):
    """A colour camera and a depth camera (both sensor_msgs/Image): all three commands read the colour one."""
    from semmap.calib.check import frame_from_bag
    from semmap.pipeline import build

    bag = _bag(tmp_path / "two.bag", {"/camera/depth/image_raw": "depth", "/camera/image_raw": "rgb"})
    res = build(bag, tmp_path / "map", overrides={"workers": False, "segmentation": {"backend": "test-bright"},
                                                  "topics": {"odometry": "none"}})
    assert res.summary.tour.topics.image == "/camera/image_raw"
    assert res.summary.painting.scans_painted > 0

    assert main(["segment", str(bag), "--backend", "test-bright", "--out", str(tmp_path / "seg")]) == 0
    summary = json.loads((tmp_path / "seg" / "summary.json").read_text())
    assert summary["source"]["topic"] == "/camera/image_raw"
    assert summary["pixel_share"] == {"person": 1.0}  # the bright colour images, not the dark depth ones

    img, pts, *_ = frame_from_bag(bag, 1.0)
    assert img.shape == (H, W, 3) and int(img.min()) == 200 and len(pts) > 0  # the colour image, as BGR
    calib = _calibration(tmp_path / "calib.yaml")
    out = tmp_path / "check.png"
    assert main(["calibrate", "check", "--calib", str(calib), "--bag", str(bag), "--out", str(out)]) == 0
    assert out.is_file()


def test_two_colour_cameras_are_one_error_naming_both_and_the_setting(tmp_path, bright_backend, capsys):
    from semmap.calib.check import frame_from_bag
    from semmap.errors import BagError
    from semmap.pipeline import build

    bag = _bag(tmp_path / "two.bag", {"/front/image_raw": "rgb", "/rear/image_raw": "rgb"})
    both = r"several image topics \(/front/image_raw, /rear/image_raw\)"
    with pytest.raises(BagError, match=both + r"; choose one with topics.image in the config"):
        build(bag, tmp_path / "map", overrides={"workers": False, "segmentation": {"backend": "test-bright"},
                                                "topics": {"odometry": "none"}})
    assert main(["segment", str(bag), "--backend", "test-bright", "--out", str(tmp_path / "seg")]) == 3
    err = capsys.readouterr().err
    assert "several image topics (/front/image_raw, /rear/image_raw); choose one with --topic" in " ".join(err.split())
    with pytest.raises(BagError, match=both + r"; choose one with --image-topic"):
        frame_from_bag(bag)
    # named, the choice is the same everywhere
    res = build(bag, tmp_path / "map", overrides={"workers": False, "segmentation": {"backend": "test-bright"},
                                                  "topics": {"odometry": "none", "image": "/rear/image_raw"}})
    assert res.summary.tour.topics.image == "/rear/image_raw"
    assert main(["segment", str(bag), "--backend", "test-bright", "--topic", "/rear/image_raw", "--out",
                 str(tmp_path / "seg")]) == 0
    assert frame_from_bag(bag, image_topic="/rear/image_raw")[0].shape == (H, W, 3)


def test_a_named_topic_of_the_wrong_type_is_one_error(tmp_path):
    from semmap.calib.check import frame_from_bag
    from semmap.errors import BagError

    bag = _bag(tmp_path / "one.bag", {"/camera/image_raw": "rgb"})
    with pytest.raises(BagError, match="topic /scan is sensor_msgs/msg/LaserScan, not sensor_msgs/msg/Image"):
        frame_from_bag(bag, image_topic="/scan")
