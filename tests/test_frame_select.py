"""Frame selection (``segmentation.select``): which camera frames the model runs on, and how the scans
paired with the others are labelled."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semmap.config import OnnxSegmentation, TopicSegmentation
from semmap.paint.painter import LabelMemory
from semmap.records import Mobility
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


def test_the_label_memory_takes_each_cells_majority_and_leaves_unseen_cells_unknown():
    mem = LabelMemory(0.05)
    xy = np.array([[1.01, 1.01], [1.02, 1.03], [1.04, 1.01], [2.0, 2.0]])
    mob = np.array([Mobility.DYNAMIC, Mobility.DYNAMIC, Mobility.STATIC, Mobility.SEMI_STATIC], np.uint8)
    cls = np.array([0, 0, -1, 3], np.int16)
    mem.add(10, xy[:2], mob[:2], cls[:2])
    mem.add(10, xy[2:], mob[2:], cls[2:])  # a second scan painted from the same frame
    found, m, c = mem.lookup(np.array([[1.03, 1.04], [2.01, 2.02], [3.0, 3.0], [-1.01, -1.01]]))
    assert found.tolist() == [True, True, False, False]
    assert m.tolist() == [Mobility.DYNAMIC, Mobility.SEMI_STATIC, 0, 0] and c.tolist() == [0, 3, -1, -1]
    mem.add(20, xy[3:], mob[3:], cls[3:])  # a new segmented frame: the memory starts afresh
    assert mem.lookup(xy[:1])[0].tolist() == [False]


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
    local = InProcessImages(tinfo.bag, tinfo.topics.image, seg_cfg, odo)
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
