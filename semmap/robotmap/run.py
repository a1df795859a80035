"""``semmap export``: maps for a robot from a saved session (see :func:`export_session`)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..geometry import dilate_mask, se2_apply
from ..grid import SemiStaticObject
from ..mapfolder.reader import MapFolder
from ..records import GridSpec
from ..version import __version__
from .encode import MapEncoding, write_layer
from .geometry import crop_box, dominant_direction, rotated_spec, warp_mask, warp_plane
from .layers import BASE_LAYERS, Plane, layer_plane, people_cells
from .masks import MaskSettings, keepout_mask, speed_mask, write_filter_params, write_speed_mask

__all__ = ["ExportResult", "ExportSettings", "export_session", "objects_geojson"]


@dataclass(frozen=True)
class ExportSettings:
    """What ``semmap export`` writes, and how.

    ``layers``: names from :data:`~semmap.robotmap.layers.BASE_LAYERS` or ``class:NAME``.
    ``resolution``: resample to this cell size (m; None keeps the build's). ``crop_margin``: crop to
    the observed cells plus this margin (m; None: no crop). ``straighten``: turn the map so its walls
    run along the image axes (``rotate_deg``: by this angle instead). ``masks``: write the nav2 keepout and speed masks.
    """

    layers: tuple[str, ...] = BASE_LAYERS
    encoding: MapEncoding = field(default_factory=MapEncoding)
    resolution: float | None = None
    crop_margin: float | None = None
    straighten: bool = False
    #: turn the map by this angle (degrees, counter-clockwise) instead of to the walls
    rotate_deg: float | None = None
    masks: bool = True
    mask_settings: MaskSettings = field(default_factory=MaskSettings)

    def __post_init__(self) -> None:
        if not self.layers:
            raise ConfigError("give at least one layer")
        if len(set(self.layers)) != len(self.layers):
            raise ConfigError(f"--layer given twice: {', '.join(self.layers)}")
        if self.resolution is not None and not 0.005 <= self.resolution <= 10.0:
            raise ConfigError(f"--resolution must be between 0.005 and 10 m, got {self.resolution}")
        if self.straighten and self.rotate_deg is not None:
            raise ConfigError("--straighten and --rotate both turn the map: give one")
        if self.rotate_deg is not None and not abs(self.rotate_deg) <= 360.0:
            raise ConfigError(f"--rotate must be an angle within ±360 degrees, got {self.rotate_deg}")
        if self.crop_margin is not None and not 0.0 <= self.crop_margin <= 100.0:
            raise ConfigError(f"--crop margin must be between 0 and 100 m, got {self.crop_margin}")
        ms = self.mask_settings
        for name in ("speed_near_furniture", "speed_near_people"):
            if not 0 <= getattr(ms, name) <= 100:
                raise ConfigError(f"--{name.replace('_', '-')} must be a per cent from 0 (no zone) to 100, got "
                                  f"{getattr(ms, name)}")
        if not 0.0 <= ms.keepout_margin_m <= 5.0 or not 0.0 <= ms.speed_margin_m <= 10.0:
            raise ConfigError("mask margins must be between 0 and 5 m (keepout) and 0 and 10 m (speed)")


@dataclass(frozen=True)
class ExportResult:
    """What was exported: the grid written, the turn from the build's map frame, the files."""

    spec: GridSpec
    #: the exported maps' frame from the build's map frame, (x, y, yaw): a point ``p`` of the build's
    #: map is at ``se2_apply(T_export_build, p)`` in the exported maps (a pure turn when straightened)
    T_export_build: NDArray[np.float64]
    files: tuple[str, ...]
    counts: dict[str, dict[str, int]]
    warnings: tuple[str, ...]
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        return {"grid": self.spec.as_dict(),
                "T_export_build": [round(float(v), 9) for v in self.T_export_build],
                "files": list(self.files), "cells": self.counts, "warnings": list(self.warnings)}


def _footprints(objs: tuple[SemiStaticObject, ...], T: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    out = []
    for o in objs:
        fp = np.asarray(o.footprint, np.float64).reshape(-1, 2)
        if fp.shape[0] >= 3:
            out.append(se2_apply(T, fp))
    return out


def objects_geojson(objs: tuple[SemiStaticObject, ...], T: NDArray[np.float64] | None = None) -> dict[str, Any]:
    """The movable objects as a GeoJSON FeatureCollection in the map frame (x, y in metres; GeoJSON's
    geographic coordinates do not apply: ``frame_id`` and ``units`` say so): each a Polygon, its
    footprint, with class, centroid, size, heading and views."""
    T = np.zeros(3) if T is None else np.asarray(T, np.float64)
    features = []
    for k, o in enumerate(objs):
        fp = np.asarray(o.footprint, np.float64).reshape(-1, 2)
        c = se2_apply(T, np.asarray([o.centroid], np.float64))[0]
        props = {"id": k, "class": o.class_name, "centroid": [round(float(c[0]), 3), round(float(c[1]), 3)],
                 "size": [round(float(v), 3) for v in o.size],
                 "yaw": round(float(math.remainder(o.yaw + float(T[2]), 2 * math.pi)), 4),
                 "views": int(o.views), "cells": int(o.n_cells)}
        if fp.shape[0] >= 3:
            ring = se2_apply(T, fp)
            if _signed_area(ring) < 0:  # RFC 7946: exterior rings counter-clockwise
                ring = ring[::-1]
            coords = [[round(float(x), 3) + 0.0, round(float(y), 3) + 0.0] for x, y in ring]
            geometry: dict[str, Any] = {"type": "Polygon", "coordinates": [coords + [coords[0]]]}
        else:
            geometry = {"type": "Point", "coordinates": props["centroid"]}
        features.append({"type": "Feature", "id": k, "geometry": geometry, "properties": props})
    return {"type": "FeatureCollection", "frame_id": "map", "units": "m", "features": features}


def _signed_area(ring: NDArray[np.float64]) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _carry(planes: dict[str, Plane], masks: dict[str, NDArray[np.bool_]], src: GridSpec, dst: GridSpec,
           T: NDArray[np.float64]) -> tuple[dict[str, Plane], dict[str, NDArray[np.bool_]]]:
    return ({k: warp_plane(p, src, dst, T) for k, p in planes.items()},
            {k: warp_mask(m, src, dst, T) for k, m in masks.items()})


def export_session(m: MapFolder, out: Path, st: ExportSettings) -> ExportResult:
    """Write the export of map folder ``m`` into the (existing, empty) folder ``out``."""
    t0 = time.perf_counter()
    warnings: list[str] = []
    planes: dict[str, Plane] = {}
    for name in st.layers:
        plane, warn = layer_plane(m, name)
        planes[name] = plane
        if warn:
            warnings.append(warn)
    c = m.cleaned
    observed = ~c.unknown | m.layers.observed
    masks = {"observed": observed, "semi": c.semi_static & c.occupied, "people": people_cells(m)}
    spec = c.spec
    T = np.zeros(3)
    # the target grid first (turned, cropped, resampled), then one warp from the build's grid onto it:
    # each cell is quantised once, so an obstacle lands where its own centre goes
    dst = spec
    if st.straighten or st.rotate_deg:
        angle = (math.radians(st.rotate_deg) if st.rotate_deg is not None
                 else dominant_direction(c.occupied & ~c.semi_static, spec))
        T = np.array([0.0, 0.0, angle])
        dst = rotated_spec(spec, observed, T)
    if st.crop_margin is not None:
        seen = warp_mask(observed, spec, dst, T) if dst != spec else observed
        dst = crop_box(seen, dst, st.crop_margin)
    if st.resolution is not None and not math.isclose(st.resolution, dst.resolution, rel_tol=1e-9):
        w = int(math.ceil(dst.width * dst.resolution / st.resolution - 1e-9))
        h = int(math.ceil(dst.height * dst.resolution / st.resolution - 1e-9))
        dst = GridSpec(float(st.resolution), dst.origin_x, dst.origin_y, max(w, 1), max(h, 1))
    if dst != spec:
        planes, masks = _carry(planes, masks, spec, dst, T)
        spec = dst

    files: list[str] = []
    counts: dict[str, dict[str, int]] = {}
    for name, plane in planes.items():
        stem = name.replace("class:", "class_").replace(" ", "_")
        write_layer(out / f"{stem}.yaml", spec, st.encoding, plane.occupied, plane.free, plane.prob)
        files += [f"{stem}.yaml", f"{stem}.{st.encoding.image_format}"]
        counts[name] = {"occupied": int(plane.occupied.sum()), "free": int(plane.free.sum()),
                        "unknown": int(plane.unknown.sum())}
    footprints = _footprints(c.objects, T)
    keep: NDArray[np.bool_] | None = None
    speed: NDArray[np.uint8] | None = None
    if st.masks:
        ms = st.mask_settings
        furniture = keepout_mask(spec, footprints, masks["semi"], 0.0)
        keep = dilate_mask(furniture, ms.keepout_margin_m / spec.resolution)
        write_layer(out / "keepout_mask.yaml", spec, MapEncoding(), keep, ~keep, np.where(keep, 1.0, 0.0).astype(
            np.float32))
        speed = speed_mask(spec, furniture, masks["people"], ms)
        write_speed_mask(out / "speed_mask.yaml", spec, speed)
        write_filter_params(out / "costmap_filters.yaml", "keepout_mask.yaml", "speed_mask.yaml")
        files += ["keepout_mask.yaml", "keepout_mask.pgm", "speed_mask.yaml", "speed_mask.png",
                  "costmap_filters.yaml"]
        counts["keepout_mask"] = {"keepout": int(keep.sum())}
        counts["speed_mask"] = {f"{v}%": int((speed == v).sum()) for v in np.unique(speed[speed > 0]).tolist()}
    if not m.layers.class_names:
        warnings.append("a LiDAR-only map (no camera classes): no furniture is known, so the keepout mask and "
                        "objects.geojson are empty, and the speed zones near people come from cleaning's leg "
                        "detector alone" if st.masks else "a LiDAR-only map (no camera classes): objects.geojson "
                        "is empty")
    elif not m.cleaned.objects:
        warnings.append("the session has no movable objects: objects.geojson is empty")
    (out / "objects.geojson").write_text(json.dumps(objects_geojson(c.objects, T), indent=1), encoding="utf-8")
    files.append("objects.geojson")

    from .preview import render_preview

    first = planes[st.layers[0]]
    render_preview(out / "preview.png", spec, first, st.layers[0], footprints, keep, speed)
    files.append("preview.png")
    result = ExportResult(spec, T, tuple(files + ["export.json"]), counts, tuple(warnings),
                          time.perf_counter() - t0)
    doc = {"semmap_version": __version__, "session": str(m.path), "settings": _settings_dict(st),
           **result.as_dict()}
    (out / "export.json").write_text(json.dumps(doc, indent=2), encoding="utf-8")
    return result


def _settings_dict(st: ExportSettings) -> dict[str, Any]:
    d = asdict(st)
    d["layers"] = list(st.layers)
    return d
