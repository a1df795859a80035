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
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..config import BuildConfig
from ..grid import CleanedMap, GridLayers
from ..io.mapserver import write_map
from ..io.tum import write_tum
from ..io.yamlio import write_yaml
from ..runtime import peak_rss_mb
from .summary import BuildSummary

__all__ = ["GRID_FORMAT_VERSION", "MAP_FOLDER_VERSION", "BuildOutcome", "write_map_folder"]

#: the layout of the map folder (``summary.json``'s keys and the files); :func:`semmap.load_map` reads
#: this version and the ones before it. 2: camera images are "images" in ``summary.json`` (version 1
#: said "frames", the word now kept for coordinate frames).
MAP_FOLDER_VERSION = 2
#: the layout of ``grid.npz`` (its ``format_version``), unchanged since the first map folder
GRID_FORMAT_VERSION = 1


@dataclass(frozen=True)
class BuildOutcome:
    """Everything a build made, cleaned, ready to be written as a map folder.

    ``layers`` and ``cleaned`` are cut to the observed part of the grid; ``poses`` (N, 3) are
    the base's poses in the map frame at ``stamps_ns``, ``odometry`` (N, 3) the odometry poses at the
    same stamps (rows of NaN where there was none). ``summary`` is complete but for what only
    writing knows (the write time, the total time, the files, the main process's peak memory).
    ``started`` is the ``time.perf_counter()`` of the build's start.
    """

    config: BuildConfig
    class_names: tuple[str, ...]
    layers: GridLayers
    cleaned: CleanedMap
    stamps_ns: NDArray[np.int64]
    poses: NDArray[np.float64]
    odometry: NDArray[np.float64]
    summary: BuildSummary
    started: float
    #: (N,) per scan: 0 no labels, 1 painted from a segmented frame, 2 labelled from earlier frames (None: unknown)
    labels_from: NDArray[np.uint8] | None = None


def write_map_folder(out: Path, outcome: BuildOutcome) -> BuildSummary:
    """Write every file of the map folder into ``out``; return the summary as written."""
    t1 = time.perf_counter()
    cleaned, layers = outcome.cleaned, outcome.layers
    spec = cleaned.spec
    write_map(out / "map.yaml", spec, cleaned.occupied, known=~cleaned.unknown)
    write_map(out / "semi_static.yaml", spec, cleaned.semi_static, known=~cleaned.unknown)
    objects = [o.as_dict() for o in cleaned.objects]
    (out / "semi_static_objects.json").write_text(json.dumps({"frame_id": "map", "objects": objects}, indent=2),
                                                  encoding="utf-8")
    np.savez_compressed(
        out / "grid.npz",
        format_version=np.int32(GRID_FORMAT_VERSION),
        resolution=np.float64(spec.resolution),
        origin=np.array([spec.origin_x, spec.origin_y], np.float64),
        log_odds=layers.log_odds,
        hits=layers.hits,
        free=layers.free,
        mobility=layers.mobility,
        class_counts=layers.class_counts,
        class_ids=np.asarray(layers.class_ids, np.int32),
        sightings=layers.sightings,
        class_names=np.asarray(outcome.class_names if outcome.class_names else ("",), dtype=str),
        occupied=cleaned.occupied,
        semi_static=cleaned.semi_static,
        dynamic_removed=cleaned.dynamic_removed,
    )
    stamps = outcome.stamps_ns
    write_tum(out / "trajectory.tum", stamps, outcome.poses)
    odom = outcome.odometry
    have_odom = np.isfinite(odom[:, 0])
    if have_odom.any():
        write_tum(out / "odometry.tum", stamps[have_odom], odom[have_odom])
    write_yaml(out / "config.yaml", outcome.config.model_dump(mode="json"), "# effective semmap build configuration\n")

    from .report import render_pictures, write_report

    pictures = render_pictures(out, outcome)
    s = outcome.summary
    elapsed = time.perf_counter() - outcome.started
    n = s.counts.scans
    timings = s.timings_s.model_copy(update={"write": round(time.perf_counter() - t1, 3),
                                             "total": round(elapsed, 3)})
    throughput = s.throughput.model_copy(update={
        "scans_per_s_end_to_end": round(n / elapsed, 1) if elapsed > 0 else None})
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) + ["summary.json",
                                                                                          "report.md"]
    summary = s.model_copy(update={"timings_s": timings, "throughput": throughput,
                                   "peak_rss_mb": round(peak_rss_mb(), 1), "files": files})
    (out / "summary.json").write_text(summary.to_json(), encoding="utf-8")
    write_report(out / "report.md", summary.model_dump(mode="json"), pictures)
    return summary
