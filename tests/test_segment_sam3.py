"""SAM 3 with a tiny random-weight config: the cached-embedding path gives the same masks as the
uncached one, the image is encoded once per frame whatever the number of prompts, and the input
resolution shrinks to fit the memory budget."""

import numpy as np
import pytest

from semmap.config import SegmentationConfig
from semmap.records import Image

pytest.importorskip("torch")
pytest.importorskip("transformers")

PROMPTS = ("person", "chair", "dining table", "potted plant")


@pytest.fixture(scope="module")
def tiny_sam3(tmp_path_factory):
    from semmap.segment.sam3 import save_random_model

    return save_random_model(tmp_path_factory.mktemp("sam3") / "tiny", "tiny", seed=1)


def _frame(seed=0, stamp=1):
    rng = np.random.default_rng(seed)
    return Image(stamp, "cam", rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), "rgb8")


def test_cached_embedding_gives_the_same_masks_as_the_uncached_path(tiny_sam3):
    from semmap.segment.base import create_segmenter

    seg = create_segmenter(SegmentationConfig(backend="sam3", model=tiny_sam3, prompts=PROMPTS, conf=0.0))
    assert seg.names == PROMPTS
    img = _frame()
    cached = seg.segment(img)
    uncached = seg.segment_uncached(img)
    assert cached.label.shape == (120, 160)
    assert len(np.unique(cached.label)) >= 2  # random weights still paint something at conf 0
    assert np.array_equal(cached.label, uncached.label)
    assert np.allclose(cached.confidence, uncached.confidence, atol=1e-6)
    seg.close()


def test_the_image_is_encoded_once_per_frame_and_the_decoder_once_per_prompt(tiny_sam3):
    from semmap.segment.sam3 import Sam3Segmenter

    seg = Sam3Segmenter(SegmentationConfig(backend="sam3", model=tiny_sam3, prompts=PROMPTS))
    a = seg.segment(_frame(0, 1))
    b = seg.segment(_frame(0, 1))  # the same frame again: its embedding is reused
    seg.segment(_frame(1, 2))
    assert seg.stats == {"embeddings": 2, "embedding_reuses": 1, "decoder_runs": 3 * len(PROMPTS)}
    assert np.array_equal(a.label, b.label)


def test_input_resolution_scales_to_the_memory_budget(tiny_sam3):
    from semmap.segment.sam3 import Sam3Segmenter

    sides = []
    for budget in (1000.0, 3.0, 1.0, 0.5):
        seg = Sam3Segmenter(SegmentationConfig(backend="sam3", model=tiny_sam3, prompts=PROMPTS, imgsz=448,
                                               memory_budget_mb=budget))
        side = seg.input_side
        assert side % 28 == 0 and seg.activation_mb(side) <= budget or side == 28
        res = seg.segment(_frame())  # every chosen resolution runs (rotary positions follow it)
        assert res.label.shape == (120, 160)
        sides.append(side)
    assert sides[0] == 448 and sides == sorted(sides, reverse=True) and sides[-1] < 224


def test_missing_model_folder_is_a_config_error(tmp_path):
    from semmap.errors import ConfigError
    from semmap.segment.base import create_segmenter

    with pytest.raises(ConfigError, match="segmentation.model"):
        create_segmenter(SegmentationConfig(backend="sam3", model=tmp_path / "nope"))
