"""``semmap paint``: the painted scans of a tour, with and without the occlusion filter.

:func:`iter_painted` streams a tour through the same painter ``semmap build`` uses (deskew,
motion compensation to the image time, projection, label lookup) twice per scan: once with
the occlusion filter, once without. :func:`export_painted` writes one row per beam to CSV
or NPZ for anyone to score or plot; :func:`semmap.paint.figure.paint_picture` draws the
research's Fig. 6 for one camera frame: the mask, the painted points without the filter,
and with it.

Scans are paired with images as in ``semmap build``: the image nearest the scan's middle
beam within ``sync.max_image_offset``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..classes import load_class_table
from ..config import BuildConfig
from ..errors import BagError, ConfigError, OutputExistsError
from ..io.bag import OpenBag, read_bag
from ..records import Mobility, PaintedScan, Scan, Segmentation
from ..segment.images import InProcessImages
from .need import make_selector, need_context
from .painter import CameraView, Painter, label_memory
from .stream import ScanStream, open_build_tour, selection_odometry, tour_class_names

__all__ = ["EXPORT_COLUMNS", "PaintExport", "PaintedPair", "export_painted", "iter_painted"]

log = logging.getLogger(__name__)

ProgressFn = Callable[[int, int], None]

#: the columns of the exported file, in order (see docs/occlusion.md, "`semmap paint`")
EXPORT_COLUMNS = ("stamp_ns", "beam", "x", "y", "class_raw", "mobility_raw", "class", "mobility", "object")


@dataclass(frozen=True)
class PaintedPair:
    """One scan painted twice: ``raw`` without the occlusion filter, ``filtered`` with it.

    ``view`` is how the scan fell into the camera (None when no image was paired with it);
    ``segmentation`` the label image it was painted with.
    """

    scan: Scan
    raw: PaintedScan
    filtered: PaintedScan
    view: CameraView | None
    segmentation: Segmentation | None

    @property
    def relabelled(self) -> int:
        """Points the filter made unknown."""
        return int(np.count_nonzero(self.raw.mobility != self.filtered.mobility))


@dataclass(frozen=True)
class PaintExport:
    """What :func:`export_painted` wrote."""

    out: Path
    format: str
    scans: int
    beams: int
    scans_painted: int
    relabelled: int
    relabelled_max_per_scan: int
    class_names: tuple[str, ...] = field(default_factory=tuple)


def iter_painted(
    tour: str | Path,
    config: str | Path | BuildConfig | None = None,
    calibration: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    progress: ProgressFn | None = None,
) -> Iterator[PaintedPair]:
    """Paint every scan of ``tour`` with and without the occlusion filter, in scan order.

    Scans are paired with images and odometry by the same scan stream as ``semmap build``
    (:class:`~semmap.paint.stream.ScanStream`). The filter's parameters come from the config
    (``paint.occlusion``); the filtered painting uses them even where the config switches the
    filter off.
    """
    with read_bag(tour, lazy=True) as bag:  # opened once: the tour, counting and streaming
        yield from _painted_pairs(bag, tour, config, calibration, overrides, progress)


def _painted_pairs(bag: OpenBag, tour: str | Path, config: str | Path | BuildConfig | None,
                   calibration: str | Path | None, overrides: dict[str, Any] | None,
                   progress: ProgressFn | None) -> Iterator[PaintedPair]:
    tinfo, cfg = open_build_tour(tour, config, calibration, overrides, source=bag)
    if tinfo.topics.image is None:
        raise BagError(f"{tinfo.bag}: no camera or label image topic, so nothing to paint; set topics.image "
                       f"or topics.labels")
    names = tour_class_names(tinfo, cfg)
    table = load_class_table(cfg.segmentation.classes_file)
    on = cfg.paint.with_occlusion_filter(True)
    off = cfg.paint.with_occlusion_filter(False)
    # no registration here: the painters pass every label on through the wheel odometry (a build passes
    # structure's and furniture's on in the map frame)
    painter = Painter(tinfo.T_base_lidar, tinfo.calibration, names, table, on, cfg.sync, cfg.grid.no_return_range,
                      memory=label_memory(cfg.segmentation, cfg.grid.resolution, places=True))
    raw_painter = Painter(tinfo.T_base_lidar, tinfo.calibration, names, table, off, cfg.sync,
                          cfg.grid.no_return_range, memory=label_memory(cfg.segmentation, cfg.grid.resolution,
                                                                        places=True))
    odometry = selection_odometry(tinfo, cfg)
    images = InProcessImages(tinfo.bag, tinfo.topics.image, cfg.segmentation,
                             make_selector(cfg.segmentation, odometry, need_context(tinfo, cfg)))
    try:
        for item in ScanStream(tinfo, cfg.sync, images, progress, bag=bag):
            raw = raw_painter.paint(item.scan, item.odometry, item.segmentation)
            filtered = painter.paint(item.scan, item.odometry, item.segmentation)
            seg = item.segmentation if isinstance(item.segmentation, Segmentation) else None  # None: not segmented
            yield PaintedPair(item.scan, raw.painted, filtered.painted, filtered.view, seg)
    finally:
        images.close()


def _beam_rows(pair: PaintedPair) -> dict[str, NDArray[Any]]:
    scan = pair.scan
    n = scan.ranges.size
    r = scan.ranges.astype(np.float64)
    a = scan.angles
    hit = pair.raw.hit
    x = np.where(hit, r * np.cos(a), np.nan)
    y = np.where(hit, r * np.sin(a), np.nan)
    return {
        "stamp_ns": np.full(n, scan.stamp_ns, np.int64),
        "beam": np.arange(n, dtype=np.int32),
        "x": x.astype(np.float32),
        "y": y.astype(np.float32),
        "class_raw": pair.raw.class_id,
        "mobility_raw": pair.raw.mobility,
        "class": pair.filtered.class_id,
        "mobility": pair.filtered.mobility,
        "object": np.asarray(pair.filtered.instance, np.int32),
    }


def export_painted(
    tour: str | Path,
    out: str | Path,
    config: str | Path | BuildConfig | None = None,
    calibration: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    fmt: str | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
    on_pair: Callable[[PaintedPair], None] | None = None,
) -> PaintExport:
    """Write the painted scans of ``tour`` to ``out``: one row per beam (see :data:`EXPORT_COLUMNS`).

    ``fmt`` is ``"csv"`` or ``"npz"`` (default: from the suffix of ``out``). In CSV the class
    is a name (empty for none) and the mobility a name (``unknown``, ``static``,
    ``semi_static``, ``dynamic``); in NPZ they are the class index into ``class_names``
    (-1 for none) and the mobility value (0-3).

    ``on_pair`` sees every :class:`PaintedPair` as it is written (to pick a frame to draw,
    say, without reading the tour twice).
    """
    out = Path(out)
    fmt = (fmt or out.suffix.lstrip(".")).lower()
    if fmt not in ("csv", "npz"):
        raise ConfigError(f"{out}: cannot tell the format; name the file .csv or .npz")
    if out.exists() and not force:
        raise OutputExistsError(f"{out}: exists (use --force to replace it)")
    if not out.parent.is_dir():
        raise ConfigError(f"{out.parent}: no such folder")
    cols: dict[str, list[NDArray[Any]]] = {c: [] for c in EXPORT_COLUMNS}
    scans = painted = relabelled = worst = beams = 0
    names: tuple[str, ...] = ()
    tmp = out.with_name(f".{out.name}.part")
    try:
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            if fmt == "csv":
                fh.write(",".join(EXPORT_COLUMNS) + "\n")
            for pair in iter_painted(tour, config, calibration, overrides, progress):
                if on_pair is not None:
                    on_pair(pair)
                rows = _beam_rows(pair)
                names = pair.raw.class_names
                if fmt == "csv":
                    fh.write(_csv_chunk(rows, names))
                else:
                    for k, v in rows.items():
                        cols[k].append(v)
                scans += 1
                beams += rows["beam"].size
                painted += pair.view is not None
                n = pair.relabelled
                relabelled += n
                worst = max(worst, n)
        if scans == 0:
            raise BagError(f"{tour}: no usable scans")
        if fmt == "npz":
            data: dict[str, Any] = {k: np.concatenate(v) for k, v in cols.items()}
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **data, class_names=np.asarray(names if names else ("",), dtype=str))
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    log.info("%s: %d scans, %d beams; the occlusion filter relabelled %d points", out, scans, beams, relabelled)
    return PaintExport(out, fmt, scans, beams, painted, relabelled, worst, names)


_MOBILITY_NAMES = np.array([m.label for m in Mobility])


def _csv_chunk(rows: dict[str, NDArray[Any]], names: tuple[str, ...]) -> str:
    """One scan's rows as CSV text: classes and mobilities by name, no return as empty x, y."""
    cls_names = np.array([*names, ""], dtype=object)  # index -1 → ""
    x, y = rows["x"], rows["y"]
    xs = np.where(np.isfinite(x), np.char.mod("%.4f", x), "")
    ys = np.where(np.isfinite(y), np.char.mod("%.4f", y), "")
    stamp = str(int(rows["stamp_ns"][0]))
    cols = [np.full(x.size, stamp, dtype=object), rows["beam"].astype(str), xs, ys,
            cls_names[rows["class_raw"]], _MOBILITY_NAMES[rows["mobility_raw"]],
            cls_names[rows["class"]], _MOBILITY_NAMES[rows["mobility"]], rows["object"].astype(str)]
    lines = [",".join(map(str, r)) for r in zip(*cols)]
    return "\n".join(lines) + "\n"
