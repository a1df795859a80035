"""Random-weight SAM 3 models for the tests and tools/bench_segment.py (no SAM 3 weights can be
downloaded here). The library never uses these; they exercise the ``sam3`` backend's inference path
with SAM 3's real architecture. Import them with ``tests/`` on ``sys.path`` (pytest puts it there)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from semmap.classes import load_class_table


def _import() -> tuple[Any, Any]:
    import torch
    import transformers

    return torch, transformers


#: Random-weight configurations. ``small`` is SAM 3 (``Sam3Config()``: ViT-L 1024 wide, 32 layers of
#: which 4 global, MLP 4736, window 24, 1008 px; FPN/DETR/mask decoder 256 wide, 6+6 DETR layers, 200
#: queries) with every width and the query count divided by 4 and the token grid side by 2 (504 px,
#: window 12, position-embedding tile 168 px), depths kept. Each cost term (N tokens, width w:
#: projections and MLPs N·w², global attention N²·w, windowed attention N·window²·w, convolutions
#: N·w², the masks N·queries·w) then shrinks by the same factor 64, so at any input side s the preset
#: splits its FLOPs between the image embedding and a prompt's decoder run as SAM 3 does at 2·s, to
#: within 2 % (the 32 text tokens are not scaled): :func:`flop_split` gives 13.3× at 504 px (SAM 3:
#: 13.4× at 1008 px) and 20.3× at 252 px (SAM 3: 20.7× at 504 px). The text encoder (run once per
#: prompt at load) is not scaled.
PRESETS: dict[str, dict[str, Any]] = {
    # seconds-fast, for unit tests
    "tiny": dict(vit_hidden=32, vit_layers=2, vit_heads=2, vit_mlp=64, side=112, window=4, global_layers=[1],
                 tile=56, hidden=32, detr_layers=1, queries=10, text_layers=1),
    "small": dict(vit_hidden=256, vit_layers=32, vit_heads=4, vit_mlp=1184, side=504, window=12,
                  global_layers=[7, 15, 23, 31], tile=168, hidden=64, detr_layers=6, queries=50, text_layers=2),
}


def random_config(preset: str = "tiny", vocab_size: int = 256) -> Any:
    """The ``Sam3Config`` of a random-weight preset (see ``PRESETS``)."""
    _, tf = _import()
    if preset not in PRESETS:
        raise ValueError(f"unknown SAM 3 preset {preset!r} (known: {', '.join(PRESETS)})")
    p = PRESETS[preset]
    side, dh = p["side"], p["hidden"]
    grid = side // 14
    vit = dict(model_type="sam3_vit_model", hidden_size=p["vit_hidden"], intermediate_size=p["vit_mlp"],
               num_hidden_layers=p["vit_layers"], num_attention_heads=p["vit_heads"], image_size=side,
               patch_size=14, window_size=p["window"], global_attn_indexes=list(p["global_layers"]),
               pretrain_image_size=p["tile"])
    text_hidden = max(32, dh)
    heads = max(2, dh // 32)  # SAM 3: 8 heads of 32 channels
    return tf.Sam3Config(
        vision_config=dict(backbone_config=vit, fpn_hidden_size=dh,
                           backbone_feature_sizes=[[grid * 4] * 2, [grid * 2] * 2, [grid] * 2]),
        text_config=dict(model_type="clip_text_model", vocab_size=vocab_size, hidden_size=text_hidden,
                         intermediate_size=2 * text_hidden, projection_dim=text_hidden,
                         num_hidden_layers=p["text_layers"], num_attention_heads=2, max_position_embeddings=32,
                         bos_token_id=2, eos_token_id=3, pad_token_id=0),
        geometry_encoder_config=dict(hidden_size=dh, num_layers=1, num_attention_heads=2, intermediate_size=2 * dh),
        detr_encoder_config=dict(hidden_size=dh, num_layers=p["detr_layers"], num_attention_heads=heads,
                                 intermediate_size=8 * dh),
        detr_decoder_config=dict(hidden_size=dh, num_layers=p["detr_layers"], num_attention_heads=heads,
                                 intermediate_size=8 * dh, num_queries=p["queries"]),
        mask_decoder_config=dict(hidden_size=dh, num_attention_heads=heads),
    )


def flop_split(config: Any = None, side: int | None = None) -> dict[str, Any]:
    """FLOPs of one frame's image embedding and of one prompt's decoder run, counted by torch.

    ``config``: a ``Sam3Config`` (default: SAM 3's own, ``Sam3Config()``); ``side``: the square input
    side (default: the config's). The image encoder runs on the meta device (shapes only, so SAM 3's
    ViT-L costs nothing to count); the prompt path (DETR encoder/decoder, scoring, mask decoder) runs
    on CPU with random weights, since its box bias needs real values. Attention is counted: torch's
    ``FlopCounterMode`` has no formula for the CPU flash-attention kernel, so one is supplied.
    Returns GFLOP: ``vision``, ``decoder`` and the decoder's parts.
    """
    torch, tf = _import()
    from types import SimpleNamespace

    from torch.utils.flop_counter import FlopCounterMode, sdpa_flop_count

    cfg = copy.deepcopy(config) if config is not None else tf.Sam3Config()
    vit_cfg = cfg.vision_config.backbone_config
    side = int(side or (vit_cfg.image_size if isinstance(vit_cfg.image_size, int) else vit_cfg.image_size[0]))
    cpu_sdpa = {torch.ops.aten._scaled_dot_product_flash_attention_for_cpu:
                lambda q, k, v, *_, out_shape=None, **__: sdpa_flop_count(q, k, v)}
    with torch.device("meta"):
        model = tf.Sam3Model(cfg).eval()
    gen = torch.Generator().manual_seed(0)
    for name in ("detr_encoder", "detr_decoder", "mask_decoder", "dot_product_scoring"):
        part = getattr(model, name).to_empty(device="cpu")
        with torch.no_grad():
            for p in part.parameters():
                p.copy_(torch.randn(p.shape, generator=gen) * 0.02)
            for b in part.buffers():
                if b.is_floating_point():
                    b.zero_()
    vit = model.vision_encoder.backbone
    at_side = copy.copy(vit.config)
    at_side.image_size = side
    for layer in vit.layers:
        if layer.window_size == 0:
            layer.position_ids = layer.precompute_positions(at_side, 0).to("meta")
    n_text = int(cfg.text_config.max_position_embeddings)
    mask = torch.zeros(1, n_text, dtype=torch.long)
    mask[0, :3] = 1  # a three-token prompt
    text = SimpleNamespace(pooler_output=torch.randn(1, n_text, cfg.detr_encoder_config.hidden_size, generator=gen))
    with torch.inference_mode():
        with FlopCounterMode(display=False, custom_mapping=cpu_sdpa) as counter:
            embed = model.get_vision_features(pixel_values=torch.zeros(1, 3, side, side, device="meta"))
        vision = counter.get_total_flops()
        embed.last_hidden_state = None
        embed.fpn_hidden_states = tuple(torch.randn(x.shape, generator=gen) for x in embed.fpn_hidden_states)
        embed.fpn_position_encoding = tuple(torch.randn(x.shape, generator=gen) for x in embed.fpn_position_encoding)
        with FlopCounterMode(display=False, custom_mapping=cpu_sdpa) as counter:
            model(vision_embeds=embed, text_embeds=text, attention_mask=mask)
        decoder = counter.get_total_flops()
        parts = {k.split(".")[-1]: sum(v.values()) / 1e9 for k, v in counter.get_flop_counts().items()
                 if k.count(".") == 1}
    return {"side": side, "vision": vision / 1e9, "decoder": decoder / 1e9, "decoder_parts": parts}


def save_random_model(folder: str | Path, preset: str = "tiny", seed: int = 0,
                      vocabulary: tuple[str, ...] = ()) -> Path:
    """Write a random-weight SAM 3 model folder (model + word-level tokenizer) for tests/benchmarks.

    The words of ``vocabulary`` (and the COCO class names' words) are in the tokenizer's
    vocabulary. The masks such a model produces are meaningless; it exercises the
    inference path with SAM 3's real architecture.
    """
    torch, tf = _import()
    from tokenizers import Tokenizer, models, pre_tokenizers

    if preset not in PRESETS:
        raise ValueError(f"unknown SAM 3 preset {preset!r} (known: {', '.join(PRESETS)})")
    words = {"[PAD]", "[UNK]", "[BOS]", "[EOS]"}
    for name in list(vocabulary) + list(load_class_table(None).names("coco")):
        words.update(name.lower().split())
    vocab = {w: i for i, w in enumerate(["[PAD]", "[UNK]", "[BOS]", "[EOS]"] + sorted(words - {
        "[PAD]", "[UNK]", "[BOS]", "[EOS]"}))}
    cfg = random_config(preset, len(vocab))
    side = PRESETS[preset]["side"]
    torch.manual_seed(seed)
    model = tf.Sam3Model(cfg).eval()
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    model.save_pretrained(str(out))
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="[UNK]"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    fast = tf.PreTrainedTokenizerFast(tokenizer_object=tok, unk_token="[UNK]", pad_token="[PAD]",
                                      bos_token="[BOS]", eos_token="[EOS]")
    fast.save_pretrained(str(out))
    (out / "preprocessor_config.json").write_text(json.dumps({"image_mean": [0.5] * 3, "image_std": [0.5] * 3,
                                                              "size": {"height": side, "width": side}}))
    return out

