"""semmap import carmen: a CARMEN log as a bag semmap build reads, with honest odometry.

The bags are read back with rosbags' AnyReader (what ROS tools read), not with semmap's reader.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from semmap.cli.main import main
from semmap.errors import ConfigError
from semmap.geometry import quaternion_to_yaw, se2_between, se2_compose
from semmap.io.carmen import honest_odometry, read_carmen

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen"


def _ranges(n=180, r=3.0):
    return " ".join(f"{r + 0.01 * (i % 7):.3f}" for i in range(n))


def _corrected_log(path, steps, drift=(0.01, 0.0, 0.02), n_odom=4, stamps=None, offset=0.0):
    """A corrected log: the reference robot poses follow ``steps``; the wheels measure each step with
    ``drift`` added (x, y, yaw); ODOM restarts at the reference pose after every scan (stamped 0), as
    in Radish's corrected logs. Returns (reference poses, true wheel steps)."""
    ref = [np.zeros(3)]
    wheel = []
    for s in steps:
        ref.append(se2_compose(ref[-1], s))
        wheel.append(np.asarray(s, float) + drift)
    mount = np.array([offset, 0.0, 0.0])
    lines = ["# message formats defined: PARAM SYNC ODOM FLASER RLASER TRUEPOS",
             f"PARAM robot_frontlaser_offset {offset} nohost 0"]
    t = 10.0
    for k, pose in enumerate(ref):
        laser = se2_compose(pose, mount)
        st = t if stamps is None else stamps[k]
        lines.append(f"FLASER 180 {_ranges()} {laser[0]:.6f} {laser[1]:.6f} {laser[2]:.6f} {laser[0]:.6f} "
                     f"{laser[1]:.6f} {laser[2]:.6f} {st:.4f} host {st:.4f}")
        lines.append(f"ODOM {pose[0]:.6f} {pose[1]:.6f} {pose[2]:.6f} 0 0 0 0 host 0")  # the restart
        if k < len(wheel):
            for j in range(1, n_odom + 1):  # the wheels' path to the next scan, from the reference pose
                part = se2_compose(pose, np.asarray(wheel[k]) * (j / n_odom))
                lines.append(f"ODOM {part[0]:.6f} {part[1]:.6f} {part[2]:.6f} 0.3 0.1 0 {st + 0.2 * j:.4f} host "
                             f"{st + 0.2 * j:.4f}")
        t += 1.0
    path.write_text("\n".join(lines) + "\n")
    return np.array(ref), np.array(wheel)


def _read_bag(folder):
    from rosbags.highlevel import AnyReader

    bag = next(p for p in folder.iterdir() if p.suffix == ".bag")
    out = {}
    with AnyReader([bag]) as r:
        for conn, t, raw in r.messages():
            msg = r.deserialize(raw, conn.msgtype)
            out.setdefault(conn.topic, []).append((t, msg))
    return out


def _pose(msg):
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return np.array([p.x, p.y, float(quaternion_to_yaw([q.x, q.y, q.z, q.w]))])


STEPS = [(0.3, 0.0, 0.1), (0.25, 0.05, -0.2), (0.4, 0.0, 0.3), (0.2, -0.02, 0.5), (0.35, 0.0, -0.1)]


def test_the_odometry_is_the_wheels_steps_chained_never_the_reference(tmp_path):
    ref, wheel = _corrected_log(tmp_path / "c.log", STEPS, offset=0.12)
    assert main(["import", "carmen", str(tmp_path / "c.log"), "--out", str(tmp_path / "tour"), "-q"]) == 0
    msgs = _read_bag(tmp_path / "tour")
    scans = [t for t, _ in msgs["/scan"]]
    odom = {t: _pose(m) for t, m in msgs["/odom"]}
    at_scans = np.array([odom[t] for t in scans])
    # the chain of the true wheel steps, from the origin
    want = [np.zeros(3)]
    for w in wheel:
        want.append(se2_compose(want[-1], w))
    assert np.allclose(at_scans[:, :2], np.array(want)[:, :2], atol=1e-5)
    assert np.allclose(np.cos(at_scans[:, 2] - np.array(want)[:, 2]), 1.0, atol=1e-9)
    # ... and not the reference's steps: each odometry step is the wheels' (drifted) step
    for k in range(1, len(ref)):
        step = se2_between(at_scans[k - 1], at_scans[k])
        assert np.allclose(step, wheel[k - 1], atol=1e-5)
        assert not np.allclose(step, se2_between(ref[k - 1], ref[k]), atol=5e-3)
    # the reference goes on its own topic, as robot (base) poses, and the mount on /tf_static
    gt = np.array([_pose(m) for _, m in msgs["/ground_truth/odom"]])
    assert np.allclose(gt, ref, atol=1e-5)
    tf = msgs["/tf_static"][0][1].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", "laser")
    assert tf.transform.translation.x == pytest.approx(0.12)
    scan = msgs["/scan"][0][1]
    assert scan.header.frame_id == "laser" and len(scan.ranges) == 180
    assert scan.angle_min == pytest.approx(-math.pi / 2) and scan.angle_increment == pytest.approx(math.pi / 180)
    # the wheel path between scans is there too, in time order
    assert len(msgs["/odom"]) > len(scans) and all(np.diff([t for t, _ in msgs["/odom"]]) > 0)


@pytest.mark.skipif(not (DATA / "intel-corrected.log.gz").is_file(), reason="../shared/data/carmen is absent")
def test_the_intel_log_odometry_is_not_the_reference():
    log = read_carmen(DATA / "intel-corrected.log.gz")
    assert log.corrected and len(log.front) == 910
    odo, ok, _, _ = honest_odometry(log)
    ref = np.array([s.pose for s in log.front])  # the laser is at the robot's centre in this log
    steps_o = np.array([se2_between(odo[k - 1], odo[k]) for k in range(1, len(odo))])
    steps_r = np.array([se2_between(ref[k - 1], ref[k]) for k in range(1, len(ref))])
    gap = np.linalg.norm(steps_o[:, :2] - steps_r[:, :2], axis=1)
    # a leak would make them equal; the wheels differ from the SLAM steps by centimetres a step
    assert np.median(gap) > 0.01 and np.median(np.abs(np.sin(steps_o[:, 2] - steps_r[:, 2]))) > 0.005
    # and over the whole tour they drift apart by metres, while the path lengths agree within 1 %
    from semmap.register.metrics import align_se2

    T = align_se2(odo[:, :2], ref[:, :2])
    moved = odo[:, :2] @ np.array([[math.cos(T[2]), -math.sin(T[2])], [math.sin(T[2]), math.cos(T[2])]]).T + T[:2]
    assert np.sqrt(np.mean(np.sum((moved - ref[:, :2]) ** 2, axis=1))) > 1.0
    length = [np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1).sum() for p in (odo, ref)]
    assert length[0] == pytest.approx(length[1], rel=0.01)
    assert ok[1:].all()


def test_a_raw_log_keeps_its_odometry_fields_and_has_no_reference(tmp_path):
    lines = []
    for k in range(4):
        lines.append(f"FLASER 180 {_ranges()} {k * 0.5:.3f} 0 0 {k * 0.48:.3f} 0.01 0.002 {10 + k}.5 h {10 + k}.5")
    (tmp_path / "raw.log").write_text("\n".join(lines) + "\n")
    log = read_carmen(tmp_path / "raw.log")
    assert not log.corrected
    odo, _, _, _ = honest_odometry(log)
    assert np.allclose(odo[:, 0], [0.0, 0.48, 0.96, 1.44])
    assert main(["import", "carmen", str(tmp_path / "raw.log"), "--out", str(tmp_path / "t"), "-q"]) == 0
    assert "/ground_truth/odom" not in _read_bag(tmp_path / "t")
    assert not (tmp_path / "t" / "reference.tum").exists()


def test_stamps_too_coarse_to_pair_are_refused(tmp_path, capsys):
    _corrected_log(tmp_path / "c.log", STEPS, stamps=[10, 10, 11, 11, 12, 12])
    assert main(["import", "carmen", str(tmp_path / "c.log"), "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "c.log" in err and "too coarse" in err
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("text, message", [
    ("FLASER 180 1 2 3\n", r"c\.log:1: FLASER: 180 readings, 6 pose fields"),
    (f"FLASER 180 {_ranges()} 0 0 zero 0 0 0 1.0 h 1.0\n", r"c\.log:1: FLASER: a field is not a number"),
    ("ODOM 0 0 0 0 0 0 1.0 h 1.0\n", "no FLASER or ROBOTLASER1 line"),
    (f"FLASER 180 {_ranges()} 0 0 0 0 0 0 1.0\n", "'timestamp \\[hostname\\] logger_timestamp' expected"),
])
def test_a_malformed_log_is_one_line_naming_the_line(tmp_path, text, message):
    (tmp_path / "c.log").write_text(text)
    with pytest.raises(ConfigError, match=message):
        read_carmen(tmp_path / "c.log")


def test_a_gzip_log_reads_like_the_plain_one(tmp_path):
    import gzip

    _corrected_log(tmp_path / "c.log", STEPS)
    (tmp_path / "c.log.gz").write_bytes(gzip.compress((tmp_path / "c.log").read_bytes()))
    a, b = read_carmen(tmp_path / "c.log"), read_carmen(tmp_path / "c.log.gz")
    assert len(a.front) == len(b.front) and np.array_equal(a.odom, b.odom)


def test_build_reads_the_imported_tour_unchanged(tmp_path):
    # a corridor 2 m wide: the scans see its walls (the builder needs structure to map)
    steps = [(0.2, 0.0, 0.0)] * 12
    ref, _ = _corrected_log(tmp_path / "c.log", steps, drift=(0.0, 0.0, 0.0))
    lines = (tmp_path / "c.log").read_text().splitlines()
    a = -math.pi / 2 + np.arange(180) * math.pi / 180
    with np.errstate(divide="ignore"):
        r = np.where(np.abs(np.sin(a)) > 0.05, 1.0 / np.abs(np.sin(a)), 20.0)
    r = np.minimum(r, 20.0)
    text = " ".join(f"{v:.3f}" for v in r)
    lines = [ln.replace(_ranges(), text) if ln.startswith("FLASER") else ln for ln in lines]
    (tmp_path / "c.log").write_text("\n".join(lines) + "\n")
    assert main(["import", "carmen", str(tmp_path / "c.log"), "--out", str(tmp_path / "tour"), "-q"]) == 0
    cfg = tmp_path / "odom.yaml"
    cfg.write_text("registration: {mode: odometry}\n")
    assert main(["build", str(tmp_path / "tour"), "--out", str(tmp_path / "map"), "--config", str(cfg), "-q"]) == 0
    import semmap

    m = semmap.load_map(tmp_path / "map")
    assert m.summary.counts.scans == len(ref)
    # the walls at y = +-1 m in the map frame (the first scan's base pose)
    rows, _ = np.nonzero(m.cleaned.occupied)
    y = m.spec.origin_y + (rows + 0.5) * m.spec.resolution
    assert np.mean(np.abs(np.abs(y) - 1.0) < 0.1) > 0.9


def test_a_build_warns_when_scans_have_no_odometry(tmp_path):
    # the corridor tour of the test above, with the wheels' ODOM lines gone after the fourth scan
    steps = [(0.2, 0.0, 0.0)] * 12
    _corrected_log(tmp_path / "c.log", steps, drift=(0.0, 0.0, 0.0))
    a = -math.pi / 2 + np.arange(180) * math.pi / 180
    r = np.minimum(np.where(np.abs(np.sin(a)) > 0.05, 1.0 / np.maximum(np.abs(np.sin(a)), 1e-9), 20.0), 20.0)
    text = " ".join(f"{v:.3f}" for v in r)
    out, scans = [], 0
    for ln in (tmp_path / "c.log").read_text().splitlines():
        if ln.startswith("FLASER"):
            scans += 1
            ln = ln.replace(_ranges(), text)
        elif ln.startswith("ODOM") and scans > 4 and ln.split()[7] != "0":
            continue  # only the restart lines (stamped 0) are left: no wheel motion is known
        out.append(ln)
    (tmp_path / "c.log").write_text("\n".join(out) + "\n")
    assert main(["import", "carmen", str(tmp_path / "c.log"), "--out", str(tmp_path / "tour"), "-q"]) == 0
    assert main(["build", str(tmp_path / "tour"), "--out", str(tmp_path / "map"), "-q"]) == 0
    import json

    summary = json.loads((tmp_path / "map" / "summary.json").read_text())
    assert summary["registration"]["odom_missing"] >= 7
    assert any("had no odometry on /odom" in w for w in summary["warnings"]), summary["warnings"]
