"""Simulated tours are real bags: rosbags' AnyReader opens them with the documented topics and rates."""

import math

import numpy as np
import pytest
import yaml

from semmap.geometry import quaternion_to_yaw
from semmap.io.bag import bag_info, open_bag
from semmap.io.calibration import read_calibration

TOPICS = {
    "/scan": ("sensor_msgs/msg/LaserScan", 15.0),
    "/camera/image_raw": ("sensor_msgs/msg/Image", 5.0),
    "/camera/labels": ("sensor_msgs/msg/Image", 5.0),
    "/camera/camera_info": ("sensor_msgs/msg/CameraInfo", 5.0),
    "/odom": ("nav_msgs/msg/Odometry", 50.0),
    "/ground_truth/odom": ("nav_msgs/msg/Odometry", 50.0),
    "/tf": ("tf2_msgs/msg/TFMessage", 50.0),
    "/tf_static": ("tf2_msgs/msg/TFMessage", None),
}
RESEARCH_K = [601.80, 0.0, 328.17, 0.0, 600.12, 240.45, 0.0, 0.0, 1.0]


def test_topics_types_and_rates(short_tour):
    info = bag_info(short_tour.bag)
    assert {t.name for t in info.topics} == set(TOPICS)
    for name, (msgtype, rate) in TOPICS.items():
        t = info.topic(name)
        assert t.msgtype == msgtype
        if rate is not None:
            assert t.rate_hz == pytest.approx(rate, rel=0.02), name
    assert info.topic("/tf_static").count == 1
    assert info.duration_s == pytest.approx(8.0, abs=0.1)


def _first(reader, topic):
    conns = [c for c in reader.connections if c.topic == topic]
    for conn, _, raw in reader.messages(connections=conns):
        return reader.deserialize(raw, conn.msgtype)
    raise AssertionError(f"no message on {topic}")


def test_messages_decode_to_the_ground_truth(short_tour):
    gt = np.load(short_tour.out / "ground_truth" / "beams.npz")
    calib = read_calibration(short_tour.out / "calibration.yaml")
    with open_bag(short_tour.bag) as reader:
        scan = _first(reader, "/scan")
        info = _first(reader, "/camera/camera_info")
        image = _first(reader, "/camera/image_raw")
        labels = _first(reader, "/camera/labels")
        static = _first(reader, "/tf_static")
        odom = _first(reader, "/odom")
    # LaserScan: 270 deg at 0.5 deg, ranges = truth + 1 cm noise, REP-117 inf for no return
    assert len(scan.ranges) == 541
    assert math.degrees(scan.angle_max - scan.angle_min) == pytest.approx(270.0)
    assert scan.header.frame_id == "laser"
    stamp = scan.header.stamp.sec * 10**9 + scan.header.stamp.nanosec
    assert stamp == gt["stamp_ns"][0]
    truth = np.isfinite(gt["range"][0])
    ok = np.isfinite(scan.ranges) & truth
    assert ok.sum() / truth.sum() > 0.97  # 0.5 % dropouts
    assert np.all(np.isposinf(np.asarray(scan.ranges)[~truth]))  # no return: +inf
    assert (np.asarray(scan.ranges)[ok] - gt["range"][0][ok]).std() == pytest.approx(0.01, rel=0.25)
    # CameraInfo: ROS1 upper-case D/K/R/P, ROS2 lower-case d/k/r/p, the research's intrinsics
    k = info.K if short_tour.format == "ros1" else info.k
    assert np.allclose(k, RESEARCH_K)
    assert np.allclose(np.asarray(k).reshape(3, 3), calib.intrinsics.K)
    assert (info.width, info.height) == (640, 480)
    # images: rgb8 and a mono16 label image of the same size and stamp
    assert image.encoding == "rgb8" and (image.height, image.width) == (480, 640)
    assert labels.encoding == "mono16" and labels.step == 1280
    assert labels.header.stamp == image.header.stamp
    lab = np.frombuffer(labels.data.tobytes(), dtype="<u2").reshape(480, 640)
    assert set(np.unique(lab)) <= set(range(81))  # COCO class list
    # /tf_static: base_link -> laser at the front-left corner, yawed 45 deg; base_link -> camera
    tfs = {t.child_frame_id: t for t in static.transforms}
    assert set(tfs) == {"laser", "camera_optical_frame"}
    las = tfs["laser"].transform
    assert tfs["laser"].header.frame_id == "base_link"
    assert (las.translation.x, las.translation.y) == pytest.approx((0.38, 0.23))
    q = las.rotation
    assert quaternion_to_yaw([q.x, q.y, q.z, q.w]) == pytest.approx(math.pi / 4)
    assert odom.header.frame_id == "odom" and odom.child_frame_id == "base_link"


def test_calibration_matches_tf_static(short_tour):
    calib = read_calibration(short_tour.out / "calibration.yaml")
    # a point 2 m in front of the laser along its x axis is in front of the camera (z > 0)
    p = calib.T_cam_lidar @ np.array([2.0, 0.0, 0.0, 1.0])
    assert p[2] > 0.5
    assert np.allclose(calib.T_lidar_cam @ calib.T_cam_lidar, np.eye(4))


def test_manifest_and_ground_truth_files(short_tour):
    manifest = yaml.safe_load((short_tour.out / "tour.yaml").read_text())
    assert manifest["scenario"] == "demo" and manifest["format"] == short_tour.format
    for rel in manifest["ground_truth"].values():
        assert (short_tour.out / rel).is_file(), rel
    assert (short_tour.out / "preview" / "world.png").stat().st_size > 10_000
    assert (short_tour.out / "preview" / "camera.png").stat().st_size > 10_000
    odo = manifest["odometry_error"]
    assert 0.01 <= abs(odo["scale"]) <= 0.02 and 0.01 <= abs(odo["yaw_scale"]) <= 0.02


READ_TOPICS = ["/scan", "/odom", "/camera/labels", "/tf", "/tf_static"]


def _via_rosbags(bag, topics):
    with open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages(connections=conns)]


def test_streamed_messages_are_rosbags_messages(short_tour, monkeypatch):
    """semmap reads uncompressed ROS1 and MCAP messages record by record (not whole chunks): same messages,
    same order."""
    import semmap.io.fastbag as fastbag
    from semmap.io.bag import iter_messages
    from semmap.io.fastbag import mcap_records, ros1_records

    theirs = _via_rosbags(short_tour.bag, READ_TOPICS)
    monkeypatch.setattr(fastbag, "_SPARSE_MIN_BYTES", 0)  # record by record even where chunks would do
    monkeypatch.setattr(fastbag, "_RELEASE_BYTES", 4096)  # hand mapped pages back after every few messages
    with open_bag(short_tour.bag) as reader:
        conns = [c for c in reader.connections if c.topic in READ_TOPICS]
        records = ros1_records(reader, conns) or mcap_records(reader, conns)
        assert (records is not None) == (short_tour.format in ("ros1", "mcap"))  # sqlite3: rosbags reads rows
        if records is not None:
            kept = list(records)  # views of the mapped bag, held while later pages are handed back
            assert any(isinstance(raw, memoryview) for _, _, raw in kept)
            assert [(c.topic, t, bytes(raw)) for c, t, raw in kept] == theirs
    ours = [(topic, t) for topic, t, _ in iter_messages(short_tour.bag, READ_TOPICS)]
    assert ours == [(topic, t) for topic, t, _ in theirs]
    assert {topic for topic, _ in ours} == set(READ_TOPICS)


def _rewrite(src, dst, topics, compression=None):
    """A copy of a ROS1 bag with only ``topics``, compressed or not."""
    from rosbags.rosbag1 import Writer

    with open_bag(src) as reader:
        writer = Writer(dst)
        if compression:
            writer.set_compression(compression)
        with writer:
            out = {}
            for conn in reader.connections:
                if conn.topic in topics and conn.id not in out:
                    out[conn.id] = writer.add_connection(conn.topic, conn.msgtype, msgdef=conn.msgdef.data,
                                                         md5sum=conn.digest)
            for conn, t, raw in reader.messages(connections=[c for c in reader.connections if c.id in out]):
                writer.write(out[conn.id], t, raw)


def test_record_by_record_only_where_chunks_hold_other_bytes(short_tour, tmp_path):
    """Scans beside camera images are read on their own; in a LiDAR-only bag whole chunks are cheaper."""
    if short_tour.bag.suffix != ".bag":
        pytest.skip("ROS1 only")
    from semmap.io.fastbag import ros1_records

    with open_bag(short_tour.bag) as reader:
        assert ros1_records(reader, [c for c in reader.connections if c.topic == "/scan"]) is not None
    lidar_only = tmp_path / "lidar.bag"
    _rewrite(short_tour.bag, lidar_only, ["/scan", "/odom"])
    with open_bag(lidar_only) as reader:
        assert ros1_records(reader, list(reader.connections)) is None


def test_compressed_ros1_chunks_are_read_by_rosbags(short_tour, tmp_path):
    """A bz2/lz4 ROS1 bag must be decompressed chunk by chunk: rosbags' own path reads it, unchanged."""
    if short_tour.bag.suffix != ".bag":
        pytest.skip("ROS1 only")
    from rosbags.rosbag1 import Writer

    from semmap.io.bag import iter_messages
    from semmap.io.fastbag import ros1_records

    packed = tmp_path / "lz4.bag"
    _rewrite(short_tour.bag, packed, READ_TOPICS, Writer.CompressionFormat.LZ4)
    with open_bag(packed) as reader:
        assert ros1_records(reader, [c for c in reader.connections if c.topic == "/scan"]) is None
    assert [(topic, t) for topic, t, _ in iter_messages(packed, READ_TOPICS)] == \
        [(topic, t) for topic, t, _ in _via_rosbags(short_tour.bag, READ_TOPICS)]
