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
   the cached embedding and the prompt's text embedding, itself computed once at load). The
   prompts' decoder passes are batched: as many prompts as fit the memory budget
   (:meth:`Sam3Segmenter.prompt_batch`) go through the DETR stages in one call, and the prompts
   that keep a query through the mask head in one more. On two CPU threads that is 5 % faster
   than a call per prompt, 14 % when another process shares the cores (as mapping does during a
   build); on a single thread it is not faster, and prompts run one at a time. The one
   prompt-independent step of a decoder pass, the DETR encoder's first self-attention over the
   image tokens, runs once per frame and is shared by every prompt. Prompts are merged into the
   label image in prompt order, as one after another would. The mask head (a third of a
   prompt's FLOPs at 1008 px, nearly half at 504 px) runs only for prompts with some query kept
   (scores at least ``conf``): a class absent from the frame costs the DETR stages alone.
3. **The input resolution scales to a memory budget**: the largest square side, a multiple
   of twice the patch size and at most ``segmentation.imgsz`` (default: the model's own
   size, 1008 for SAM 3), whose estimated peak activation memory
   (:func:`estimate_activation_mb`) fits ``segmentation.memory_budget_mb``.

Each prompt names one class (``segmentation.prompts``, default the names of
``segmentation.class_list``): label value k is prompt k. A query's score is
``sigmoid(logit) · sigmoid(presence)`` as in ``Sam3Processor.post_process_instance_segmentation``;
queries scoring at least ``segmentation.conf`` paint their mask (``mask_threshold``) where no
better-scoring instance already did. Painting happens at the masks' own resolution (4× the token
grid: 288² for SAM 3 at 1008 px) and the frame's label and confidence images are resized to the
image once, nearest-neighbour (``nearest-exact``: pixel centres aligned). This is exactly what
upsampling every kept mask to the image with ``nearest-exact`` and painting there would give; it
differs from upsampling the mask logits bilinearly (as Sam3Processor does) only along mask
boundaries, which are snapped to the mask grid (by at most half a mask pixel: about ±1 px for
SAM 3 at 1008 px on a 640×480 image).

What a prompt costs beside the embedding is SAM 3's own split: counted with torch's
``FlopCounterMode`` (``flop_split`` in tests/sam3_helpers.py), SAM 3's image embedding costs 13.4× one prompt's
decoder run at its native 1008 px (5614 vs 420 GFLOP: the DETR encoder's attention over the
72² tokens grows with their number squared, like the ViT's global layers), 20.7× at 504 px; so
time(10 prompts) / time(1 prompt) cannot go below 1.63 at 1008 px (1.41 at 504 px) while every
prompt runs its mask head, even if time followed FLOPs (on CPU the decoder's small operations run
well below the ViT's FLOP rate). The first DETR encoder layer's self-attention (7 % of a run's
FLOPs) is prompt-independent and is computed once per frame (:meth:`Sam3Segmenter._encode`
re-runs ``Sam3DetrEncoder.forward`` around it; a test holds it to the library's own forward).

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
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from ..classes import load_class_table
from ..config import Sam3Segmentation
from ..errors import ConfigError
from ..records import Image, Segmentation
from .base import register
from .common import require_model, rgb_array

__all__ = ["Sam3Segmenter", "estimate_activation_mb"]

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

    def __init__(self, cfg: Sam3Segmentation) -> None:
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
        self._shared: Any = None  # the frame's prompt-independent DETR encoder input (see _encode)
        self._side: int | None = None
        self._index: dict[tuple[int, int], NDArray[np.intp]] = {}
        self.stats = {"embeddings": 0, "embedding_reuses": 0, "decoder_runs": 0, "mask_heads": 0,
                      "decoder_calls": 0}

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
        size = self._vit["image_size"]
        self._native_side = int(size if isinstance(size, int) else size[0])
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
        self._text: list[tuple[Any, Any, Any]] = []  # per prompt: text features, attention mask, token ids
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
        self._embed = self._shared = None  # free the previous frame's embedding first
        with self._torch.inference_mode():
            self._embed = model.get_vision_features(pixel_values=self.pixel_values(rgb))
        self._embed_key = key
        self.stats["embeddings"] += 1
        return self._embed

    def _keep(self, pred_logits: Any, presence_logits: Any) -> tuple[Any, Any]:
        """Query scores (``sigmoid(logit) · sigmoid(presence)``) and the queries kept: at least ``conf``,
        at most ``max_det`` of them, best first."""
        torch = self._torch
        scores = pred_logits[0].float().sigmoid()
        if presence_logits is not None:
            scores = scores * presence_logits[0].float().sigmoid()
        keep = torch.nonzero(scores >= self.cfg.conf).flatten()
        keep = keep[torch.argsort(scores[keep], descending=True)][: self.cfg.max_det]
        return scores, keep

    def decoder_mb(self, side: int) -> float:
        """Estimated activation memory (MB, float32) of one prompt's decoder pass at a ``side`` input:
        the DETR stages' token states (about fourteen copies of the token grid at the DETR width, its
        MLP eight of them) and the mask head's pixel features (4× the token grid, a few copies) with
        one mask per query. An upper-bound style estimate, as :func:`estimate_activation_mb`."""
        g = side // self._patch
        fine = (4 * g) ** 2
        return 4.0 * (g * g * self._detr_hidden * 14 + fine * self._detr_hidden * 3 + self._queries * fine) / 2**20

    def prompt_batch(self) -> int:
        """How many prompts' decoder passes run in one call: as many as fit the memory budget, when
        torch runs on more than one thread; one at a time on a single thread, where one big call was
        measured no faster than many small ones (docs/benchmarks.md, SAM 3 prompt cost)."""
        self._load()
        if self._torch.get_num_threads() < 2:
            return 1
        per = self.decoder_mb(self.input_side)
        return max(1, min(len(self.names), int(self.cfg.memory_budget_mb // per)))

    def _encode(self, embed: Any, features: Any, text_mask: Any) -> tuple[Any, Any, Any]:
        """The DETR encoder for a batch of prompts on one frame: ``Sam3DetrEncoder.forward`` on the
        token grid the model's own decoder path uses (the FPN's second-coarsest level), with the first
        layer's self-attention over the image tokens, the same for every prompt, computed once per
        frame. Returns the encoded tokens, their position encodings and the grid's shape."""
        from transformers.masking_utils import create_bidirectional_mask

        enc = self._model.detr_encoder
        first = enc.layers[0]
        if self._shared is None:
            x, pos, shapes = enc._prepare_multilevel_features([embed.fpn_hidden_states[-2]],
                                                              [embed.fpn_position_encoding[-2]])
            h = first.layer_norm1(x)
            with_pos = h + pos
            h, _ = first.self_attn(query=with_pos, key=with_pos, value=h)
            self._shared = (x, pos, shapes, first.dropout(h) + x)
        x, pos, shapes, attended = self._shared
        n = features.shape[0]
        mask = create_bidirectional_mask(config=enc.config, inputs_embeds=x.expand(n, -1, -1),
                                         attention_mask=text_mask, encoder_hidden_states=features)
        h = attended.expand(n, -1, -1)
        cross, _ = first.cross_attn(query=first.layer_norm2(h), key=features, value=features, attention_mask=mask)
        h = first.dropout(cross) + h
        h = first.dropout(first.mlp(first.layer_norm3(h))) + h
        pos = pos.expand(n, -1, -1)
        for layer in enc.layers[1:]:
            h = layer(h, prompt_feats=features, vision_pos_encoding=pos, prompt_cross_attn_mask=mask)
        return h, pos, shapes

    def _decode_many(self, embed: Any, prompts: list[tuple[Any, Any]]) -> list[tuple[Any, Any, Any]]:
        """The decoder passes of some prompts (their text features and attention masks) on a cached
        image embedding, in one batch: ``Sam3Model.forward``'s text-prompt path (DETR encoder, DETR
        decoder, scoring, mask head) through the model's own modules, except that the mask head runs
        only for the prompts that keep a query (the box head, unused here, never does). Returns, per
        prompt, its scores, its kept queries and its mask logits (None when it keeps nothing)."""
        torch, model = self._torch, self._model
        fpn = embed.fpn_hidden_states[:-1]
        features = torch.cat([t.pooler_output for t, _ in prompts])
        text_mask = torch.cat([m for _, m in prompts]).bool()
        tokens, pos, shapes = self._encode(embed, features, text_mask)
        dec = model.detr_decoder(vision_features=tokens, text_features=features, vision_pos_encoding=pos,
                                 text_mask=text_mask, spatial_shapes=shapes)
        logits = model.dot_product_scoring(decoder_hidden_states=dec.intermediate_hidden_states,
                                           text_features=features, text_mask=text_mask).squeeze(-1)[-1]
        presence = dec.presence_logits[-1]
        kept = [self._keep(logits[i:i + 1], None if presence is None else presence[i:i + 1])
                for i in range(len(prompts))]
        self.stats["decoder_calls"] += 1
        self.stats["decoder_runs"] += len(prompts)
        masks: list[Any] = [None] * len(prompts)
        heads = [i for i, (_, keep) in enumerate(kept) if keep.numel()]
        if heads:
            sel = torch.tensor(heads, device=features.device)
            k = len(heads)
            self.stats["mask_heads"] += k
            pred = model.mask_decoder(decoder_queries=dec.intermediate_hidden_states[-1][sel],
                                      backbone_features=[f.expand(k, -1, -1, -1) for f in fpn],
                                      encoder_hidden_states=tokens[sel], prompt_features=features[sel],
                                      prompt_mask=text_mask[sel]).pred_masks
            for j, i in enumerate(heads):
                masks[i] = pred[j:j + 1]
        return [(scores, keep, m) for (scores, keep), m in zip(kept, masks)]

    def _decode(self, embed: Any, text: Any, mask: Any) -> tuple[Any, Any, Any]:
        """One prompt's decoder pass (see :meth:`_decode_many`)."""
        return self._decode_many(embed, [(text, mask)])[0]

    def _paint(self, masks: Any, scores: Any, keep: Any, k: int, canvas: list[Any]) -> None:
        """Paint one prompt's kept instances (label value k) at mask resolution, where they beat what
        is there. ``canvas`` is [label, confidence, instance, instances so far] at mask resolution, made
        on first use."""
        torch = self._torch
        if keep.numel() == 0:
            return
        t = self.cfg.mask_threshold
        thr = math.log(t / (1 - t)) if 0 < t < 1 else (-math.inf if t <= 0 else math.inf)  # logit space
        on = masks[0, keep] > thr
        # the best-scoring kept instance covering each pixel (the first of the queries sorted best first)
        best_t, which = torch.where(on, scores[keep].view(-1, 1, 1), torch.zeros((), dtype=scores.dtype)).max(0)
        best, which = best_t.cpu().numpy(), which.cpu().numpy()
        if not canvas:
            canvas += [np.zeros(best.shape, np.uint16), np.zeros(best.shape, np.float32),
                       np.zeros(best.shape, np.uint16), 0]
        label, conf, instance, seen = canvas
        upd = best > conf
        label[upd] = k
        conf[upd] = best[upd]
        # instances numbered from 1 across the prompts (at most 65535 per image)
        instance[upd] = np.minimum(seen + 1 + which[upd], np.iinfo(np.uint16).max)
        canvas[3] = seen + int(keep.numel())

    def _nearest(self, n_in: int, n_out: int) -> NDArray[np.intp]:
        """Source indices of torch's ``nearest-exact`` resize (pixel centres aligned) along one axis."""
        key = (n_in, n_out)
        if key not in self._index:
            src = self._torch.arange(n_in, dtype=self._torch.float32).view(1, 1, n_in, 1)
            idx = self._torch.nn.functional.interpolate(src, size=(n_out, 1), mode="nearest-exact")
            self._index[key] = idx.view(-1).to(self._torch.int64).numpy()
        return self._index[key]

    def _finish(self, canvas: list[Any], shape: tuple[int, int], stamp_ns: int) -> Segmentation:
        """The frame's label, confidence and instances at image size: the mask-resolution canvas, resized once."""
        if not canvas:
            return Segmentation(stamp_ns, np.zeros(shape, np.uint16), self.names, np.zeros(shape, np.float32))
        label, conf, instance, _ = canvas
        ys = self._nearest(label.shape[0], shape[0])[:, None]
        xs = self._nearest(label.shape[1], shape[1])[None, :]
        return Segmentation(stamp_ns, label[ys, xs], self.names, conf[ys, xs], instance[ys, xs])

    def segment(self, image: Image) -> Segmentation:
        """Cached path: one image embedding, then the prompts' decoder passes, batched."""
        self._load()
        rgb = rgb_array(image, self.name)
        embed = self.image_embedding(rgb)
        canvas: list[Any] = []
        step = self.prompt_batch()
        with self._torch.inference_mode():
            for first in range(0, len(self._text), step):
                part = [(text, mask) for text, mask, _ in self._text[first:first + step]]
                for k, (scores, keep, masks) in enumerate(self._decode_many(embed, part), start=first + 1):
                    self._paint(masks, scores, keep, k, canvas)
                del part
        return self._finish(canvas, rgb.shape[:2], image.stamp_ns)

    def segment_uncached(self, image: Image) -> Segmentation:
        """Reference path: the full model (image encoder included) once per prompt, nothing reused."""
        model = self._load()
        rgb = rgb_array(image, self.name)
        canvas: list[Any] = []
        with self._torch.inference_mode():
            for k, (_, mask, ids) in enumerate(self._text, start=1):
                out = model(pixel_values=self.pixel_values(rgb), input_ids=ids, attention_mask=mask)
                scores, keep = self._keep(out.pred_logits, out.presence_logits)
                self._paint(out.pred_masks, scores, keep, k, canvas)
                del out
        return self._finish(canvas, rgb.shape[:2], image.stamp_ns)

    def close(self) -> None:
        self._model = None
        self._embed = self._shared = None
        self._embed_key = None


@register("sam3")
def _make(cfg: Sam3Segmentation) -> Sam3Segmenter:
    return Sam3Segmenter(cfg)
