"""The research's Fig. 6 for one camera image: what the occlusion filter changes.

:func:`paint_picture` draws three panels side by side for one :class:`PaintedPair`:

(a) the camera image with the label masks laid over it (the masks alone, in palette
    colours, when the tour has no RGB topic);
(b) the scan's points that fell into the image, painted *without* the filter, coloured by
    mobility: dynamic red, semi-static orange, static green;
(c) the same points *with* the filter: the points it relabelled ``unknown`` are drawn as
    hollow black rings on a yellow halo, the rest coloured as in (b).

When the true mobility of the beams is known (simulated tours), points whose painted
mobility is still wrong in (c) are crossed out.

:class:`ImagePicker` chooses which scan to draw while a tour streams past (the one with
the most relabelled points, by default), so a tour is read once; :func:`picture` is the
whole job for one tour.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..config import BuildConfig
from ..errors import BagError, ConfigError, OutputExistsError, SemmapError
from ..palette import class_color, rgb01
from ..records import Image, Mobility
from .export import PaintedPair, iter_painted

__all__ = ["ImagePicker", "PictureResult", "camera_image", "draw_picked", "paint_picture", "picture"]

log = logging.getLogger(__name__)

#: point colours (RGB 0-255) of the picture: dynamic red, semi-static orange, static green
POINT_COLORS: dict[Mobility, tuple[int, int, int]] = {
    Mobility.DYNAMIC: (230, 25, 45),
    Mobility.SEMI_STATIC: (255, 140, 0),
    Mobility.STATIC: (60, 200, 75),
}
_HALO = (255, 235, 0)  # behind relabelled points


@dataclass(frozen=True)
class PictureResult:
    """What :func:`picture` drew."""

    out: Path
    scan_stamp_ns: int
    image_stamp_ns: int
    points_in_view: int
    relabelled: int
    rgb: bool  # drawn over the RGB image (else over the label masks)


class ImagePicker:
    """Keep the one scan worth drawing while pairs stream past.

    * default: the scan with the most relabelled points (the first of equals);
    * ``at``: the scan whose stamp is nearest ``at`` (ns; the export's ``stamp_ns`` column);
    * ``image``: the ``image``-th camera image (0-based, counting the images scans were
      painted with), and of its scans the one with the most relabelled points.

    Only scans that fell into a camera image are considered.
    """

    def __init__(self, at: int | None = None, image: int | None = None) -> None:
        if at is not None and image is not None:
            raise ValueError("give at most one of at and image")
        if image is not None and image < 0:
            raise ValueError(f"image must be >= 0, got {image}")
        self.at, self.image = at, image
        self.best: PaintedPair | None = None
        self._key: tuple[float, ...] = ()
        self._image_stamps: list[int] = []

    @property
    def images_seen(self) -> int:
        """Camera images the painted scans used so far."""
        return len(self._image_stamps)

    def offer(self, pair: PaintedPair) -> None:
        view = pair.view
        if view is None or view.beams.size == 0:
            return
        if not self._image_stamps or self._image_stamps[-1] != view.stamp_ns:
            self._image_stamps.append(view.stamp_ns)
        if self.at is not None:
            key: tuple[float, ...] = (-abs(pair.scan.stamp_ns - self.at),)
        elif self.image is not None:
            if len(self._image_stamps) - 1 != self.image:
                return
            key = (pair.relabelled, -abs(pair.scan.stamp_ns - view.stamp_ns))
        else:
            key = (pair.relabelled,)
        if self.best is None or key > self._key:
            self.best, self._key = pair, key

    __call__ = offer


def camera_image(tour: str | Path, stamp_ns: int, config: str | Path | BuildConfig | None = None,
                 calibration: str | Path | None = None, max_offset_ns: int = 50_000_000) -> Image | None:
    """The RGB image of ``tour`` nearest ``stamp_ns`` (within ``max_offset_ns``), or None.

    None when the tour has no RGB topic (only label images, say) or no image near the stamp.
    Grey images come back as three equal channels.
    """
    from ..io.bag import read_bag
    from ..io.tour import load_build_config, open_tour

    with contextlib.ExitStack() as stack:  # the bag, opened once
        try:
            if isinstance(config, BuildConfig):
                cfg, cfg_dir = config, Path.cwd()
            else:
                cfg, cfg_dir = load_build_config(config)
            src = stack.enter_context(read_bag(tour))
            tinfo = open_tour(Path(tour), cfg, cfg_dir, calibration, consumes="rgb", source=src)
        except SemmapError as exc:
            log.info("%s: no RGB image for the picture (%s)", tour, exc)
            return None
        topic = tinfo.topics.image
        if topic is None:
            return None
        try:  # bag time runs a little behind capture time
            img = src.nearest_stamp(topic, stamp_ns, max_offset_ns, until_ns=stamp_ns + 2_000_000_000)
        except BagError as exc:
            log.warning("%s: cannot decode the image for the picture: %s", topic, exc)
            return None
    if img is None:
        return None
    data = np.asarray(img.data)
    if data.ndim == 2:  # grey camera (or mono16): three equal 8-bit channels
        if data.dtype != np.uint8:
            data = (data.astype(np.float64) * (255.0 / max(float(data.max()), 1.0))).astype(np.uint8)
        data = np.repeat(data[:, :, None], 3, axis=2)
    return Image(img.stamp_ns, img.frame_id, data, "rgb8")


def _mask_colours(label: NDArray[Any], names: tuple[str, ...]) -> tuple[NDArray[np.float64], list[int]]:
    """(H, W, 3) palette colours of the masks (0 where none) and the label values present."""
    present = [int(v) for v in np.unique(label) if 0 < v <= len(names)]
    lut = np.zeros((int(label.max()) + 1, 3))
    for v in present:
        lut[v] = class_color(names[v - 1])
    return lut[label], present


def _outline(label: NDArray[Any]) -> NDArray[np.bool_]:
    """Pixels on the border between different label values (2 px wide)."""
    edge = np.zeros(label.shape, bool)
    edge[:, 1:] |= label[:, 1:] != label[:, :-1]
    edge[1:, :] |= label[1:, :] != label[:-1, :]
    edge[:, :-1] |= edge[:, 1:].copy()
    edge[:-1, :] |= edge[1:, :].copy()
    return edge


def paint_picture(pair: PaintedPair, out_png: str | Path, image: Image | NDArray[np.uint8] | None = None,
                  truth: NDArray[np.uint8] | None = None, title: str | None = None, force: bool = True) -> Path:
    """Draw Fig. 6 for the scan of ``pair`` into ``out_png`` (written whole or not at all).

    ``image`` is the RGB camera image the scan was painted with (see :func:`camera_image`);
    without it the label masks are drawn in palette colours. ``truth`` is the true mobility
    of every beam (N,), for simulated tours: points still painted wrongly with the filter
    are then crossed out in panel (c).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    out_png = Path(out_png)
    if out_png.exists() and not force:
        raise OutputExistsError(f"{out_png}: exists (use --force to replace it)")
    view, seg = pair.view, pair.segmentation
    if view is None or seg is None:
        raise SemmapError(f"scan at {pair.scan.stamp_ns} fell into no camera image: nothing to draw")
    label = np.asarray(seg.label)
    h, w = label.shape
    names = tuple(seg.names) or pair.raw.class_names
    colours, present = _mask_colours(label, names)
    on_mask = label > 0
    rgb = None
    if image is not None:
        rgb = np.asarray(image.data if isinstance(image, Image) else image)
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[:, :, None], 3, axis=2)
        if rgb.shape[:2] != (h, w):
            import cv2

            rgb = cv2.resize(np.ascontiguousarray(rgb), (w, h), interpolation=cv2.INTER_AREA)
        rgb = rgb[:, :, :3].astype(np.float64)

    # (a) the image with the masks over it; without RGB, the masks on white
    if rgb is not None:
        panel_a = rgb.copy()
        panel_a[on_mask] = 0.4 * panel_a[on_mask] + 0.6 * colours[on_mask]
    else:
        panel_a = np.full((h, w, 3), 255.0)
        panel_a[on_mask] = colours[on_mask]
    edge = _outline(label)
    panel_a[edge] = 0.3 * panel_a[edge]
    # (b), (c): a pale grey background so the coloured points stand out, the masks as faint
    # tints with dark outlines
    grey = rgb.mean(axis=2, keepdims=True).repeat(3, axis=2) if rgb is not None else np.full((h, w, 3), 200.0)
    back = 0.45 * grey + 0.55 * 255
    back[on_mask] = 0.75 * back[on_mask] + 0.25 * colours[on_mask]
    back[edge] = 0.35 * colours[edge] if present else back[edge]
    back[edge & ~on_mask] = 90.0

    uv = view.uv
    mob_raw = pair.raw.mobility[view.beams]
    mob_f = pair.filtered.mobility[view.beams]
    relab = mob_raw != mob_f
    t_mob = None if truth is None else np.asarray(truth)[view.beams]

    def wrong(m: NDArray[np.uint8]) -> NDArray[np.bool_]:
        assert t_mob is not None
        return (m >= Mobility.SEMI_STATIC) & (m != t_mob)

    k = int(uv.shape[0])
    size = 30.0 if k < 200 else 18.0

    def counts(m: NDArray[np.uint8]) -> str:
        return (f"{int(np.sum(m == Mobility.DYNAMIC))} dynamic, {int(np.sum(m == Mobility.SEMI_STATIC))} "
                f"semi-static, {int(np.sum(m == Mobility.STATIC))} static")

    def scatter(ax: Any, m: NDArray[np.uint8]) -> None:
        for mob in (Mobility.STATIC, Mobility.SEMI_STATIC, Mobility.DYNAMIC):
            s = m == mob
            if s.any():
                ax.scatter(uv[s, 0], uv[s, 1], s=size, color=np.array(POINT_COLORS[mob]) / 255,
                           edgecolors="black", linewidths=0.5, zorder=3)
        s = m == Mobility.UNKNOWN
        if s.any():
            ax.scatter(uv[s, 0], uv[s, 1], s=size, facecolors="none", edgecolors="black", linewidths=1.1, zorder=3)
        if t_mob is not None:
            s = wrong(m)
            if s.any():
                ax.scatter(uv[s, 0], uv[s, 1], s=size * 1.6, marker="x", color="black", linewidths=0.9, zorder=4)

    fig, axes = plt.subplots(1, 3, figsize=(19.5, 6.4), dpi=100)
    axes[0].imshow(np.clip(panel_a, 0, 255).astype(np.uint8))
    mask_txt = ", ".join(f"{names[v - 1]}" for v in present) or "no masks"
    kind = "camera image and masks" if rgb is not None else "label masks (the tour has no RGB topic)"
    n_cls = f"{len(present)} class{'' if len(present) == 1 else 'es'}"
    axes[0].set_title(f"(a) {kind}\n{n_cls} in view: {mask_txt}")
    for ax in axes[1:]:
        ax.imshow(np.clip(back, 0, 255).astype(np.uint8))
    scatter(axes[1], mob_raw)
    t1 = f"(b) without the filter: {k} points in view\n{counts(mob_raw)}"
    if t_mob is not None:
        t1 += f"; {int(wrong(mob_raw).sum())} wrong"
    axes[1].set_title(t1)
    n_rel = int(relab.sum())
    if n_rel:
        axes[2].scatter(uv[relab, 0], uv[relab, 1], s=size * 5, color=np.array(_HALO) / 255, edgecolors="none",
                        zorder=2)
    scatter(axes[2], mob_f)
    t2 = f"(c) with the filter: {n_rel} relabelled unknown\n{counts(mob_f)}"
    if t_mob is not None:
        t2 += f"; {int(wrong(mob_f).sum())} still wrong"
    axes[2].set_title(t2)
    for ax in axes:
        ax.set_xlim(-0.5, w - 0.5)
        ax.set_ylim(h - 0.5, -0.5)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.title.set_fontsize(11)
    # legends below the panels, never over the points
    if present:
        axes[0].legend(handles=[Patch(color=rgb01(class_color(names[v - 1])), label=names[v - 1])
                                for v in present], loc="upper center", bbox_to_anchor=(0.5, -0.02),
                       ncol=min(len(present), 5), fontsize=10, frameon=False)
    handles = [Line2D([], [], ls="", marker="o", markersize=8, markerfacecolor=rgb01(POINT_COLORS[m]),
                      markeredgecolor="black", label=m.label.replace("_", "-")) for m in
               (Mobility.DYNAMIC, Mobility.SEMI_STATIC, Mobility.STATIC)]
    handles.append(Line2D([], [], ls="", marker="o", markersize=8, markerfacecolor="none", markeredgecolor="black",
                          label="unknown"))
    handles.append(Line2D([], [], ls="", marker="o", markersize=14, markerfacecolor=rgb01(_HALO),
                          markeredgecolor="none", label="relabelled by the filter"))
    if t_mob is not None:
        handles.append(Line2D([], [], ls="", marker="x", markersize=8, color="black", markeredgewidth=0.9,
                              label="wrong (true mobility differs)"))
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.66, 0.0), ncol=len(handles), fontsize=10,
               frameon=False)
    view_dt = (view.stamp_ns - pair.scan.stamp_ns) / 1e9
    fig.suptitle(title or f"scan at {pair.scan.stamp_ns / 1e9:.3f} s, image {view_dt:+.3f} s: LiDAR points on the "
                          f"camera's masks, without and with the occlusion filter", fontsize=12)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    out_png.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_png.with_name(f".{out_png.stem}.part.png")
    try:
        fig.savefig(tmp)
        os.replace(tmp, out_png)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return out_png


def picture(
    tour: str | Path,
    out_png: str | Path,
    config: str | Path | BuildConfig | None = None,
    calibration: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    at: int | None = None,
    image: int | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> PictureResult:
    """Paint ``tour`` and draw Fig. 6 for one scan (see :class:`ImagePicker` for which)."""
    out_png = Path(out_png)
    if out_png.exists() and not force:
        raise OutputExistsError(f"{out_png}: exists (use --force to replace it)")
    picker = ImagePicker(at, image)
    for pair in iter_painted(tour, config, calibration, overrides, progress):
        picker.offer(pair)
    return draw_picked(picker, tour, out_png, config, calibration)


def draw_picked(picker: ImagePicker, tour: str | Path, out_png: str | Path,
                config: str | Path | BuildConfig | None = None,
                calibration: str | Path | None = None) -> PictureResult:
    """Draw the scan ``picker`` kept, over the tour's RGB image when it has one."""
    pair = picker.best
    if pair is None or pair.view is None:
        if picker.image is not None and picker.images_seen <= picker.image:
            raise ConfigError(f"{tour}: image {picker.image} asked for, but the scans were painted with only "
                              f"{picker.images_seen} camera images")
        raise BagError(f"{tour}: no scan fell into a camera image, so there is nothing to draw")
    img = camera_image(tour, pair.view.stamp_ns, config, calibration)
    paint_picture(pair, out_png, img)
    return PictureResult(Path(out_png), pair.scan.stamp_ns, pair.view.stamp_ns, int(pair.view.beams.size),
                         pair.relabelled, img is not None)
