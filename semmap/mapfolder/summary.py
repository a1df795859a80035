"""``summary.json``: the numbers of one build, typed.

:class:`BuildSummary` is written by :func:`semmap.mapfolder.writer.write_map_folder` and read back by
:func:`semmap.load_map`. Its JSON keys are the field names below, in this order.
"""

from __future__ import annotations

import json
from typing import Any

from pydantic import BaseModel, ConfigDict

__all__ = [
    "BuildSummary",
    "CountsSummary",
    "MapSummary",
    "MessagesSummary",
    "OcclusionSummary",
    "PaintingSummary",
    "ThroughputSummary",
    "TimingsSummary",
    "TourFrames",
    "TourSummary",
    "TourTopics",
]


class _Part(BaseModel):
    # extra keys are ignored on reading: a folder of the same map_folder_version may carry more
    model_config = ConfigDict(extra="ignore", frozen=True)


class TourTopics(_Part):
    scan: str
    image: str | None
    image_kind: str | None
    odometry: str | None  # the Odometry topic, or "/tf (odom -> base_footprint)" for odometry from /tf
    tf_static: str | None


class TourFrames(_Part):
    base: str
    lidar: str
    map: str = "map"


class TourSummary(_Part):
    """Where the data came from, and what was found in it."""

    bag: str
    scenario: str | None
    duration_s: float
    topics: TourTopics
    frames: TourFrames
    T_base_lidar: list[list[float]]
    T_base_lidar_source: str
    calibration: str | None


class MessagesSummary(_Part):
    read: dict[str, int]  # messages read, per topic
    skipped: dict[str, int]  # messages that could not be read, per topic
    odometry_out_of_order: int


class CountsSummary(_Part):
    scans: int  # scans painted and mapped
    scans_without_image: int
    scans_without_odometry: int
    odometry: int  # odometry messages (from /tf: odometry transforms)
    bad_scans: int  # no beams, or no angle increment
    scans_out_of_order: int  # repeated or backwards stamps
    images: int  # camera images segmented
    bad_images: int  # camera images that could not be read or segmented
    #: camera images the frame selection left out (segmentation.select, max_rate); None: written before it
    skipped_images: int | None = None


class OcclusionSummary(_Part):
    on: bool
    points_relabelled: int
    points_relabelled_per_painted_scan: float
    points_relabelled_max_per_scan: int
    scans_with_relabelled_points: int


class FrameSelectionSummary(_Part):
    """Which camera frames the model ran on (``segmentation.select``), and what the others' scans took."""

    select: str
    max_rate: float | None
    max_frames: int | None = None
    max_seconds: float | None = None
    frames_segmented: int
    frames_skipped: int
    #: scans paired with a skipped frame, which take labels cell by cell from the segmented ones, and the
    #: returns that took one (structure and furniture through the registered poses, people through the odometry)
    scans_from_memory: int
    returns_labelled_from_memory: int


class PaintingSummary(_Part):
    class_list: str | None
    backend: str | None
    scans_painted: int
    frame_selection: FrameSelectionSummary | None = None  # None: written before frames were selected
    readings_below_range_min_fraction: float
    # None: not recorded (folders written before these were counted)
    readings_below_range_min_unblocked_fraction: float | None = None  # on beams not masked as blocked
    readings_nan_fraction: float | None = None
    readings_nan_unblocked_fraction: float | None = None  # on beams not masked as blocked
    blocked_beams: int | None = None  # beams masked as blocked (paint.blocked_share), over all beam layouts
    # their contiguous sectors: {"first_deg", "last_deg", "beams"}, angles in the LiDAR frame
    blocked_sectors: list[dict[str, float]] | None = None
    points_in_view_fraction: float
    occlusion_filter: OcclusionSummary
    hits_by_mobility: dict[str, int]
    hits_by_class: dict[str, int]


class MapSummary(_Part):
    resolution: float
    origin: list[float]
    size_cells: list[int]
    size_m: list[float]
    occupied_cells: int
    free_cells: int
    semi_static_cells: int
    dynamic_cells_removed: int
    semi_static_objects: int
    semi_static_objects_by_class: dict[str, int]
    #: cells some scan hit or crossed
    observed_cells: int | None = None
    #: the grid while fusing: its tiles (grid.tile_margin m on a side) and their layers' bytes, and
    #: those bytes per observed cell (what a building costs, whatever its outline)
    grid_tiles: int | None = None
    grid_bytes: int | None = None
    grid_bytes_per_observed_cell: float | None = None


class TimingsSummary(_Part):
    """Wall time of each step, s (``*_busy``: the worker's own working time beside the loop)."""

    read: float
    paint: float
    hand_over: float
    wait_images: float = 0.0
    clean: float
    write: float
    register_busy: float
    fuse_busy: float
    loop: float
    total: float
    segmentation_busy: float
    workers: bool


class ThroughputSummary(_Part):
    scans_per_s: float | None
    scans_per_s_end_to_end: float | None
    real_time_factor: float | None


class ConsistencySummary(_Part):
    """How well the scans agree with the map (:mod:`semmap.grid.consistency`); no ground truth needed."""

    endpoints_on_map: float  # share of sampled returns within one cell of an occupied cell of map.yaml
    wall_thickness_m: float  # mean thickness of the occupied structures
    endpoints_sampled: int


class BuildSummary(_Part):
    """What one ``semmap build`` read, did and wrote."""

    semmap_version: str
    map_folder_version: int
    created_unix_s: float
    machine: str
    tour: TourSummary
    messages: MessagesSummary
    counts: CountsSummary
    painting: PaintingSummary
    registration: dict[str, Any]  # "mode", then the registrar's counters (they depend on the mode)
    warnings: list[str]
    map: MapSummary
    timings_s: TimingsSummary
    #: CPU time of the streaming loop per process, s; on a machine with fewer cores than busy processes
    #: their sum, not the busiest one, bounds the speed
    cpu_s: dict[str, float | None]
    throughput: ThroughputSummary
    peak_rss_mb: float
    peak_rss_mb_workers: dict[str, float]
    files: list[str]
    #: None in map folders written before semmap scored it
    consistency: ConsistencySummary | None = None

    def to_json(self) -> str:
        """The text of ``summary.json`` (Python's JSON float formatting, as every earlier folder)."""
        return json.dumps(self.model_dump(mode="json"), indent=2)
