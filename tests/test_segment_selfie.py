"""The real pretrained MediaPipe selfie model on the COCO128 person images (the research's Table I
protocol, person class): about 0.57 IoU over the 61 images that contain people."""

import numpy as np
import pytest

from semmap.config import SelfieSegmentation
from semmap.records import Image

pytest.importorskip("ai_edge_litert")


def test_selfie_person_iou_on_coco128(data_dir, tmp_path):
    from semmap.segment.evaluate import evaluate_segmentation, write_eval_outputs

    cfg = SelfieSegmentation(model=data_dir / "models" / "selfie_segmentation.tflite")
    res = evaluate_segmentation(data_dir / "coco128-seg", [cfg])
    b = res.backends[0]
    person = b.per_class()["person"]
    assert res.images == 128 and person.images == 61
    assert [c.name for c in b.classes] == ["person"]
    assert 0.54 <= person.iou <= 0.60  # reference ≈ 0.57
    assert 0.69 <= person.dice <= 0.76
    assert person.iou_fp < person.iou  # false positives on people-free images count in the strict figure
    assert b.fps > 0  # its speed target (≥ 20 FPS) is checked by tools/bench_segment.py
    paths = write_eval_outputs(res, tmp_path)
    assert "| mediapipe-selfie:selfie_segmentation | 0.5" in paths["table"].read_text()
    assert paths["chart"].stat().st_size > 10_000


def test_selfie_labels_are_person_with_its_probability(data_dir):
    import cv2

    from semmap.segment.base import create_segmenter

    seg = create_segmenter(SelfieSegmentation(model=data_dir / "models" / "selfie_segmentation.tflite"))
    assert seg.names == ("person",)
    img = cv2.imread(str(data_dir / "coco128-seg" / "images" / "train2017" / "000000000061.jpg"))[:, :, ::-1]
    res = seg.segment(Image(61, "cam", np.ascontiguousarray(img), "rgb8"))
    assert res.label.shape == img.shape[:2] and set(np.unique(res.label)) <= {0, 1}
    assert res.confidence is not None
    assert np.all(res.confidence[res.label == 1] > 0.5) and np.all(res.confidence[res.label == 0] == 0)
    seg.close()
