"""The on-disk mask cache: a Segmenter wrapper that stores each result by model and image stamp.

``segmentation.cache_dir: DIR`` turns it on for every command (``build``, ``segment``,
``eval-seg``); :func:`~semmap.segment.base.create_segmenter` applies it. Layout::

    DIR/<model key>/model.json          what the key stands for (backend, weights digest, options)
    DIR/<model key>/<stamp_ns>.npz      label (uint16), confidence (float32) and instance (uint16)
                                        images (if any), image digest, the model's seconds for it
                                        (``max_seconds`` budgets count them on a rebuild)

The **model key** is a digest of the backend name, the SHA-256 of the weights file (or
folder) and the options that change the result (thresholds, input size, prompts, memory
budget, class list). Another model or another threshold gets its own folder, so a stale
result is never served. Each entry also records a digest of the image it was computed
from; an image with the same stamp but other pixels is segmented again and the entry
replaced. Entries are ``.npz`` files read with ``allow_pickle=False``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..config import ModelSegmentationConfig
from ..records import Image, Segmentation
from .common import file_digest

__all__ = ["CachedSegmenter", "model_identity", "model_key"]

log = logging.getLogger(__name__)

#: options that change a backend's result (other fields, such as threads or cache_dir, do not), each with
#: the value a backend without that option is keyed by. These are the defaults of the one flat
#: segmentation config every backend shared before each had its own model: keeping them keeps the
#: keys, and so the cached results, of earlier versions valid. Not settings: never read as defaults.
_RESULT_OPTIONS: dict[str, Any] = {"conf": 0.25, "iou": 0.7, "mask_threshold": 0.5, "max_det": 300, "imgsz": None,
                                   "prompts": None, "memory_budget_mb": 4096.0, "class_list": "coco"}


def _weights_digest(path: Path, cache_root: Path) -> str:
    """SHA-256 of the weights, remembered per (path, size, mtime) so big models are hashed once."""
    p = Path(path).expanduser().resolve()
    st = p.stat()
    memo_file = cache_root / "weights.json"
    key = f"{p}|{st.st_size}|{st.st_mtime_ns}"
    try:
        memo = json.loads(memo_file.read_text()) if memo_file.is_file() else {}
    except (OSError, ValueError):
        memo = {}
    if key in memo:
        return str(memo[key])
    digest = file_digest(p)
    memo[key] = digest
    with contextlib.suppress(OSError):
        _atomic_write_text(memo_file, json.dumps(memo, indent=1))
    return digest


def model_identity(cfg: ModelSegmentationConfig, cache_root: Path | None = None) -> dict[str, Any]:
    """What a cached result depends on: backend, weights digest, result-changing options."""
    # entry format 2 keeps the instance image: results cached before it are segmented again
    ident: dict[str, Any] = {"backend": cfg.backend, "entry_format": 2}
    weights = cfg.weights
    if weights is None and cfg.backend == "mediapipe-selfie":
        from .selfie import default_selfie_model

        weights = default_selfie_model()
    if weights is not None and Path(weights).expanduser().exists():
        root = cache_root if cache_root is not None else Path(tempfile.gettempdir())
        ident["weights_sha256"] = _weights_digest(Path(weights), root)
    opts = cfg.model_dump(mode="json")
    if opts.get("folder") is not None:  # a backend reading results from a folder (a plugin's)
        ident["folder"] = str(Path(opts["folder"]).expanduser().resolve())
    for k, absent in _RESULT_OPTIONS.items():
        ident[k] = opts.get(k, absent)
    return ident


def model_key(identity: dict[str, Any]) -> str:
    """A short, stable name for a model identity."""
    text = json.dumps(identity, sort_keys=True)
    return f"{identity['backend']}-{hashlib.sha256(text.encode()).hexdigest()[:16]}"


def image_digest(image: Image) -> str:
    h = hashlib.blake2b(digest_size=16)
    h.update(f"{image.encoding}|{image.data.shape}".encode())
    h.update(np.ascontiguousarray(image.data).data)
    return h.hexdigest()


def _atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=path.suffix)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)


class CachedSegmenter:
    """Wraps a segmenter: results are read from the cache, or computed and stored."""

    consumes = "rgb"

    def __init__(self, inner: Any, cfg: ModelSegmentationConfig) -> None:
        self.inner = inner
        self.name = inner.name
        root = Path(cfg.cache_dir).expanduser()  # type: ignore[arg-type]
        root.mkdir(parents=True, exist_ok=True)
        self.identity = model_identity(cfg, root)
        self.dir = root / model_key(self.identity)
        self.dir.mkdir(exist_ok=True)
        meta = self.dir / "model.json"
        if not meta.is_file():
            _atomic_write_text(meta, json.dumps(self.identity, indent=1, sort_keys=True))
        self.hits = 0
        self.misses = 0
        #: the model's time for the last frame: measured, or as stored with a cached one (None: not stored)
        self.last_model_seconds: float | None = None
        self._names: tuple[str, ...] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        if self._names is None:
            names_file = self.dir / "names.json"
            if names_file.is_file():  # known without loading the model
                try:
                    self._names = tuple(json.loads(names_file.read_text()))
                except (OSError, ValueError):
                    self._names = None
            if self._names is None:
                self._names = tuple(self.inner.names)
                _atomic_write_text(names_file, json.dumps(list(self._names)))
        return self._names

    def _path(self, stamp_ns: int) -> Path:
        return self.dir / f"{stamp_ns}.npz"

    def _read(self, image: Image, digest: str) -> Segmentation | None:
        p = self._path(image.stamp_ns)
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                if str(z["image_digest"]) != digest:
                    return None
                conf = z["confidence"] if "confidence" in z.files else None
                instance = z["instance"] if "instance" in z.files else None
                self.last_model_seconds = float(z["model_seconds"]) if "model_seconds" in z.files else None
                return Segmentation(image.stamp_ns, z["label"], self.names, conf, instance)
        except (OSError, ValueError, KeyError) as exc:
            log.warning("%s: unreadable cache entry, segmenting again (%s)", p, exc)
            return None

    def segment(self, image: Image) -> Segmentation:
        digest = image_digest(image)
        seg = self._read(image, digest)
        if seg is not None:
            self.hits += 1
            return seg
        self.misses += 1
        _ = self.inner.names  # a model that loads on first use loads now: its start-up is not its time
        t0 = time.perf_counter()
        seg = self.inner.segment(image)
        self.last_model_seconds = time.perf_counter() - t0
        arrays: dict[str, Any] = {"label": seg.label, "image_digest": np.array(digest),
                                  "model_seconds": np.array(self.last_model_seconds)}
        if seg.confidence is not None:
            arrays["confidence"] = seg.confidence
        if seg.instance is not None:
            arrays["instance"] = seg.instance
        fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".tmp-", suffix=".npz")
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, self._path(image.stamp_ns))
        if self._names is None:
            self._names = tuple(seg.names)
            _atomic_write_text(self.dir / "names.json", json.dumps(list(self._names)))
        return seg

    def close(self) -> None:
        if self.hits or self.misses:
            log.info("mask cache %s: %d hits, %d segmented", self.dir, self.hits, self.misses)
        self.inner.close()
