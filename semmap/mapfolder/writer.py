"""Writing the map folder (see README, "The map folder")::

    OUT/
      map.yaml + map.pgm          the cleaned map for map_server / nav2 (trinary)
      semantic.png                the map coloured by mobility and class, objects outlined, legend, scale bar
      semi_static.yaml + .pgm     the cells flagged movable (occupied = semi-static)
      semi_static_objects.json    movable objects: class, centroid, extent, cells
      grid.npz                    full fidelity: log-odds, hit/free counts, mobility and class counts,
                                  the sightings of objects the object list was grouped by
      trajectory.tum              base_link poses in the map frame, one per scan
      odometry.tum                the wheel odometry at the same stamps (odom frame)
      config.yaml                 the effective configuration
      summary.json                the numbers
      report.md                   for people: pictures, counts, timings
      report/*.png                the report's pictures
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import __version__
from ..config import BuildConfig
from ..io.bag import ReadStats
from ..io.mapserver import write_map
from ..io.tum import write_tum
from ..io.yamlio import write_yaml
from ..workers import peak_rss_mb

if TYPE_CHECKING:
    from ..grid import CleanedMap, GridLayers
    from ..io.tour import Tour
    from ..pipeline import _Pipeline

__all__ = ["write_map_folder", "MAP_FOLDER_VERSION"]

MAP_FOLDER_VERSION = 1


def _crop_to_observed(layers: GridLayers, cleaned: CleanedMap, margin_m: float) -> tuple[GridLayers, CleanedMap]:
    """Cut the grid down to the observed cells plus a margin (the fusion window grows in big steps)."""
    from ..grid.clean import crop_sightings

    rows, cols = np.nonzero(~cleaned.unknown)
    if rows.size == 0:
        return layers, cleaned
    m = int(np.ceil(margin_m / layers.spec.resolution))
    h, w = layers.spec.shape
    r0, r1 = max(int(rows.min()) - m, 0), min(int(rows.max()) + 1 + m, h)
    c0, c1 = max(int(cols.min()) - m, 0), min(int(cols.max()) + 1 + m, w)
    spec = layers.spec.crop(r0, r1, c0, c1)
    win = (slice(r0, r1), slice(c0, c1))
    layers = replace(layers, spec=spec, log_odds=layers.log_odds[win], hits=layers.hits[win], free=layers.free[win],
                     mobility=layers.mobility[(slice(None), *win)],
                     class_counts=layers.class_counts[(slice(None), *win)],
                     sightings=crop_sightings(layers.sightings, r0, r1, c0, c1))
    cleaned = replace(cleaned, spec=spec, occupied=cleaned.occupied[win], free=cleaned.free[win],
                      unknown=cleaned.unknown[win], semi_static=cleaned.semi_static[win],
                      dynamic_removed=cleaned.dynamic_removed[win])
    return layers, cleaned


def write_map_folder(out: Path, tour: Tour, cfg: BuildConfig, pipe: _Pipeline, layers: GridLayers,
                     stats: ReadStats, loop_s: float, t_start: float) -> dict[str, Any]:
    """Clean the fused grid and write every file of the map folder into ``out``.

    ``loop_s`` is the wall time of the streaming loop (read, paint, register, fuse).
    """
    from ..grid import clean

    t0 = time.perf_counter()
    cleaned = clean(layers, cfg.cleaning, pipe.class_names)
    layers, cleaned = _crop_to_observed(layers, cleaned, margin_m=1.0)
    pipe.timers.clean = time.perf_counter() - t0
    t1 = time.perf_counter()
    spec = cleaned.spec

    write_map(out / "map.yaml", spec, cleaned.occupied, known=~cleaned.unknown)
    write_map(out / "semi_static.yaml", spec, cleaned.semi_static, known=~cleaned.unknown)
    objects = [o.as_dict() for o in cleaned.objects]
    (out / "semi_static_objects.json").write_text(json.dumps({"frame_id": "map", "objects": objects}, indent=2),
                                                  encoding="utf-8")
    np.savez_compressed(
        out / "grid.npz",
        format_version=np.int32(MAP_FOLDER_VERSION),
        resolution=np.float64(spec.resolution),
        origin=np.array([spec.origin_x, spec.origin_y], np.float64),
        log_odds=layers.log_odds,
        hits=layers.hits,
        free=layers.free,
        mobility=layers.mobility,
        class_counts=layers.class_counts,
        class_ids=np.asarray(layers.class_ids, np.int32),
        sightings=layers.sightings,
        class_names=np.asarray(pipe.class_names if pipe.class_names else ("",), dtype=str),
        occupied=cleaned.occupied,
        semi_static=cleaned.semi_static,
        dynamic_removed=cleaned.dynamic_removed,
    )
    stamps = pipe.trace.stamps
    poses = np.asarray(pipe.trace.poses, np.float64).reshape(-1, 3)
    write_tum(out / "trajectory.tum", stamps, poses)
    odom = pipe.trace.odom
    have_odom = np.isfinite(odom[:, 0])
    if have_odom.any():
        write_tum(out / "odometry.tum", stamps[have_odom], odom[have_odom])
    write_yaml(out / "config.yaml", cfg.model_dump(mode="json"), "# effective semmap build configuration\n")

    from .report import render_pictures, write_report

    pictures = render_pictures(out, cleaned, layers, pipe)
    pipe.timers.write = time.perf_counter() - t1
    elapsed = time.perf_counter() - t_start
    n = pipe.counts["scans"]
    loop = loop_s
    span_s = (stamps[-1] - stamps[0]) * 1e-9 if n > 1 else 0.0
    by_class: dict[str, int] = {}
    for o in cleaned.objects:
        by_class[o.class_name] = by_class.get(o.class_name, 0) + 1
    summary: dict[str, Any] = {
        "semmap_version": __version__,
        "map_folder_version": MAP_FOLDER_VERSION,
        "created_unix_s": round(time.time(), 3),
        "machine": f"{platform.machine()}, Python {platform.python_version()}",
        "tour": {
            "bag": str(tour.bag),
            "scenario": tour.manifest.get("scenario"),
            "duration_s": round(span_s, 3),
            "topics": {"scan": tour.topics.scan, "frames": tour.topics.frames, "frames_kind": tour.topics.frames_kind,
                       "odometry": tour.topics.odometry, "tf_static": tour.topics.tf_static},
            "frames": {"base": tour.base_frame, "lidar": tour.lidar_frame, "map": "map"},
            "T_base_lidar": np.round(tour.T_base_lidar, 9).tolist(),
            "T_base_lidar_source": tour.T_base_lidar_source,
            "calibration": tour.calibration_source or None,
        },
        "messages": {"read": stats.read, "skipped": stats.skipped,
                     "odometry_out_of_order": pipe.odom.out_of_order if pipe.odom is not None else 0},
        "counts": {**pipe.counts, **{k: v for k, v in pipe.frame_counts.items()
                                     if k not in ("segment_ms", "peak_rss_mb", "cpu_s")}},
        "painting": {
            "class_list": cfg.segmentation.class_list if pipe.class_names else None,
            "backend": cfg.segmentation.backend if pipe.class_names else None,
            "scans_painted": pipe.painter.stats.painted,
            "readings_below_range_min_fraction": round(pipe.painter.stats.below_range_min
                                                       / max(pipe.painter.stats.beams, 1), 4),
            "points_in_view_fraction": round(pipe.painter.stats.points_in_view
                                             / max(pipe.painter.stats.points_total, 1), 4),
            "occlusion_filter": {
                "on": cfg.paint.occlusion_filter,
                "points_relabelled": pipe.painter.stats.occlusion_relabelled,
                "points_relabelled_per_painted_scan": round(pipe.painter.stats.occlusion_relabelled
                                                            / max(pipe.painter.stats.painted, 1), 2),
                "points_relabelled_max_per_scan": pipe.painter.stats.occlusion_max_per_scan,
                "scans_with_relabelled_points": pipe.painter.stats.occlusion_scans,
            },
            "hits_by_mobility": {m: int(v) for m, v in zip(("unknown", "static", "semi_static", "dynamic"),
                                                          pipe.mobility_hits)},
            "hits_by_class": {pipe.class_names[i]: int(v) for i, v in enumerate(pipe.class_hits) if v > 0},
        },
        "registration": {"mode": cfg.registration.mode, **pipe.result.registration},
        "warnings": pipe.warnings,
        "map": {
            "resolution": spec.resolution,
            "origin": [spec.origin_x, spec.origin_y, 0.0],
            "size_cells": [spec.width, spec.height],
            "size_m": [round(spec.width * spec.resolution, 2), round(spec.height * spec.resolution, 2)],
            "occupied_cells": int(cleaned.occupied.sum()),
            "free_cells": int(cleaned.free.sum()),
            "semi_static_cells": int(cleaned.semi_static.sum()),
            "dynamic_cells_removed": int(cleaned.dynamic_removed.sum()),
            "semi_static_objects": len(objects),
            "semi_static_objects_by_class": by_class,
        },
        "timings_s": {**pipe.timers.as_dict(),
                      "register_busy": round(pipe.result.register_busy_s, 3),
                      "fuse_busy": round(pipe.result.fuse_busy_s, 3),
                      "loop": round(loop, 3), "total": round(elapsed, 3),
                      "segmentation_busy": round(pipe.frame_counts.get("segment_ms", 0) / 1000.0, 3),
                      "workers": cfg.workers},
        # CPU time of the streaming loop per process: on a machine with fewer cores than busy
        # processes, their sum, not the busiest one, bounds the speed
        "cpu_s": {**pipe.cpu_s, "total": round(sum(pipe.cpu_s.values()), 3),
                  "per_scan_ms": round(1000 * sum(pipe.cpu_s.values()) / n, 3) if n else None},
        "throughput": {
            "scans_per_s": round(n / loop, 1) if loop > 0 else None,
            "scans_per_s_end_to_end": round(n / elapsed, 1) if elapsed > 0 else None,
            "real_time_factor": round(span_s / loop, 1) if loop > 0 and span_s > 0 else None,
        },
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "peak_rss_mb_workers": {**pipe.result.peak_rss_mb,
                                **({"frames": pipe.frame_counts["peak_rss_mb"]}
                                   if "peak_rss_mb" in pipe.frame_counts else {})},
        "files": sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) + ["summary.json",
                                                                                               "report.md"],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    write_report(out / "report.md", summary, pictures)
    return summary
