"""Segmentation as users drive it: the mask cache, `semmap segment` → `folder` backend → `semmap build`,
a model backend in the build's frame worker, and `semmap eval-seg`'s protocol on a dataset whose
every number is known."""

import csv
import json
from typing import Literal

import cv2
import numpy as np
import pytest

from semmap.cli.main import main
from semmap.config import PLUGIN_SEGMENTATION, ModelSegmentationConfig, OnnxSegmentation, SegmentationConfig
from semmap.records import Image, Segmentation
from semmap.segment import base


class _CountingConfig(ModelSegmentationConfig):
    """A plugin backend's options: its own model, as each built-in backend has."""

    backend: Literal["test-counting"] = "test-counting"
    conf: float = 0.25


class _Counting:
    """A backend that labels bright pixels 1 and counts its calls."""

    name = "test-counting"
    consumes = "rgb"
    names = ("person",)
    calls = 0

    def __init__(self, cfg):
        self.cfg = cfg

    def segment(self, image):
        type(self).calls += 1
        on = (image.data[:, :, 0] > 128).astype(np.uint16)
        return Segmentation(image.stamp_ns, on, self.names, np.full(image.data.shape[:2], self.cfg.conf, np.float32),
                            instance=on * 7)

    def close(self):
        pass


@pytest.fixture
def counting_backend():
    base._load_backends()
    base.register("test-counting")(_Counting)
    _Counting.calls = 0
    yield _Counting
    base.SEGMENTERS.pop("test-counting", None)
    base.CONSUMES.pop("test-counting", None)
    PLUGIN_SEGMENTATION.pop("test-counting", None)


def _img(stamp, value=200):
    a = np.zeros((20, 30, 3), np.uint8)
    a[5:10, 5:20] = value
    return Image(stamp, "cam", a, "rgb8")


def test_mask_cache_serves_a_second_run_without_segmenting(tmp_path, counting_backend):
    cfg = _CountingConfig(cache_dir=tmp_path / "cache")
    seg = base.create_segmenter(cfg)
    first = [seg.segment(_img(s)) for s in (1, 2, 3)]
    seg.close()
    assert counting_backend.calls == 3
    seg = base.create_segmenter(cfg)
    again = [seg.segment(_img(s)) for s in (1, 2, 3)]
    assert counting_backend.calls == 3  # all three from the cache
    assert seg.hits == 3 and seg.names == ("person",)
    for a, b in zip(first, again):
        assert np.array_equal(a.label, b.label) and a.label.dtype == b.label.dtype == np.uint16
        assert np.array_equal(a.confidence, b.confidence)
        assert np.array_equal(a.instance, b.instance) and a.instance.max() == 7  # objects stay told apart
    # the same stamp with other pixels is segmented again, not served stale
    seg.segment(_img(2, value=90))
    assert counting_backend.calls == 4
    # another threshold is another model identity: its own folder
    seg2 = base.create_segmenter(cfg.model_copy(update={"conf": 0.5}))
    seg2.segment(_img(1))
    assert counting_backend.calls == 5
    assert len([d for d in (tmp_path / "cache").iterdir() if d.is_dir()]) == 2


def test_cache_key_follows_the_weights_file(tmp_path):
    from semmap.segment.cache import model_identity, model_key

    w = tmp_path / "m.onnx"
    w.write_bytes(b"one")
    k1 = model_key(model_identity(OnnxSegmentation(model=w), tmp_path))
    w.write_bytes(b"two")
    k2 = model_key(model_identity(OnnxSegmentation(model=w), tmp_path))
    assert k1 != k2 and k1.startswith("onnx-")


def test_unknown_backend_lists_the_available_ones():
    from semmap.errors import ConfigError

    with pytest.raises(ConfigError, match="mediapipe-selfie.*onnx.*sam3"):
        base.create_segmenter(SegmentationConfig(backend="yolo"))


# ---------------------------------------------------------------------------------------
# segment → folder → build, and a model backend in the build's frame worker


@pytest.fixture(scope="module")
def ros1_tour(tmp_path_factory, short_demo_world):
    from semmap.sim.tour import simulate

    return simulate(short_demo_world, tmp_path_factory.mktemp("tour") / "demo", fmt="ros1", seed=3)


@pytest.fixture(scope="module")
def semantic_onnx(tmp_path_factory):
    pytest.importorskip("onnxruntime")
    from test_segment_yolo import _semantic_model

    return _semantic_model(tmp_path_factory.mktemp("onnx") / "semantic.onnx")


def test_segment_a_bag_then_build_from_the_label_folder(ros1_tour, tmp_path, capsys):
    from semmap.pipeline import build

    out = tmp_path / "seg"
    assert main(["segment", str(ros1_tour.out), "--backend", "topic", "--out", str(out)]) == 0
    assert "images" in capsys.readouterr().out
    labels = sorted((out / "labels").glob("*.png"))
    summary = json.loads((out / "summary.json").read_text())
    assert len(labels) == summary["images"] == 40  # 8 s at 5 Hz
    assert len(list((out / "overlays").glob("*.jpg"))) == 40
    lab = cv2.imread(str(labels[10]), cv2.IMREAD_UNCHANGED)
    assert lab.dtype == np.uint16 and lab.shape == (480, 640)
    names = json.loads((out / "classes.json").read_text())["names"]
    assert names[0] == "person" and len(names) == 80
    assert summary["pixel_share"]  # the demo tour's camera sees furniture and people

    ref = build(ros1_tour.out, tmp_path / "map_topic", overrides={"workers": False})
    folder = build(ros1_tour.out, tmp_path / "map_folder",
                   overrides={"workers": False, "segmentation": {"backend": "folder", "folder": str(out / "labels")}})
    # the folder backend reads the camera topic's stamps: the same frames, the same painting
    assert folder.summary.painting.scans_painted == ref.summary.painting.scans_painted > 0
    assert folder.summary.painting.hits_by_class == ref.summary.painting.hits_by_class


def test_segment_limit_counts_every_image_tried_and_repeated_warnings_are_counted(ros1_tour, tmp_path, caplog):
    """A label folder that covers 2 of 40 frames: --limit 10 tries 10 images, not the whole bag; three
    warnings name the first skipped images and one counts them all; summary.json has the reasons."""
    import shutil

    full = tmp_path / "full"
    assert main(["segment", str(ros1_tour.out), "--backend", "topic", "--out", str(full), "--no-overlays",
                 "-q"]) == 0
    few = tmp_path / "few"
    few.mkdir()
    for png in sorted((full / "labels").glob("*.png"))[:2]:
        shutil.copy(png, few)
    shutil.copy(full / "classes.json", few)
    caplog.clear()
    out = tmp_path / "seg"
    assert main(["segment", str(ros1_tour.out), "--backend", "folder", "--folder", str(few), "--out", str(out),
                 "--limit", "10", "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["images"] == 2 and summary["bad_images"] == 8
    assert summary["skipped_because"] == {f"{few}: no label image for stamp N": 8}
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 4 and "8 images skipped in all" in warnings[-1]


def test_build_runs_a_model_backend_in_its_worker_and_a_rebuild_uses_the_cache(ros1_tour, semantic_onnx, tmp_path):
    from semmap.pipeline import build

    cache = tmp_path / "cache"
    seg = {"backend": "onnx", "model": str(semantic_onnx), "cache_dir": str(cache)}
    first = build(ros1_tour.out, tmp_path / "m1", overrides={"segmentation": seg})
    entries = sorted(cache.glob("onnx-*/*.npz"))
    assert first.summary.counts.images == len(entries) == 40
    assert first.summary.painting.backend == "onnx"
    assert first.summary.cpu_s["images"] > 0  # the model ran in the image worker
    assert set(first.summary.painting.hits_by_class) <= {"person", "chair"}
    mtimes = [p.stat().st_mtime_ns for p in entries]
    second = build(ros1_tour.out, tmp_path / "m2", overrides={"segmentation": seg})
    assert [p.stat().st_mtime_ns for p in sorted(cache.glob("onnx-*/*.npz"))] == mtimes  # nothing segmented again
    assert second.summary.painting.hits_by_class == first.summary.painting.hits_by_class


def test_a_rebuild_with_a_frame_selection_runs_no_model_either(ros1_tour, semantic_onnx, tmp_path):
    from semmap.pipeline import build

    cache = tmp_path / "cache"
    seg = {"backend": "onnx", "model": str(semantic_onnx), "cache_dir": str(cache), "select": "need",
           "max_frames": 30}
    first = build(ros1_tour.out, tmp_path / "m1", overrides={"segmentation": seg})
    fs = first.summary.painting.frame_selection
    entries = sorted(cache.glob("onnx-*/*.npz"))
    assert fs.frames_segmented == len(entries) <= 30 and fs.frames_skipped > 0
    mtimes = [p.stat().st_mtime_ns for p in entries]
    second = build(ros1_tour.out, tmp_path / "m2", overrides={"segmentation": seg, "cleaning": {"person_radius": 0.3}})
    assert [p.stat().st_mtime_ns for p in sorted(cache.glob("onnx-*/*.npz"))] == mtimes  # nothing segmented again
    assert second.summary.painting.frame_selection == fs  # the same frames, from the cache


def test_a_model_time_budget_is_kept_and_a_rebuild_selects_the_same_frames_from_the_cache(ros1_tour, semantic_onnx,
                                                                                           tmp_path):
    from semmap.pipeline import build

    cache = tmp_path / "cache"
    build(ros1_tour.out, tmp_path / "m0", overrides={"segmentation": {
        "backend": "onnx", "model": str(semantic_onnx), "cache_dir": str(tmp_path / "probe")}})
    times = [float(np.load(p)["model_seconds"]) for p in (tmp_path / "probe").glob("*/*.npz")]
    # about fifteen frames' worth of model time, of the 40, and room for a slow first frame: another run's first
    # inference (the runtime warming up) took 15 ms where the others take under 2 ms, and alone spent the budget
    budget = 15 * float(np.median(times)) + 2 * max(times)
    seg = {"backend": "onnx", "model": str(semantic_onnx), "cache_dir": str(cache), "max_seconds": budget}
    first = build(ros1_tour.out, tmp_path / "m1", overrides={"segmentation": seg})
    fs = first.summary.painting.frame_selection
    entries = sorted(cache.glob("onnx-*/*.npz"))
    assert fs.max_seconds == budget and fs.frames_segmented == len(entries) and fs.frames_skipped > 0
    spent = sum(float(np.load(p)["model_seconds"]) for p in entries)
    assert spent <= budget + max(float(np.load(p)["model_seconds"]) for p in entries)  # one frame over at most
    assert 2 <= fs.frames_segmented < 40
    mtimes = [p.stat().st_mtime_ns for p in entries]
    second = build(ros1_tour.out, tmp_path / "m2", overrides={"segmentation": seg})
    assert [p.stat().st_mtime_ns for p in sorted(cache.glob("onnx-*/*.npz"))] == mtimes  # no model ran
    assert second.summary.painting.frame_selection == fs  # the cached frames' own times spent the same budget


# ---------------------------------------------------------------------------------------
# eval-seg's protocol on a dataset built here


def _square(x0, y0, x1, y1):
    return [x0, y0, x1, y0, x1, y1, x0, y1]


def _write_dataset(root):
    """Three 40x40 images: (1) a person; (2) a person and a chair; (3) nothing."""
    (root / "images" / "val").mkdir(parents=True)
    (root / "labels" / "val").mkdir(parents=True)
    objs = {1: [(0, _square(0.1, 0.1, 0.5, 0.6))],
            2: [(0, _square(0.5, 0.5, 0.9, 0.9)), (56, _square(0.05, 0.05, 0.3, 0.3))],
            3: []}
    for i, lst in objs.items():
        cv2.imwrite(str(root / "images" / "val" / f"{i:012d}.png"), np.zeros((40, 40, 3), np.uint8))
        if lst:
            (root / "labels" / "val" / f"{i:012d}.txt").write_text(
                "\n".join(f"{c} " + " ".join(f"{v:.3f}" for v in pts) for c, pts in lst) + "\n")
    return objs


def test_eval_seg_protocol_counts_every_pixel(tmp_path, capsys):
    from semmap.segment.evaluate import rasterize_polygons

    data = tmp_path / "data"
    _write_dataset(data)
    gt = {i: rasterize_polygons(data / "labels" / "val" / f"{i:012d}.txt"
                                if i < 3 else None, 40, 40, 80) for i in (1, 2, 3)}
    pred_dir = tmp_path / "pred"
    pred_dir.mkdir()
    (pred_dir / "classes.json").write_text(json.dumps({"names": ["person", "chair"]}))
    p1 = np.zeros((40, 40), np.uint16)
    p1[np.roll(gt[1][0], 5, axis=0)] = 1  # the person, 5 px too low
    p2 = np.zeros((40, 40), np.uint16)
    p2[gt[2][0]] = 1  # the person exactly; the chair missed
    p3 = np.zeros((40, 40), np.uint16)
    p3[30:32, 30:35] = 2  # a chair where there is none: a false positive of 10 px
    for i, p in ((1, p1), (2, p2), (3, p3)):
        cv2.imwrite(str(pred_dir / f"{i:012d}.png"), p)

    g1, s1 = gt[1][0], np.roll(gt[1][0], 5, axis=0)
    i1, u1 = int((g1 & s1).sum()), int((g1 | s1).sum())
    b, c = int(gt[2][0].sum()), int(gt[2][56].sum())
    person_iou = (i1 + b) / (u1 + b)
    person_dice = 2 * (i1 + b) / (int(s1.sum()) + int(g1.sum()) + 2 * b)

    out = tmp_path / "eval"
    assert main(["eval-seg", str(data), "--backend", "folder", "--folder", str(pred_dir), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| folder |" in printed
    with open(out / "metrics.csv") as fh:
        rows = {r["class"]: r for r in csv.DictReader(fh)}
    assert float(rows["person"]["iou"]) == pytest.approx(person_iou, abs=1e-4)
    assert float(rows["person"]["dice"]) == pytest.approx(person_dice, abs=1e-4)
    assert float(rows["person"]["image_iou"]) == pytest.approx((i1 / u1 + 1.0) / 2, abs=1e-4)
    assert int(rows["person"]["images"]) == 2 and int(rows["person"]["fp_images"]) == 0
    assert float(rows["chair"]["iou"]) == 0.0 and int(rows["chair"]["images"]) == 1
    assert int(rows["chair"]["fp_images"]) == 1  # image 3
    assert float(rows["ALL"]["iou"]) == pytest.approx((person_iou + 0.0) / 2, abs=1e-4)
    assert c > 0 and (out / "chart.png").stat().st_size > 10_000


def test_eval_seg_compares_backends_side_by_side(tmp_path, counting_backend):
    from semmap.segment.evaluate import evaluate_segmentation

    data = tmp_path / "data"
    _write_dataset(data)
    res = evaluate_segmentation(data, [_CountingConfig(), _CountingConfig(conf=0.9)],
                                labels=["a", "b"])
    assert [b.label for b in res.backends] == ["a", "b"]
    assert all(b.images == 3 and b.fps > 0 for b in res.backends)
    assert res.backends[0].per_class()["person"].iou == 0.0  # black images: nothing bright, nothing found
    assert "| a | 0.000 |" in res.table()
