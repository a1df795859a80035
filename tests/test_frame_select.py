"""Frame selection (``segmentation.select``): which camera frames the model runs on, and how the scans
paired with the others are labelled."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semmap.config import OnnxSegmentation, TopicSegmentation
from semmap.paint.painter import LabelMemory
from semmap.records import Mobility, Segmentation
from semmap.segment.select import FrameSelector, SkippedFrame

S = 1_000_000_000


def _run(sel: FrameSelector, frames: list[tuple[float, tuple[float, float, float]]]) -> list[bool]:
    out = []
    for t, pose in frames:
        sel.add_odometry(int(t * S), np.array(pose))
        out.append(sel.want(int(t * S)))
    return out


def test_all_takes_every_frame_and_needs_no_odometry():
    sel = FrameSelector(TopicSegmentation())
    assert sel.trivial
    assert all(sel.want(k * S // 10) for k in range(20))
    assert (sel.selected, sel.skipped) == (20, 0)


def test_motion_takes_a_frame_per_distance_per_turn_and_per_interval():
    cfg = TopicSegmentation(select="motion", select_distance=0.45, select_angle=14.0, select_interval=2.0)
    # 10 frames a second; the robot drives 1 m/s for 1 s, turns 30°/s for 1 s, then stands 3 s
    frames = [(k / 10, (k / 10, 0.0, 0.0)) for k in range(10)]
    frames += [(1 + k / 10, (1.0, 0.0, math.radians(3.0 * k))) for k in range(10)]
    frames += [(2 + k / 10, (1.0, 0.0, math.radians(30.0))) for k in range(30)]
    taken = [t for (t, _), w in zip(frames, _run(FrameSelector(cfg), frames)) if w]
    # the first frame; 0.5 and 1 m on; 15° and 30° turned; then only the interval, 2 s after the last one
    assert taken == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0, 4.0])


def test_motion_without_odometry_takes_a_frame_per_interval():
    sel = FrameSelector(TopicSegmentation(select="motion", select_interval=1.0))
    taken = [k for k in range(50) if sel.want(k * S // 10)]
    assert taken == [0, 10, 20, 30, 40]


def test_a_frame_the_model_could_not_take_does_not_count_as_segmented():
    sel = FrameSelector(TopicSegmentation(select="motion", select_interval=1.0))
    assert sel.want(0)
    sel.failed()  # e.g. a corrupt JPEG
    assert sel.want(S // 10)  # the next frame is taken in its place, not a second later
    assert not sel.want(2 * S // 10)
    assert (sel.selected, sel.skipped) == (1, 1)


def test_the_budget_holds_the_average_rate_whatever_the_selection_wants():
    sel = FrameSelector(TopicSegmentation(max_rate=2.0))  # every frame wanted, 2 per second allowed
    taken = [k for k in range(15 * 60) if sel.want(k * S // 15)]  # a 15 Hz camera for 60 s
    assert len(taken) == pytest.approx(2 * 60, abs=2)
    assert max(np.diff(taken)) <= 8  # spread over the tour, not spent at its start


def test_the_budget_saves_a_quiet_stretchs_frames_for_a_busy_one():
    # a corridor whose walls are known (nothing wanted for 20 s), then a room of furniture (every frame
    # wanted): one frame a second allows five at once after the quiet spell, then one a second again
    class Busy(FrameSelector):
        def wanted(self, stamp_ns):
            return self._last_ns is None or stamp_ns >= 20 * S

    sel = Busy(TopicSegmentation(max_rate=1.0))
    taken = [k for k in range(15 * 40) if sel.want(k * S // 15)]
    assert taken[0] == 0 and taken[1:6] == list(range(300, 305))  # the saved frames, on the room's first ones
    assert len(taken) == pytest.approx(1 + 5 + 20, abs=1)  # then the rate: 40 s of tour, 26 frames at most
    assert min(np.diff(taken[6:])) >= 14


def test_a_frame_budget_is_spread_over_the_tour_and_never_overspent():
    sel = FrameSelector(TopicSegmentation(max_frames=30))
    assert not sel.trivial
    sel.spread_over(60.0)  # a 60 s tour: a frame every 2 s
    taken = [k for k in range(15 * 60) if sel.want(k * S // 15)]
    assert len(taken) == 30 and taken[-1] > 15 * 50  # the last ones near the end, not all at the start
    sel = FrameSelector(TopicSegmentation(max_frames=10))
    sel.spread_over(1.0)  # a wrong guess of the length: the count still holds
    assert sum(sel.want(k * S // 15) for k in range(15 * 60)) == 10


def _run_timed(sel, seconds_per_frame, tour_s=60.0, hz=15):
    """Frames of a ``hz`` camera over ``tour_s``: the ones taken, each costing ``seconds_per_frame(k)``."""
    sel.spread_over(tour_s)
    taken = []
    for k in range(int(hz * tour_s)):
        stamp = k * S // hz
        if sel.want(stamp):
            taken.append(k)
            sel.timed(seconds_per_frame(len(taken)), stamp)
    return taken


def test_a_model_time_budget_is_spread_over_the_tour_and_never_overspent():
    sel = FrameSelector(TopicSegmentation(max_seconds=6.0))
    assert not sel.trivial
    taken = _run_timed(sel, lambda n: 0.5)  # a 0.5 s model: 12 frames in 6 s
    assert 11 <= len(taken) <= 12 and sel.model_seconds <= 6.0 + 0.5  # the last frame may start before the end
    assert taken[-1] > 15 * 50 and max(np.diff(taken)) < 15 * 10  # spread, not spent at the start
    # a model that turns out cheaper after its first frame (a warm-up): the budget buys more frames later
    sel = FrameSelector(TopicSegmentation(max_seconds=6.0))
    taken = _run_timed(sel, lambda n: 2.0 if n == 1 else 0.1)
    assert sel.model_seconds <= 6.0 + 2.0 and len(taken) > 12
    assert taken[-1] > 15 * 45


def test_a_model_time_budget_holds_under_a_frame_budget_and_a_rate():
    sel = FrameSelector(TopicSegmentation(max_seconds=100.0, max_frames=20))
    assert len(_run_timed(sel, lambda n: 0.1)) == 20  # the frame count binds
    sel = FrameSelector(TopicSegmentation(max_seconds=100.0, max_rate=0.5))
    assert len(_run_timed(sel, lambda n: 0.1)) == pytest.approx(30, abs=2)  # the rate binds
    sel = FrameSelector(TopicSegmentation(max_seconds=3.0, max_rate=5.0))
    assert len(_run_timed(sel, lambda n: 0.5)) <= 7  # the seconds bind


def test_the_label_memory_transfers_furniture_on_one_frames_word_structure_on_two_and_a_person_briefly():
    mem = LabelMemory(0.05, window_s=2.0)
    person, wall, chair, pillar = ([[1.01, 1.01], [1.02, 1.03]], [[1.04, 1.01]], [[2.0, 2.0]], [[4.0, 4.0]])
    query = np.array([[1.03, 1.04], [2.01, 2.02], [3.0, 3.0], [4.01, 4.01]])

    def frame(t, pts, mobility, cls):
        n = len(pts)
        mem.add(t * S, np.array(pts), np.full(n, mobility, np.uint8), np.full(n, cls, np.int16))

    frame(1, person + wall, Mobility.DYNAMIC, 0)  # two of the cell's three returns: a person
    frame(1, chair, Mobility.SEMI_STATIC, 3)  # a second scan painted from the same frame
    frame(1, pillar, Mobility.STATIC, -1)
    # a person and furniture (a thin leg the masks hit and miss) on one frame's word; structure not yet
    assert mem.lookup(S, query)[0].tolist() == [True, True, False, False]
    frame(2, person, Mobility.DYNAMIC, 0)
    frame(2, chair, Mobility.SEMI_STATIC, 3)
    frame(2, pillar, Mobility.STATIC, -1)
    found, m, c = mem.lookup(2 * S, query)
    assert found.tolist() == [True, True, False, True]  # cells no frame saw stay unknown
    assert m.tolist() == [Mobility.DYNAMIC, Mobility.SEMI_STATIC, 0, Mobility.STATIC]
    assert c.tolist() == [0, 3, -1, -1]
    found, m, _ = mem.lookup(9 * S, query)  # the person's label holds 2 s; furniture's and structure's all tour
    assert found.tolist() == [False, True, False, True]
    frame(10, chair, Mobility.STATIC, -1)  # one frame saw the chair's cell as structure: furniture still leads
    found, m, _ = mem.lookup(10 * S, query)
    assert found[1] and m[1] == Mobility.SEMI_STATIC
    frame(11, chair, Mobility.STATIC, -1)  # two votes each way: structure takes the lead by one, not enough
    assert mem.lookup(11 * S, query)[0].tolist() == [False, False, False, True]
    frame(12, chair, Mobility.STATIC, -1)
    found, m, _ = mem.lookup(12 * S, query)
    assert found.tolist() == [False, True, False, True] and m[1] == Mobility.STATIC


def _score(tour, folder):
    from semmap.sim.score import score_map

    return score_map(tour, folder)


def test_a_build_selecting_by_motion_runs_fewer_frames_and_keeps_the_map(demo_tour, demo_map, tmp_path):
    from semmap.pipeline import build

    res = build(demo_tour.out, tmp_path / "motion", overrides={"segmentation": {"select": "motion"}})
    fs = res.summary.painting.frame_selection
    n_all = demo_map.summary.counts.images
    assert fs.select == "motion" and fs.frames_skipped > 0
    assert fs.frames_segmented + fs.frames_skipped == n_all
    assert res.summary.counts.images == fs.frames_segmented < 0.75 * n_all
    assert fs.scans_from_memory > 0 and fs.returns_labelled_from_memory > 0
    report = (res.out / "report.md").read_text()
    assert f"Label images used for {fs.frames_segmented} of {n_all} frames (select: motion)" in report
    assert "![where the model ran](report/frames.png)" in report and (res.out / "report" / "frames.png").is_file()
    assert not (demo_map.out / "report" / "frames.png").exists()  # every frame segmented: nothing to show
    s_all, s_mot = _score(demo_tour.out, demo_map.out), _score(demo_tour.out, res.out)
    assert s_mot["standing_left"] == s_all["standing_left"] == 0.0  # the standing person is gone
    assert s_mot["ghost_rate"] <= s_all["ghost_rate"] + 0.005
    assert s_mot["f1"] >= s_all["f1"] - 0.01
    assert s_mot["semi_recall"] >= s_all["semi_recall"] - 0.05


def test_the_image_worker_hands_over_instances_and_skipped_frames(demo_tour, tmp_path):
    pytest.importorskip("onnxruntime")
    from test_segment_yolo import _instance_model

    from semmap.paint.stream import open_build_tour, selection_odometry
    from semmap.segment.images import InProcessImages
    from semmap.workers import ImageWorker

    model = _instance_model(tmp_path / "m.onnx")
    seg_cfg = OnnxSegmentation(model=model, select="motion", select_distance=0.4)
    tinfo, cfg = open_build_tour(demo_tour.out, overrides={"segmentation": seg_cfg.model_dump(mode="json")})
    assert tinfo.topics.image_kind != "labels"  # the camera images
    intr = tinfo.calibration.intrinsics
    odo = selection_odometry(tinfo, cfg)
    assert odo is not None
    worker = ImageWorker(tinfo.bag, tinfo.topics.image, seg_cfg, (intr.height, intr.width), odometry=odo)
    local = InProcessImages(tinfo.bag, tinfo.topics.image, seg_cfg, FrameSelector(seg_cfg, odo))
    try:
        worker.wait_ready()
        got: list = []
        while (a := worker.next()) is not None:
            b = local.next()
            assert type(a) is type(b) and a.stamp_ns == b.stamp_ns
            if not isinstance(a, SkippedFrame):
                assert a.instance is not None and np.array_equal(a.instance, b.instance)
                assert np.array_equal(a.label, b.label)
                worker.release(a)
            got.append(a)
        assert local.next() is None
        skipped = sum(isinstance(g, SkippedFrame) for g in got)
        assert 0 < skipped < len(got)
        assert worker.counts["skipped_frames"] == skipped and worker.counts["images"] == len(got) - skipped
    finally:
        worker.close()
        local.close()


# ---------------------------------------------------------------------------------------
# select: need, on a simulated room seen from a robot standing still


def _need_world(person_at):
    """Walls, a chair, and a person where ``person_at(t)`` says (None: nobody): the object table and labels."""
    from semmap.classes import load_class_table
    from semmap.sim.raycast import PartSet
    from semmap.sim.world import Person, chair, wall

    coco = load_class_table().names("coco")
    objs = [wall(1, 6.0, -6.0, 6.0, 6.0), wall(2, -6.0, 6.0, 6.0, 6.0), wall(3, -6.0, -6.0, 6.0, -6.0),
            chair(4, (3.5, -0.8, 0.0))]
    labels = np.array([0, 0, 0, coco.index("chair") + 1, coco.index("person") + 1], np.uint16)

    def at(t):
        parts = [p for o in objs for p in o.parts]
        owners = [i for i, o in enumerate(objs) for _ in o.parts]
        xy = person_at(t)
        if xy is not None:
            body = Person(5, "p", np.array([xy])).parts_at(0.0)
            parts += list(body)
            owners += [len(objs)] * len(body)
        return PartSet.build(parts, owners)

    return at, labels, coco


def _run_need(person_at, seconds=8.0, need_cells=2.0):
    """The frames (s) the need selector takes: scans at 10 Hz, frames at 5 Hz, a robot standing still."""
    from semmap.config import PaintConfig, SimCameraConfig, SimLidarConfig, SyncConfig
    from semmap.geometry import se3_from_xyz_rpy, se3_inverse
    from semmap.paint.need import NeedContext, NeedSelector
    from semmap.records import Calibration, CameraIntrinsics, Scan
    from semmap.sim.sensors import CameraSim, LidarSim

    lcfg = SimLidarConfig(sweep=False, noise_std=0.0, dropout_prob=0.0, rate_hz=10.0)
    ccfg = SimCameraConfig(noise_std=0.0)
    t_base_lidar = se3_from_xyz_rpy(lcfg.mount.xyz, lcfg.mount.rpy)
    calib = Calibration(CameraIntrinsics(640, 480, np.asarray(ccfg.K), np.zeros(5)),
                        se3_inverse(se3_from_xyz_rpy(ccfg.mount.xyz, ccfg.mount.rpy)) @ t_base_lidar)
    ctx = NeedContext("/scan", t_base_lidar, calib, PaintConfig(), SyncConfig(), 10.0, None)
    from semmap.segment.select import OdometrySource

    sel = NeedSelector(TopicSegmentation(select="need", need_cells=need_cells), OdometrySource("/odom"), ctx)
    lidar, cam = LidarSim(lcfg), CameraSim(ccfg, 2.6, np.random.default_rng(0))
    world, labels, coco = _need_world(person_at)
    taken = []
    for k in range(int(seconds * 10)):
        t = k / 10
        ps = world(t)
        sel.on_record("/odom", (int(t * S), "odom", "base", np.zeros(3)))
        r = lidar.cast(np.zeros(3), ps).ranges
        sel.on_record("/scan", Scan(int(t * S), "laser", lidar.angle_min, lidar.angle_increment, r.astype(np.float32),
                                    lcfg.range_min, lcfg.range_max))
        if k % 2 == 0 and sel.want(int(t * S)):  # a frame with every other scan
            frame = cam.render(np.zeros(3), ps, labels, np.random.default_rng(0))
            sel.segmented(Segmentation(int(t * S), frame.label, coco))
            taken.append(round(t, 1))
    return taken


def test_need_looks_again_only_until_a_place_is_decided():
    # the first frame labels the chair: furniture is decided on one frame's word; what the walls lack after one
    # frame (a tenth of a small thing's weight each) is less than need_cells
    assert _run_need(lambda t: None) == [0.0]
    # eager, the walls are looked at once more, once they have stood a second (two frames in a row), and no more
    assert _run_need(lambda t: None, need_cells=0.05) == [0.0, 1.0]


def test_need_looks_at_someone_who_stops_but_not_at_someone_walking_past():
    walker = _run_need(lambda t: (2.5, -3.0 + 1.2 * t) if 2.0 <= t < 7.0 else None)
    assert walker == [0.0]  # nobody stays on a cell for a second: the cleaning drops them unlabelled
    stander = _run_need(lambda t: (2.5, 0.6) if t >= 3.0 else None)
    assert stander[:2] == [0.0, 4.0]  # looked at once standing a second
    assert len(stander) <= 3
