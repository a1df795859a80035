"""YOLO-seg decoding (letterbox, NMS, masks) on tensors built by hand, and the onnx backend on tiny
ONNX graphs, so every pixel of the expected label image is known."""

import os
from pathlib import Path

import numpy as np
import pytest

from semmap.config import OnnxSegmentation
from semmap.records import Image
from semmap.segment.yolo import decode_detections, letterbox, nms, yolo_seg_postprocess

NC, NM = 2, 2  # classes (person, chair), mask coefficients


def _candidate(cx, cy, w, h, cls, score, coef):
    col = np.zeros(4 + NC + NM, np.float32)
    col[:4] = (cx, cy, w, h)
    col[4 + cls] = score
    col[4 + NC:] = coef
    return col


def _protos(left_only: bool = False) -> np.ndarray:
    """16x16 prototypes for a 64x64 input: channel 0 = +10 (or +10 left half, -10 right), channel 1 = 0."""
    p = np.zeros((1, NM, 16, 16), np.float32)
    p[0, 0] = 10.0
    if left_only:
        p[0, 0, :, 8:] = -10.0
    return p


def test_letterbox_centres_a_wide_image_and_records_the_geometry():
    img = np.full((32, 64, 3), 200, np.uint8)
    x, lb = letterbox(img, (64, 64))
    assert x.shape == (1, 3, 64, 64) and x.dtype == np.float32
    assert (lb.scale, lb.left, lb.top) == (1.0, 0, 16)
    assert np.allclose(x[0, :, 16:48], 200 / 255) and np.allclose(x[0, :, :16], 114 / 255)


def test_nms_keeps_the_best_of_overlapping_boxes():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30]], float)
    keep = nms(boxes, np.array([0.9, 0.8, 0.7]), 0.5)
    assert keep.tolist() == [0, 2]


def test_raw_head_decoding_thresholds_and_nms_per_class():
    cands = np.stack([
        _candidate(20, 32, 16, 8, 0, 0.9, (1, 0)),   # person
        _candidate(21, 32, 16, 8, 0, 0.6, (1, 0)),   # duplicate person: suppressed
        _candidate(21, 32, 16, 8, 1, 0.5, (1, 0)),   # a chair in the same place: another class, kept
        _candidate(50, 10, 4, 4, 1, 0.1, (1, 0)),    # below conf
    ], axis=1)[None]  # [1, 4+nc+nm, N]
    det = decode_detections(cands, NC, NM, conf=0.25, iou=0.7)
    assert len(det) == 2
    assert det.classes.tolist() == [0, 1]
    assert np.allclose(det.scores, [0.9, 0.5])
    assert np.allclose(det.boxes[0], [12, 28, 28, 36])


def test_mask_of_an_instance_is_its_box_in_image_pixels():
    """A mask that is on everywhere, cropped to a box, lands exactly on the box in the
    original image (letterbox undone: 64x32 image in a 64x64 input, 16 px pad on top)."""
    out0 = np.stack([_candidate(20, 32, 16, 8, 0, 0.9, (1, 0))], axis=1)[None]
    _, lb = letterbox(np.zeros((32, 64, 3), np.uint8), (64, 64))
    label, conf, _, _ = yolo_seg_postprocess(out0, _protos(), lb, NC)
    assert label.shape == (32, 64) and label.dtype == np.uint16
    rows, cols = np.nonzero(label)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (12, 19, 12, 27)
    assert np.count_nonzero(label == 1) == 16 * 8
    assert np.allclose(conf[label == 1], 0.9) and np.all(conf[label == 0] == 0)


def test_mask_follows_the_prototypes_inside_the_box():
    """Prototypes on in the left half of the input only: a box across the middle is labelled
    up to the image column where the bilinear mask crosses 0.5 (x = 32 px)."""
    out0 = np.stack([_candidate(28, 32, 32, 8, 1, 0.8, (1, 0))], axis=1)[None]  # x 12..44
    _, lb = letterbox(np.zeros((32, 64, 3), np.uint8), (64, 64))
    label, _, _, _ = yolo_seg_postprocess(out0, _protos(left_only=True), lb, NC)
    cols = np.nonzero(label.any(0))[0]
    assert (cols.min(), cols.max()) == (12, 31)
    assert set(np.unique(label)) == {0, 2}  # chair = names[1] → label 2


def test_overlapping_instances_the_better_score_wins():
    out0 = np.stack([_candidate(20, 32, 16, 8, 0, 0.6, (1, 0)),
                     _candidate(30, 32, 16, 8, 1, 0.9, (1, 0))], axis=1)[None]
    _, lb = letterbox(np.zeros((32, 64, 3), np.uint8), (64, 64))
    label, _, _, _ = yolo_seg_postprocess(out0, _protos(), lb, NC, iou=0.99)
    assert label[15, 25] == 2  # the overlap belongs to the chair (0.9)
    assert label[15, 14] == 1


def test_two_touching_objects_of_one_class_are_two_instances():
    """Two chairs whose masks touch: one connected region of the chair label, two instances, split where
    the better-scoring one takes over."""
    out0 = np.stack([_candidate(20, 32, 16, 8, 1, 0.6, (1, 0)),
                     _candidate(34, 32, 16, 8, 1, 0.9, (1, 0))], axis=1)[None]  # x 12..28 and 26..42
    _, lb = letterbox(np.zeros((32, 64, 3), np.uint8), (64, 64))
    label, _, instance, det = yolo_seg_postprocess(out0, _protos(), lb, NC, iou=0.99)
    assert len(det) == 2 and set(np.unique(label)) == {0, 2}
    assert instance.dtype == np.uint16 and np.array_equal(instance > 0, label > 0)
    better = int(np.argmax(det.scores)) + 1
    assert instance[15, 14] == 3 - better and instance[15, 27] == better and instance[15, 40] == better


def test_end_to_end_layout_needs_no_nms():
    """YOLO26's end2end export: [1, N, 6 + nm] rows of x1 y1 x2 y2 score class coefficients."""
    rows = np.array([[12, 28, 28, 36, 0.9, 1, 1, 0], [0, 0, 4, 4, 0.1, 0, 1, 0]], np.float32)[None]
    _, lb = letterbox(np.zeros((32, 64, 3), np.uint8), (64, 64))
    label, _, _, det = yolo_seg_postprocess(rows, _protos(), lb, NC)
    assert len(det) == 1 and np.count_nonzero(label == 2) == 16 * 8


# ---------------------------------------------------------------------------------------
# The onnx backend on tiny graphs


def _instance_model(path: Path) -> Path:
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    out0 = np.stack([_candidate(20, 32, 16, 8, 0, 0.9, (1, 0))], axis=1)[None]
    nodes = [helper.make_node("Constant", [], ["output0"], value=numpy_helper.from_array(out0)),
             helper.make_node("Constant", [], ["output1"], value=numpy_helper.from_array(_protos()))]
    graph = helper.make_graph(
        nodes, "tiny-yolo-seg", [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 64, 64])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(out0.shape)),
         helper.make_tensor_value_info("output1", TensorProto.FLOAT, [1, NM, 16, 16])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    for k, v in {"names": "{0: 'person', 1: 'chair'}", "task": "segment", "stride": "32",
                 "imgsz": "[64, 64]"}.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=v))
    onnx.save(model, str(path))
    return path


def _semantic_model(path: Path) -> Path:
    """A 1x1 convolution: scores (background 0.3, person = red, chair = green)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper, numpy_helper

    w = np.zeros((3, 3, 1, 1), np.float32)
    w[1, 0], w[2, 1] = 1.0, 1.0
    b = np.array([0.3, 0, 0], np.float32)
    graph = helper.make_graph(
        [helper.make_node("Conv", ["input", "w", "b"], ["scores"])], "tiny-semantic",
        [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 3, 8, 8])],
        [helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1, 3, 8, 8])],
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    model.metadata_props.append(onnx.StringStringEntryProto(key="names",
                                                            value='["background", "person", "chair"]'))
    onnx.save(model, str(path))
    return path


def test_onnx_backend_decodes_an_instance_model_with_names_from_metadata(tmp_path):
    pytest.importorskip("onnxruntime")
    from semmap.segment.base import create_segmenter

    seg = create_segmenter(OnnxSegmentation(model=_instance_model(tmp_path / "m.onnx")))
    assert seg.names == ("person", "chair")
    res = seg.segment(Image(7, "cam", np.zeros((32, 64, 3), np.uint8), "rgb8"))
    assert res.stamp_ns == 7 and res.label.shape == (32, 64)
    assert np.count_nonzero(res.label == 1) == 16 * 8
    seg.close()


def test_onnx_backend_reads_a_semantic_class_map(tmp_path):
    pytest.importorskip("onnxruntime")
    from semmap.segment.base import create_segmenter

    seg = create_segmenter(OnnxSegmentation(model=_semantic_model(tmp_path / "s.onnx")))
    assert seg.names == ("person", "chair")  # background is label 0
    img = np.zeros((16, 16, 3), np.uint8)
    img[:, :8, 0] = 255  # left: red → person
    img[:8, 8:, 1] = 255  # top right: green → chair; bottom right black → background
    res = seg.segment(Image(1, "cam", img, "rgb8"))
    assert np.all(res.label[:, :8] == 1) and np.all(res.label[:8, 8:] == 2) and np.all(res.label[8:, 8:] == 0)
    assert res.confidence is not None and np.all(res.confidence[res.label == 0] == 0)


def test_onnx_backend_errors_name_the_config_key(tmp_path):
    from semmap.errors import ConfigError
    from semmap.segment.base import create_segmenter

    with pytest.raises(ConfigError, match="segmentation.model"):
        create_segmenter(OnnxSegmentation())
    with pytest.raises(ConfigError, match="no such file"):
        create_segmenter(OnnxSegmentation(model=tmp_path / "missing.onnx"))


@pytest.mark.skipif(not os.environ.get("SEMMAP_YOLO_ONNX"), reason="set SEMMAP_YOLO_ONNX to an exported "
                    "yolo11n-seg.onnx (see tools/bench_segment.py)")
def test_a_real_yolo11n_seg_export_has_the_documented_outputs():
    pytest.importorskip("onnxruntime")
    from semmap.segment.base import create_segmenter

    seg = create_segmenter(OnnxSegmentation(model=Path(os.environ["SEMMAP_YOLO_ONNX"])))
    assert len(seg.names) == 80 and seg.names[0] == "person"
    sess = seg._load()
    outs = {o.name: o.shape for o in sess.get_outputs()}
    assert outs["output0"][1] == 4 + 80 + 32 and outs["output1"][1] == 32
    res = seg.segment(Image(1, "cam", np.zeros((480, 640, 3), np.uint8), "rgb8"))
    assert res.label.shape == (480, 640)
