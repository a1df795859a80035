"""Odometry recorded only in /tf (``odom → base_footprint``, as a TurtleBot2 records it) is used as
odometry: detected when the bag has no Odometry topic, chosen with ``topics.odometry: tf``, and
composed with the static chain to the base frame."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from semmap.errors import BagError
from semmap.geometry import se2_compose, se2_to_se3, se3_from_xyz_rpy, se3_to_se2
from semmap.io.bag import BagWriter
from semmap.io.tf import TfTree, find_tf_odometry
from semmap.io.tum import read_tum
from semmap.pipeline import build
from semmap.records import Scan

T0 = 1_700_000_000 * 1_000_000_000
MS = 1_000_000
#: base_footprint -> base_link, as a TurtleBot's URDF has it (shifted in x too, so the chain shows)
T_FOOTPRINT_LINK = se3_from_xyz_rpy([0.05, 0.0, 0.1], [0, 0, 0.2])
T_LINK_LASER = se3_from_xyz_rpy([0.2, 0.0, 0.3])
ODOM_ONLY = {"workers": False, "registration": {"mode": "odometry"}}


def robot_pose(t: float, speed: float = 0.5) -> np.ndarray:
    """base_link in the odom frame at t s: an arc at ``speed`` m/s, 0.3 rad/s."""
    w = 0.3
    yaw = w * t
    return np.array([-2.0 + speed / w * math.sin(yaw), -1.0 + speed / w * (1 - math.cos(yaw)), yaw])


def room_scan(pose_laser: np.ndarray, stamp: int, frame: str) -> Scan:
    """A 270° scan of a 10 m x 6 m room from the laser pose (x, y, yaw)."""
    n = 271
    angles = np.linspace(-3 * math.pi / 4, 3 * math.pi / 4, n)
    a = pose_laser[2] + angles
    dx, dy = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        tx = np.where(dx > 0, (5 - pose_laser[0]) / dx, (-5 - pose_laser[0]) / dx)
        ty = np.where(dy > 0, (3 - pose_laser[1]) / dy, (-3 - pose_laser[1]) / dy)
    ranges = np.minimum(np.abs(tx), np.abs(ty)).astype(np.float32)
    return Scan(stamp, frame, float(angles[0]), float(angles[1] - angles[0]), ranges, 0.05, 20.0, 0.0, 0.1)


def write_tour(path: Path, *, odom_topic: bool = True, tf: str | None = "odom->base_link", tf_speed: float = 0.5,
               old_tf_type: bool = False, fmt: str = "ros1", slam_first: int = 0) -> Path:
    """A 4 s tour: scans at 10 Hz, odometry at 50 Hz.

    ``odom_topic``: a nav_msgs/Odometry topic /odom (odom -> base_link). ``tf``: what /tf carries:
    ``"odom->base_link"`` (with map -> odom from a SLAM node in the same messages),
    ``"odom->base_footprint"`` (base_footprint -> base_link on /tf_static), ``"map->base_link"``
    (a SLAM pose, no odometry) or None. ``tf_speed``: the speed of the robot /tf says (to tell it
    from the topic's). ``old_tf_type``: /tf as ``tf/tfMessage``, as ROS1 bags before tf2 have it.
    ``slam_first``: that many /tf messages of map -> odom alone before the odometry starts (a SLAM
    node started before the robot's driver, as in the MIT bags of ../shared/data).
    """
    bag = path / "tour.bag" if fmt == "ros1" else path / "tour"
    path.mkdir(parents=True, exist_ok=True)
    with BagWriter(bag, fmt) as w:
        if old_tf_type:
            _write_tf_as_tf_tfmessage(w)
        static = [(T0, "base_link", "laser", T_LINK_LASER)]
        if tf == "odom->base_footprint":
            static.append((T0, "base_footprint", "base_link", T_FOOTPRINT_LINK))
        w.transforms("/tf_static", T0, static, static=True)
        for k in range(slam_first):
            t_ns = T0 - (slam_first - k) * 10 * MS
            w.transforms("/tf", t_ns, [(t_ns, "map", "odom", np.eye(4))])
        for k in range(4000 // 20 + 1):  # odometry every 20 ms, scans every 100 ms
            t_ns = T0 + k * 20 * MS
            t = k * 0.02
            pose = robot_pose(t)
            if odom_topic:
                w.odometry("/odom", t_ns, t_ns, "odom", "base_link", pose, (0.5, 0.0, 0.3))
            if tf is not None:
                link = robot_pose(t, tf_speed)
                drift = se2_to_se3([0.01 * t, 0.0, 0.002 * t])  # map -> odom: a SLAM node's correction
                if tf == "odom->base_link":
                    w.transforms("/tf", t_ns, [(t_ns, "map", "odom", drift), (t_ns, "odom", "base_link",
                                                                            se2_to_se3(link))])
                elif tf == "odom->base_footprint":
                    footprint = se2_to_se3(link) @ np.linalg.inv(T_FOOTPRINT_LINK)
                    w.transforms("/tf", t_ns, [(t_ns, "odom", "base_footprint", footprint)])
                elif tf == "map->base_link":
                    w.transforms("/tf", t_ns, [(t_ns, "map", "base_link", se2_to_se3(link))])
            if k % 5 == 2 and 0.1 < t < 3.8:
                laser = se2_compose(pose, se3_to_se2(T_LINK_LASER))
                w.scan("/scan", t_ns + 2 * MS, room_scan(laser, t_ns, "laser"))
    return bag


def _write_tf_as_tf_tfmessage(w: BagWriter) -> None:
    """Make ``w`` write /tf as ``tf/tfMessage`` (the fields of tf2's TFMessage, another name)."""
    from rosbags.typesys import get_types_from_msg

    w._store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", "tf/msg/tfMessage"))
    write = w._write

    def old(topic: str, msgtype: str, t_ns: int, msg: object, latched: bool = False) -> None:
        if topic == "/tf":
            msgtype, msg = "tf/msg/tfMessage", w._store.types["tf/msg/tfMessage"](transforms=msg.transforms)
        write(topic, msgtype, t_ns, msg, latched)

    w._write = old


def odometry_poses(map_folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """The build's odometry at each scan (odometry.tum): stamps (ns) and (x, y, yaw)."""
    return read_tum(map_folder / "odometry.tum")


def trajectory(map_folder: Path) -> np.ndarray:
    return read_tum(map_folder / "trajectory.tum")[1]


def test_without_an_odometry_topic_the_odometry_comes_from_tf(tmp_path, caplog):
    """(a) The same tour with /odom and with only /tf: the same trajectory within 1 mm, and one line says so."""
    with_topic = write_tour(tmp_path / "topic", tf=None)
    tf_only = write_tour(tmp_path / "tf", odom_topic=False)
    ref = build(with_topic, tmp_path / "m_topic", overrides=ODOM_ONLY)
    caplog.set_level("INFO", logger="semmap")
    res = build(tf_only, tmp_path / "m_tf", overrides=ODOM_ONLY)
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("odometry: /tf")]
    assert said == ["odometry: /tf odom -> base_link (no nav_msgs/Odometry topic)"]
    assert res.summary.tour.topics.odometry == "/tf (odom -> base_link)"
    assert res.summary.tour.frames.base == "base_link"
    assert res.summary.counts.scans == ref.summary.counts.scans == 37
    assert res.summary.counts.scans_without_odometry == 0 and res.summary.counts.odometry == 201
    assert res.summary.registration["mode"] == "odometry"
    gap = np.abs(trajectory(res.out) - trajectory(ref.out))
    assert gap[:, :2].max() < 1e-3 and gap[:, 2].max() < 1e-4
    # the odometry is the robot's pose in the odom frame (map -> odom in the same messages is ignored)
    stamps, poses = odometry_poses(res.out)
    truth = np.array([robot_pose((s - T0) * 1e-9) for s in stamps])
    assert np.abs(poses[:, :2] - truth[:, :2]).max() < 1e-3
    # the config written beside the map rebuilds it the same way
    written = (res.out / "config.yaml").read_text()
    assert "odometry: tf" in written and "odom: odom" in written


def test_odom_to_base_footprint_and_a_static_chain_to_base_link(tmp_path):
    """(b) odom -> base_footprint on /tf, base_footprint -> base_link on /tf_static (a TurtleBot2)."""
    bag = write_tour(tmp_path / "tb2", odom_topic=False, tf="odom->base_footprint")
    res = build(bag, tmp_path / "m_link", overrides={**ODOM_ONLY, "frames": {"base": "base_link"}})
    assert res.summary.tour.topics.odometry == "/tf (odom -> base_footprint -> base_link)"
    stamps, poses = odometry_poses(res.out)
    truth = np.array([robot_pose((s - T0) * 1e-9) for s in stamps])  # base_link: composed through the chain
    assert len(stamps) == 37 and np.abs(poses[:, :2] - truth[:, :2]).max() < 1e-3
    assert np.abs(np.angle(np.exp(1j * (poses[:, 2] - truth[:, 2])))).max() < 1e-4
    # without frames.base, the base frame is the child of the odometry transform
    res = build(bag, tmp_path / "m_footprint", overrides=ODOM_ONLY)
    assert res.summary.tour.frames.base == "base_footprint"
    assert res.summary.tour.topics.odometry == "/tf (odom -> base_footprint)"
    assert "base_footprint -> base_link" in res.summary.tour.T_base_lidar_source
    stamps, poses = odometry_poses(res.out)
    truth = np.array([se3_to_se2(se2_to_se3(robot_pose((s - T0) * 1e-9)) @ np.linalg.inv(T_FOOTPRINT_LINK))
                      for s in stamps])
    assert np.abs(poses[:, :2] - truth[:, :2]).max() < 1e-3


def test_old_tf_messages_and_ros2_bags(tmp_path):
    """/tf as ROS1's pre-tf2 ``tf/tfMessage``, and a ROS2 bag: the same odometry."""
    old = write_tour(tmp_path / "old", odom_topic=False, old_tf_type=True)
    ros2 = write_tour(tmp_path / "ros2", odom_topic=False, fmt="mcap")
    for bag, name in ((old, "m_old"), (ros2, "m_ros2")):
        res = build(bag, tmp_path / name, overrides=ODOM_ONLY)
        assert res.summary.tour.topics.odometry == "/tf (odom -> base_link)"
        stamps, poses = odometry_poses(res.out)
        truth = np.array([robot_pose((s - T0) * 1e-9) for s in stamps])
        assert len(stamps) == 37 and np.abs(poses[:, :2] - truth[:, :2]).max() < 1e-3


def test_odometry_that_starts_after_the_first_messages_of_tf_is_found(tmp_path):
    """/tf carries map -> odom alone for its first 300 messages (3 s) before the odometry starts."""
    bag = write_tour(tmp_path / "late", odom_topic=False, slam_first=300)
    res = build(bag, tmp_path / "m", overrides=ODOM_ONLY)
    assert res.summary.tour.topics.odometry == "/tf (odom -> base_link)"
    assert res.summary.counts.scans == 37 and res.summary.counts.scans_without_odometry == 0


def test_tf_odometry_asked_for_but_absent_is_one_clear_line(tmp_path):
    """(c) ``topics.odometry: tf`` with no odometry transform on /tf (or no /tf at all) fails, naming
    the bag, the topic and the frames; left to detection, the same bag builds without odometry."""
    slam = write_tour(tmp_path / "slam", odom_topic=False, tf="map->base_link")
    with pytest.raises(BagError) as err:
        build(slam, tmp_path / "m", overrides={**ODOM_ONLY, "topics": {"odometry": "tf"}})
    msg = str(err.value)
    assert "\n" not in msg and str(slam) in msg and "topics.odometry is 'tf'" in msg
    assert "/tf has no transform from a frame named like 'odom'" in msg and "map -> base_link" in msg
    assert "frames.odom" in msg and not (tmp_path / "m").exists()
    with pytest.raises(BagError, match=r"frame 'wheel_odom'.*base frame 'base_link'"):
        build(slam, tmp_path / "m", overrides={"topics": {"odometry": "tf"},
                                               "frames": {"odom": "wheel_odom", "base": "base_link"}})
    bare = write_tour(tmp_path / "bare", odom_topic=False, tf=None)
    with pytest.raises(BagError, match=r"topic /tf \(the odometry transforms, topics.odometry: tf\) is not in "):
        build(bare, tmp_path / "m", overrides={"topics": {"odometry": "tf"}})
    res = build(slam, tmp_path / "m_icp", overrides={"workers": False})  # a SLAM pose is not odometry
    assert res.summary.tour.topics.odometry is None and res.summary.registration["mode"] == "icp"


def test_the_odometry_topic_wins_unless_tf_is_chosen(tmp_path):
    """(d) Both an Odometry topic and /tf odometry (here /tf says the robot went 10 % faster):
    by default the topic is used; ``topics.odometry: tf`` takes /tf."""
    both = write_tour(tmp_path / "both", tf_speed=0.55)
    res = build(both, tmp_path / "m_topic", overrides=ODOM_ONLY)
    assert res.summary.tour.topics.odometry == "/odom"
    stamps, poses = odometry_poses(res.out)
    assert np.abs(poses[:, :2] - [robot_pose((s - T0) * 1e-9)[:2] for s in stamps]).max() < 1e-3
    res = build(both, tmp_path / "m_tf", overrides={**ODOM_ONLY, "topics": {"odometry": "tf"}})
    assert res.summary.tour.topics.odometry == "/tf (odom -> base_link)"
    stamps, poses = odometry_poses(res.out)
    assert np.abs(poses[:, :2] - [robot_pose((s - T0) * 1e-9, 0.55)[:2] for s in stamps]).max() < 1e-3
    # the tf topic's own name chooses it too
    res = build(both, tmp_path / "m_tf2", overrides={**ODOM_ONLY, "topics": {"odometry": "/tf"}})
    assert res.summary.tour.topics.odometry == "/tf (odom -> base_link)"


def _tree(static: list[tuple[str, str]], moving: list[tuple[str, str]]) -> tuple[TfTree, dict[str, str]]:
    tree = TfTree()
    for parent, child in static + moving:
        tree.add(parent, child, se3_from_xyz_rpy([0.1, 0.0, 0.0]))
    return tree, {child: parent for parent, child in moving}


@pytest.mark.parametrize(("static", "moving", "base", "odom", "found"), [
    # a full tree: a SLAM node's map -> odom above the wheel odometry
    ([("base_link", "laser")], [("map", "odom"), ("odom", "base_link")], None, None, ("odom", "base_link")),
    # robot_pose_ekf's odom_combined, a namespaced robot
    ([("base_link", "laser")], [("odom_combined", "base_link")], None, None, ("odom_combined", "base_link")),
    ([("robot1/base_link", "laser")], [("robot1/odom", "robot1/base_link")], None, None,
     ("robot1/odom", "robot1/base_link")),
    # a TurtleBot2: odom -> base_footprint moving, base_footprint -> base_link static
    ([("base_footprint", "base_link"), ("base_link", "laser")], [("odom", "base_footprint")], "base_link", None,
     ("odom", "base_footprint")),
    # a parent not named like odom, but not a global frame either; one named by frames.odom
    ([("base_link", "laser")], [("map", "wheels"), ("wheels", "base_link")], None, None, ("wheels", "base_link")),
    ([("base_link", "laser")], [("map", "wheels"), ("wheels", "base_link")], None, "map", ("map", "wheels")),
    # a SLAM pose only: no odometry
    ([("base_link", "laser")], [("map", "base_link")], None, None, None),
    # the LiDAR not linked to the tree (its mount in the config): the one odometry transform of /tf
    ([], [("map", "odom"), ("odom", "base_footprint")], None, None, ("odom", "base_footprint")),
])
def test_which_transform_of_tf_is_the_odometry(static, moving, base, odom, found):
    tree, moved = _tree(static, moving)
    res = find_tf_odometry(tree, moved, base or "laser", "/tf", base=base, odom=odom)
    assert (None if res is None else (res.odom_frame, res.child_frame)) == found
    if res is not None:
        assert res.base_frame == (base or res.child_frame)
