"""SAM 3 with a tiny random-weight config: the cached-embedding path gives the same masks as the
uncached one, the image is encoded once per frame whatever the number of prompts, batched prompts
give what one prompt at a time gives, painting at mask resolution equals upsampling every mask
(nearest) first, a prompt that keeps nothing skips the mask head, and the input resolution and the
prompt batch shrink to fit the memory budget."""

import math

import numpy as np
import pytest

from semmap.config import Sam3Segmentation
from semmap.records import Image

pytest.importorskip("torch")
pytest.importorskip("transformers")

PROMPTS = ("person", "chair", "dining table", "potted plant")


@pytest.fixture(scope="module")
def tiny_sam3(tmp_path_factory):
    from sam3_helpers import save_random_model

    return save_random_model(tmp_path_factory.mktemp("sam3") / "tiny", "tiny", seed=1)


def _frame(seed=0, stamp=1):
    rng = np.random.default_rng(seed)
    return Image(stamp, "cam", rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), "rgb8")


def test_cached_embedding_gives_the_same_masks_as_the_uncached_path(tiny_sam3):
    from semmap.segment.base import create_segmenter

    seg = create_segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS, conf=0.0))
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

    seg = Sam3Segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS))
    a = seg.segment(_frame(0, 1))
    b = seg.segment(_frame(0, 1))  # the same frame again: its embedding is reused
    seg.segment(_frame(1, 2))
    assert seg.stats == {"embeddings": 2, "embedding_reuses": 1, "decoder_runs": 3 * len(PROMPTS),
                         "mask_heads": 3 * len(PROMPTS),  # random weights: every prompt keeps some query
                         "decoder_calls": 3 if seg.prompt_batch() > 1 else 3 * len(PROMPTS)}
    assert np.array_equal(a.label, b.label)


def test_batched_prompts_give_what_one_prompt_at_a_time_gives(tiny_sam3, monkeypatch):
    import torch

    from semmap.segment.sam3 import Sam3Segmenter

    seg = Sam3Segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS, conf=0.0, threads=2))
    assert seg.prompt_batch() == len(PROMPTS)  # the tiny model's passes fit the default budget together
    img = _frame(4)
    together = seg.segment(img)
    # the DETR encoder with its first self-attention shared across the batch is the library's own
    with torch.inference_mode():
        embed = seg.image_embedding(img.data)
        features = torch.cat([t.pooler_output for t, _, _ in seg._text])
        mask = torch.cat([m for _, m, _ in seg._text]).bool()
        ours, _, _ = seg._encode(embed, features, mask)
        n = len(PROMPTS)
        ref = seg._model.detr_encoder(vision_features=[embed.fpn_hidden_states[-2].expand(n, -1, -1, -1)],
                                      text_features=features, text_mask=mask,
                                      vision_pos_embeds=[embed.fpn_position_encoding[-2].expand(n, -1, -1, -1)])
    assert torch.allclose(ours, ref.last_hidden_state, atol=1e-5)
    seg.stats.update(decoder_calls=0, decoder_runs=0)
    monkeypatch.setattr(seg, "prompt_batch", lambda: 3)  # a budget that holds three passes: 3 + 1
    apart = seg.segment(img)
    assert seg.stats["decoder_calls"] == 2 and seg.stats["decoder_runs"] == len(PROMPTS)
    monkeypatch.setattr(seg, "prompt_batch", lambda: 1)
    single = seg.segment(img)
    for res in (apart, single):
        assert np.array_equal(res.label, together.label) and np.array_equal(res.instance, together.instance)
        assert np.allclose(res.confidence, together.confidence, atol=1e-6)
    assert len(np.unique(together.label)) >= 3


def test_the_prompt_batch_shrinks_with_the_memory_budget(tiny_sam3):
    from semmap.segment.sam3 import Sam3Segmenter

    seg = Sam3Segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS, imgsz=112, threads=2))
    per = seg.decoder_mb(seg.input_side)
    for fits, want in ((10.0, len(PROMPTS)), (2.5, 2), (0.1, 1)):
        seg.cfg = seg.cfg.model_copy(update={"memory_budget_mb": fits * per})
        assert seg.prompt_batch() == want
    threads = seg._torch.get_num_threads()
    seg._torch.set_num_threads(1)  # one thread: a prompt at a time, however much memory there is
    try:
        seg.cfg = seg.cfg.model_copy(update={"memory_budget_mb": 10.0 * per})
        assert seg.prompt_batch() == 1
    finally:
        seg._torch.set_num_threads(threads)


def _full_resolution_reference(seg, img):
    """The per-prompt merge this backend had before: every kept mask upsampled to image size, then
    each pixel takes its best-scoring covering instance (here with nearest-exact upsampling)."""
    import torch

    h, w = img.data.shape[:2]
    label = np.zeros((h, w), np.uint16)
    conf = np.zeros((h, w), np.float32)
    instance = np.zeros((h, w), np.uint16)
    seen = 0
    t = seg.cfg.mask_threshold
    with torch.inference_mode():
        for k, (_, mask, ids) in enumerate(seg._text, start=1):
            out = seg._model(pixel_values=seg.pixel_values(img.data), input_ids=ids, attention_mask=mask)
            scores = out.pred_logits[0].sigmoid() * out.presence_logits[0].sigmoid()
            keep = torch.nonzero(scores >= seg.cfg.conf).flatten()
            if keep.numel() == 0:
                continue
            keep = keep[torch.argsort(scores[keep], descending=True)][: seg.cfg.max_det]
            masks = torch.nn.functional.interpolate(out.pred_masks[0, keep][None].float(), size=(h, w),
                                                    mode="nearest-exact")[0]
            on = masks > math.log(t / (1 - t))
            first = on.to(torch.uint8).argmax(0).numpy()
            best = scores[keep].numpy()[first]
            upd = on.any(0).numpy() & (best > conf)
            label[upd] = k
            conf[upd] = best[upd]
            instance[upd] = seen + 1 + first[upd]  # instances numbered across the prompts
            seen += keep.numel()
    return label, conf, instance


@pytest.mark.parametrize("mask_threshold,max_det", [(0.5, 300), (0.4999, 3)])
def test_painting_at_mask_resolution_equals_upsampling_every_mask_first(tiny_sam3, mask_threshold, max_det):
    from semmap.segment.sam3 import Sam3Segmenter

    seg = Sam3Segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS, conf=0.0,
                                           mask_threshold=mask_threshold, max_det=max_det))
    img = _frame(3)
    res = seg.segment(img)
    label, conf, instance = _full_resolution_reference(seg, img)
    assert len(np.unique(label)) >= 3
    assert np.array_equal(res.label, label)
    assert np.allclose(res.confidence, conf, atol=1e-6)  # batched matrix products round differently
    assert np.array_equal(res.instance, instance) and len(np.unique(instance)) > len(np.unique(label))


def test_a_prompt_that_keeps_no_query_skips_the_mask_head(tiny_sam3):
    import torch

    from semmap.segment.sam3 import Sam3Segmenter

    seg = Sam3Segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS, conf=1.0))
    img = _frame()
    res = seg.segment(img)
    assert seg.stats["decoder_runs"] == len(PROMPTS) and seg.stats["mask_heads"] == 0
    assert not res.label.any() and np.array_equal(res.label, seg.segment_uncached(img).label)
    # a threshold between the prompts' best scores: some prompts keep queries, the others skip the head
    with torch.inference_mode():
        embed = seg.image_embedding(img.data)
        best = sorted(float(seg._decode(embed, text, mask)[0].max()) for text, mask, _ in seg._text)
    assert best[0] < best[-1]
    seg.cfg = seg.cfg.model_copy(update={"conf": (best[0] + best[-1]) / 2})
    seg.stats["mask_heads"] = 0
    cached = seg.segment(img)
    assert 0 < seg.stats["mask_heads"] < len(PROMPTS)
    assert cached.label.any()
    assert np.array_equal(cached.label, seg.segment_uncached(img).label)
    # (the batched and the one-by-one decoder passes round differently on some CPUs' kernels)
    assert np.allclose(cached.confidence, seg.segment_uncached(img).confidence, atol=1e-6)


def test_input_resolution_scales_to_the_memory_budget(tiny_sam3):
    from semmap.segment.sam3 import Sam3Segmenter

    sides = []
    for budget in (1000.0, 3.0, 1.0, 0.5):
        seg = Sam3Segmenter(Sam3Segmentation(model=tiny_sam3, prompts=PROMPTS, imgsz=448,
                                               memory_budget_mb=budget))
        side = seg.input_side
        assert (side % 28 == 0 and seg.activation_mb(side) <= budget) or side == 28
        res = seg.segment(_frame())  # every chosen resolution runs (rotary positions follow it)
        assert res.label.shape == (120, 160)
        sides.append(side)
    assert sides[0] == 448 and sides == sorted(sides, reverse=True) and sides[-1] < 224


def test_missing_model_folder_is_a_config_error(tmp_path):
    from semmap.errors import ConfigError
    from semmap.segment.base import create_segmenter

    with pytest.raises(ConfigError, match="segmentation.model"):
        create_segmenter(Sam3Segmentation(model=tmp_path / "nope"))
