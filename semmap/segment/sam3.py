"""The ``sam3`` backend: SAM 3 text-prompted concept segmentation (transformers' ``Sam3Model``).

This is the one module that imports :mod:`torch` and :mod:`transformers`, lazily, when a
model loads. The model comes from a local folder (``segmentation.model``) holding what
``Sam3Model.save_pretrained`` and a tokenizer's ``save_pretrained`` write (``config.json``,
``model.safetensors``, ``tokenizer.json``...; ``preprocessor_config.json`` is read for the
normalisation if present). Nothing is downloaded.

Inference follows the research's architecture:

1. **The image embedding is computed once per frame and cached** (the ViT backbone and its
   FPN neck, by far the largest part of the model). Asking again for the same frame reuses it.
2. **The light decoder runs once per class prompt** (DETR encoder/decoder and mask head, on
   the cached embedding and the prompt's text embedding, itself computed once at load).
   Prompts run one after another, so peak memory does not grow with their number; each
   prompt's instances are merged into the label image before the next runs.
3. **The input resolution scales to a memory budget**: the largest square side, a multiple
   of twice the patch size and at most ``segmentation.imgsz`` (default: the model's own
   size, 1008 for SAM 3), whose estimated peak activation memory
   (:func:`estimate_activation_mb`) fits ``segmentation.memory_budget_mb``.

Each prompt names one class (``segmentation.prompts``, default the names of
``segmentation.class_list``): label value k is prompt k. A query's score is
``sigmoid(logit) · sigmoid(presence)`` as in ``Sam3Processor.post_process_instance_segmentation``;
queries scoring at least ``segmentation.conf`` paint their mask (``mask_threshold``) where no
better-scoring instance already did.

Sam3Processor itself needs torchvision for its image processor; the preprocessing here is
its equivalent (bilinear resize to a square, scale to [0, 1], normalise by the folder's
``image_mean``/``image_std``, default 0.5/0.5) so the backend runs without torchvision.
Ultralytics' SAM 3 is not wired in: Ultralytics does not import beside this project's torch.
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..classes import load_class_table
from ..config import SegmentationConfig
from ..errors import ConfigError
from ..records import Image, Segmentation
from .base import register
from .common import require_model, rgb_array

__all__ = ["Sam3Segmenter", "estimate_activation_mb", "save_random_model"]

log = logging.getLogger(__name__)


def _import() -> tuple[Any, Any]:
    try:
        import torch
        import transformers
    except ImportError:
        raise ConfigError("segmentation.backend 'sam3' needs torch and transformers: "
                          "pip install -c constraints.txt 'semmap[sam3]'") from None
    if not hasattr(transformers, "Sam3Model"):
        raise ConfigError(f"segmentation.backend 'sam3' needs transformers with Sam3Model "
                          f"(>= 5.0); this is {transformers.__version__}")
    return torch, transformers


def estimate_activation_mb(side: int, vit: dict[str, Any], fpn_hidden: int, num_queries: int,
                           detr_hidden: int) -> float:
    """Estimated peak activation memory (MB, float32) of one frame at a ``side``×``side`` input.

    The terms that dominate: a global-attention layer's score matrix (heads × N² for N tokens,
    when the attention kernel materialises it), a transformer layer's activations
    (N × (4·hidden + intermediate)), the FPN's finest level (4× the token grid, fpn_hidden
    channels, a few copies) and the mask head (one mask per query at the finest level).
    Weights are not included. It is an upper-bound style estimate, not a measurement.
    """
    g = side // int(vit["patch_size"])
    n = g * g
    heads = int(vit["num_attention_heads"])
    hidden = int(vit["hidden_size"])
    inter = int(vit["intermediate_size"])
    attn = heads * n * n
    layer = n * (4 * hidden + inter) * 2
    fine = (4 * g) ** 2
    fpn = fine * fpn_hidden * 4
    masks = num_queries * fine * 2 + fine * detr_hidden * 2
    return 4.0 * (attn + layer + fpn + masks) / 2**20


class Sam3Segmenter:
    """SAM 3 with one text prompt per class, the image embedding cached per frame."""

    name = "sam3"
    consumes = "rgb"

    def __init__(self, cfg: SegmentationConfig) -> None:
        self.cfg = cfg
        self.path = require_model(cfg.model, "sam3", "a local SAM 3 model folder (Sam3Model.save_pretrained "
                                                     "plus its tokenizer)")
        if not self.path.is_dir():
            raise ConfigError(f"segmentation.model: {self.path}: the sam3 backend needs a model folder")
        prompts = cfg.prompts or load_class_table(cfg.classes_file).names(cfg.class_list)
        if not prompts:
            raise ConfigError("segmentation.prompts: at least one prompt is needed")
        self.names: tuple[str, ...] = tuple(prompts)
        self._model: Any = None
        self._embed_key: str | None = None
        self._embed: Any = None
        self._side: int | None = None
        self.stats = {"embeddings": 0, "embedding_reuses": 0, "decoder_runs": 0}

    # -- loading -----------------------------------------------------------------------------
    def _load(self) -> Any:
        if self._model is not None:
            return self._model
        torch, tf = _import()
        tf.utils.logging.set_verbosity_error()
        tf.utils.logging.disable_progress_bar()
        if self.cfg.threads:
            torch.set_num_threads(self.cfg.threads)
        self._torch = torch
        try:
            model = tf.Sam3Model.from_pretrained(str(self.path), local_files_only=True)
            tokenizer = tf.AutoTokenizer.from_pretrained(str(self.path), local_files_only=True)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"segmentation.model: {self.path}: cannot load SAM 3 from this folder "
                              f"({str(exc).splitlines()[0]})") from None
        device = self.cfg.device
        if device.startswith("cuda") and not torch.cuda.is_available():
            raise ConfigError(f"segmentation.device: {device!r} asked for, but torch sees no CUDA device")
        self._device = torch.device(device)
        model = model.to(self._device).eval()
        self._model = model
        vc = model.config.vision_config
        self._vit = vc.backbone_config.to_dict()
        self._fpn_hidden = int(vc.fpn_hidden_size)
        self._queries = int(model.config.detr_decoder_config.num_queries)
        self._detr_hidden = int(model.config.detr_decoder_config.hidden_size)
        self._patch = int(self._vit["patch_size"])
        native = int(self._vit["image_size"] if isinstance(self._vit["image_size"], int) else self._vit["image_size"][0])
        self._native_side = native
        pre = self.path / "preprocessor_config.json"
        mean, std = [0.5, 0.5, 0.5], [0.5, 0.5, 0.5]
        if pre.is_file():
            try:
                meta = json.loads(pre.read_text())
                mean, std = meta.get("image_mean", mean), meta.get("image_std", std)
            except ValueError:
                raise ConfigError(f"{pre}: not valid JSON") from None
        self._mean = np.asarray(mean, np.float32).reshape(1, 1, 3)
        self._std = np.asarray(std, np.float32).reshape(1, 1, 3)
        self._side = self.choose_side()
        self._set_resolution(self._side)
        # text embeddings: once per prompt, for the whole run
        max_len = int(model.config.text_config.max_position_embeddings)
        self._text: list[tuple[Any, Any]] = []
        with torch.inference_mode():
            for prompt in self.names:
                tok = tokenizer(prompt, padding="max_length", max_length=max_len, truncation=True,
                                return_tensors="pt")
                ids = tok["input_ids"].to(self._device)
                mask = tok["attention_mask"].to(self._device)
                self._text.append((model.get_text_features(input_ids=ids, attention_mask=mask), mask, ids))
        log.info("sam3 %s: %d prompts, input %dx%d (budget %.0f MB, estimate %.0f MB)", self.path, len(self.names),
                 self._side, self._side, self.cfg.memory_budget_mb, self.activation_mb(self._side))
        return model

    def activation_mb(self, side: int) -> float:
        return estimate_activation_mb(side, self._vit, self._fpn_hidden, self._queries, self._detr_hidden)

    def choose_side(self) -> int:
        """The largest input side (multiple of 2 × patch) within imgsz whose estimate fits the budget."""
        step = 2 * self._patch
        top = self.cfg.imgsz or self._native_side
        side = max(step, (top // step) * step)
        while side > step and self.activation_mb(side) > self.cfg.memory_budget_mb:
            side -= step
        if self.activation_mb(side) > self.cfg.memory_budget_mb:
            log.warning("sam3: even a %dx%d input needs an estimated %.0f MB, over the %.0f MB budget",
                        side, side, self.activation_mb(side), self.cfg.memory_budget_mb)
        return side

    @property
    def input_side(self) -> int:
        self._load()
        assert self._side is not None
        return self._side

    def _set_resolution(self, side: int) -> None:
        """Global-attention layers precompute rotary positions for the configured size: redo them."""
        vit_model = self._model.vision_encoder.backbone
        cfg = copy.copy(vit_model.config)
        cfg.image_size = side
        for layer in vit_model.layers:
            if layer.window_size == 0:
                layer.position_ids = layer.precompute_positions(cfg, 0).to(layer.position_ids.device)

    # -- inference ---------------------------------------------------------------------------
    def pixel_values(self, rgb: NDArray[np.uint8]) -> Any:
        side = self.input_side
        x = cv2.resize(rgb, (side, side), interpolation=cv2.INTER_LINEAR).astype(np.float32) / 255.0
        x = (x - self._mean) / self._std
        return self._torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)[None])).to(self._device)

    def image_embedding(self, rgb: NDArray[np.uint8]) -> Any:
        """The vision embedding of a frame, computed once and reused while the frame is the same."""
        model = self._load()
        key = hashlib.blake2b(np.ascontiguousarray(rgb).data, digest_size=16).hexdigest()
        if key == self._embed_key:
            self.stats["embedding_reuses"] += 1
            return self._embed
        self._embed = None  # free the previous frame's embedding first
        with self._torch.inference_mode():
            self._embed = model.get_vision_features(pixel_values=self.pixel_values(rgb))
        self._embed_key = key
        self.stats["embeddings"] += 1
        return self._embed

    def _merge(self, out: Any, k: int, label: NDArray[np.uint16], conf: NDArray[np.float32]) -> None:
        """Paint one prompt's instances (label value k) where they beat what is there."""
        torch = self._torch
        scores = out.pred_logits[0].sigmoid()
        if out.presence_logits is not None:
            scores = scores * out.presence_logits[0].sigmoid()
        keep = torch.nonzero(scores >= self.cfg.conf).flatten()
        if keep.numel() == 0:
            return
        keep = keep[torch.argsort(scores[keep], descending=True)][: self.cfg.max_det]
        h, w = label.shape
        masks = out.pred_masks[0, keep].float()
        masks = torch.nn.functional.interpolate(masks[None], size=(h, w), mode="bilinear", align_corners=False)[0]
        t = self.cfg.mask_threshold
        on = masks > (math.log(t / (1 - t)) if 0 < t < 1 else (-math.inf if t <= 0 else math.inf))  # logit space
        # queries are sorted best first: each pixel takes the first query whose mask covers it
        first = on.to(torch.uint8).argmax(0).cpu().numpy()
        covered = on.any(0).cpu().numpy()
        best = scores[keep].float().cpu().numpy()[first]
        upd = covered & (best > conf)
        label[upd] = k
        conf[upd] = best[upd]

    def segment(self, image: Image) -> Segmentation:
        """Cached path: one image embedding, then the decoder once per prompt."""
        model = self._load()
        rgb = rgb_array(image, self.name)
        embed = self.image_embedding(rgb)
        label = np.zeros(rgb.shape[:2], np.uint16)
        conf = np.zeros(rgb.shape[:2], np.float32)
        with self._torch.inference_mode():
            for k, (text, mask, _) in enumerate(self._text, start=1):
                out = model(vision_embeds=embed, text_embeds=text, attention_mask=mask)
                self.stats["decoder_runs"] += 1
                self._merge(out, k, label, conf)
                del out
        return Segmentation(image.stamp_ns, label, self.names, conf)

    def segment_uncached(self, image: Image) -> Segmentation:
        """Reference path: the full model (image encoder included) once per prompt, nothing reused."""
        model = self._load()
        rgb = rgb_array(image, self.name)
        label = np.zeros(rgb.shape[:2], np.uint16)
        conf = np.zeros(rgb.shape[:2], np.float32)
        with self._torch.inference_mode():
            for k, (_, mask, ids) in enumerate(self._text, start=1):
                out = model(pixel_values=self.pixel_values(rgb), input_ids=ids, attention_mask=mask)
                self._merge(out, k, label, conf)
                del out
        return Segmentation(image.stamp_ns, label, self.names, conf)

    def close(self) -> None:
        self._model = None
        self._embed = None
        self._embed_key = None


@register("sam3")
def _make(cfg: SegmentationConfig) -> Sam3Segmenter:
    return Sam3Segmenter(cfg)


# ---------------------------------------------------------------------------------------
# Random-weight models for tests and benchmarks (no SAM 3 weights can be downloaded here)

#: (ViT hidden, layers, heads, MLP, native side, window, decoder hidden, decoder layers, queries, text layers)
_PRESETS: dict[str, tuple[int, ...]] = {
    # seconds-fast, for unit tests
    "tiny": (32, 2, 2, 64, 112, 4, 32, 1, 10, 1),
    # SAM 3's structure shrunk keeping its cost split: the ViT (12 layers, 4 of them global) costs
    # about 20x the prompt decoder (6+6 DETR layers, 200 queries), as SAM 3's 32-layer ViT-L
    # costs 22x its decoder (1444 vs 66 GFLOP at 504 px, counted with torch's FlopCounterMode)
    "small": (512, 12, 8, 2048, 448, 8, 64, 6, 200, 2),
}


def save_random_model(folder: str | Path, preset: str = "tiny", seed: int = 0,
                      vocabulary: tuple[str, ...] = ()) -> Path:
    """Write a random-weight SAM 3 model folder (model + word-level tokenizer) for tests/benchmarks.

    The words of ``vocabulary`` (and the COCO class names' words) are in the tokenizer's
    vocabulary. The masks such a model produces are meaningless; it exercises the
    inference path with SAM 3's real architecture.
    """
    torch, tf = _import()
    from tokenizers import Tokenizer, models, pre_tokenizers

    if preset not in _PRESETS:
        raise ConfigError(f"unknown SAM 3 preset {preset!r} (known: {', '.join(_PRESETS)})")
    vh, vl, heads, vi, side, win, dh, dl, nq, tl = _PRESETS[preset]
    words = {"[PAD]", "[UNK]", "[BOS]", "[EOS]"}
    for name in list(vocabulary) + list(load_class_table(None).names("coco")):
        words.update(name.lower().split())
    vocab = {w: i for i, w in enumerate(["[PAD]", "[UNK]", "[BOS]", "[EOS]"] + sorted(words - {
        "[PAD]", "[UNK]", "[BOS]", "[EOS]"}))}
    grid = side // 14
    vit = dict(model_type="sam3_vit_model", hidden_size=vh, intermediate_size=vi, num_hidden_layers=vl,
               num_attention_heads=heads, image_size=side, patch_size=14, window_size=win,
               global_attn_indexes=[vl - 1] if vl < 4 else list(range(vl // 4 - 1, vl, vl // 4)),
               pretrain_image_size=side // 2)
    text_hidden = max(32, dh)
    cfg = tf.Sam3Config(
        vision_config=dict(backbone_config=vit, fpn_hidden_size=dh,
                           backbone_feature_sizes=[[grid * 4] * 2, [grid * 2] * 2, [grid] * 2]),
        text_config=dict(model_type="clip_text_model", vocab_size=len(vocab), hidden_size=text_hidden,
                         intermediate_size=2 * text_hidden, projection_dim=text_hidden, num_hidden_layers=tl,
                         num_attention_heads=2, max_position_embeddings=32, bos_token_id=2, eos_token_id=3,
                         pad_token_id=0),
        geometry_encoder_config=dict(hidden_size=dh, num_layers=1, num_attention_heads=2, intermediate_size=2 * dh),
        detr_encoder_config=dict(hidden_size=dh, num_layers=dl, num_attention_heads=max(2, dh // 32),
                                 intermediate_size=8 * dh),
        detr_decoder_config=dict(hidden_size=dh, num_layers=dl, num_attention_heads=max(2, dh // 32),
                                 intermediate_size=8 * dh, num_queries=nq),
        mask_decoder_config=dict(hidden_size=dh, num_attention_heads=max(2, dh // 32)),
    )
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

