"""What the model backends share: checking the input image, composing label images, model names.

Nothing here imports a model runtime.
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError, SemmapError
from ..records import Image

__all__ = ["compose_instances", "default_data_dir", "file_digest", "parse_names", "require_model", "rgb_array"]


def rgb_array(image: Image, backend: str) -> NDArray[np.uint8]:
    """The image as (H, W, 3) ``uint8`` RGB; grey images are repeated into three channels."""
    a = image.data
    if image.encoding == "rgb8" and a.ndim == 3 and a.shape[2] == 3 and a.dtype == np.uint8:
        return cast(NDArray[np.uint8], a)
    if image.encoding in ("mono8", "8UC1") and a.ndim == 2 and a.dtype == np.uint8:
        return np.repeat(a[:, :, None], 3, axis=2)
    raise SemmapError(f"{backend}: needs rgb8 camera images, got {image.encoding!r} with shape {a.shape}")


def compose_instances(shape: tuple[int, int], masks: list[NDArray[np.bool_]] | NDArray[np.bool_],
                      labels: NDArray[np.integer], scores: NDArray[np.floating],
                      offsets: list[tuple[int, int]] | None = None
                      ) -> tuple[NDArray[np.uint16], NDArray[np.float32], NDArray[np.uint16]]:
    """Paint instance masks into one label image, best score last (on top).

    ``labels[i]`` is the label value (class index + 1) of instance i; ``masks[i]`` its mask,
    either full-size or, with ``offsets[i] = (row, col)``, a box-sized patch placed there.
    Returns the ``uint16`` label image, the ``float32`` confidence (the winning
    instance's score; 0 where the label is 0) and the ``uint16`` instance image (the winning
    instance's number, from 1 in the order given; 0 where the label is 0).
    """
    if len(masks) > np.iinfo(np.uint16).max:
        raise ValueError(f"{len(masks)} instances: at most 65535 fit an instance image")
    label = np.zeros(shape, np.uint16)
    conf = np.zeros(shape, np.float32)
    instance = np.zeros(shape, np.uint16)
    for i in np.argsort(np.asarray(scores), kind="stable"):
        m = masks[i]
        if offsets is None:
            r0, c0 = 0, 0
        else:
            r0, c0 = offsets[i]
        if m.size == 0:
            continue
        sub_l = label[r0:r0 + m.shape[0], c0:c0 + m.shape[1]]
        sub_c = conf[r0:r0 + m.shape[0], c0:c0 + m.shape[1]]
        sub_l[m] = int(labels[i])
        sub_c[m] = float(scores[i])
        instance[r0:r0 + m.shape[0], c0:c0 + m.shape[1]][m] = i + 1
    return label, conf, instance


def parse_names(raw: Any, source: str) -> tuple[str, ...]:
    """Class names from model metadata: a list, a ``{index: name}`` dict, or their text forms
    (JSON or a Python literal, as Ultralytics writes it; parsed with ``ast.literal_eval``, which
    evaluates no code)."""
    value = raw
    if isinstance(raw, (bytes, str)):
        text = raw.decode() if isinstance(raw, bytes) else raw
        try:
            value = json.loads(text)
        except ValueError:
            try:
                value = ast.literal_eval(text)
            except (ValueError, SyntaxError):
                raise ConfigError(f"{source}: class names {text[:60]!r} are neither JSON nor a literal") from None
    if isinstance(value, dict):
        try:
            items = sorted((int(k), str(v)) for k, v in value.items())
        except (TypeError, ValueError):
            raise ConfigError(f"{source}: class names must map integer ids to names") from None
        if [k for k, _ in items] != list(range(len(items))):
            raise ConfigError(f"{source}: class ids must be 0..{len(items) - 1}")
        return tuple(v for _, v in items)
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        return tuple(value)
    raise ConfigError(f"{source}: cannot read class names from {type(value).__name__}")


def default_data_dir() -> Path:
    """``$SEMMAP_DATA``, else ``../shared/data`` beside a source checkout."""
    env = os.environ.get("SEMMAP_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data"


def require_model(path: Path | None, backend: str, kinds: str) -> Path:
    """The configured model path, checked to exist; errors name the config key."""
    if path is None:
        raise ConfigError(f"segmentation.model: the {backend} backend needs {kinds}")
    p = Path(path).expanduser()
    if not p.exists():
        raise ConfigError(f"segmentation.model: {p}: no such file or directory")
    return p


def file_digest(path: Path, chunk: int = 1 << 20) -> str:
    """SHA-256 of a file, or of a folder's files (names and contents, sorted)."""
    h = hashlib.sha256()
    p = Path(path)
    files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
    for f in files:
        if p.is_dir():
            h.update(str(f.relative_to(p)).encode())
        with open(f, "rb") as fh:
            while block := fh.read(chunk):
                h.update(block)
    return h.hexdigest()
