"""Reading a map folder back: :func:`load_map_folder` (``semmap.load_map``).

The occupancy is read from ``map.yaml`` + ``map.pgm`` the way map_server reads it (thresholds,
``negate``, the image flipped into grid order), so what Python sees is what a robot loads; the rest
from ``grid.npz`` (read without pickle), ``semi_static_objects.json``, ``trajectory.tum``,
``odometry.tum``, ``config.yaml`` and ``summary.json``.

Every error is one :class:`~semmap.errors.MapFolderError` naming the file.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from ..config import BuildConfig
from ..errors import MapFolderError, SemmapError
from ..grid import CleanedMap, GridLayers, SemiStaticObject
from ..io.mapserver import read_map
from ..io.tum import read_tum
from ..records import GridSpec
from .summary import BuildSummary
from .writer import GRID_FORMAT_VERSION, MAP_FOLDER_VERSION

__all__ = ["MapFolder", "load_map_folder"]


@dataclass(frozen=True)
class MapFolder:
    """A map folder written by ``semmap build``, read back.

    * ``summary``: ``summary.json`` (:class:`~semmap.mapfolder.summary.BuildSummary`).
    * ``config``: the effective build configuration (``config.yaml``): building the tour again with it
      gives the same map.
    * ``cleaned``: the map: ``occupied``, ``free``, ``unknown`` as map_server reads ``map.yaml``;
      ``semi_static``, ``dynamic_removed`` and the movable ``objects`` (grid order: row 0 = lowest y).
    * ``layers``: the fused grid's evidence (``grid.npz``): log-odds, hit and free counts, hits per
      mobility and per class, the object sightings.
    * ``stamps_ns``, ``poses`` (N, 3): the base's pose in the map frame (x, y, yaw) at each scan
      (``trajectory.tum``); ``odometry`` (M, 3) at ``odometry_stamps_ns``: the wheel odometry in the
      odom frame (empty when the tour had none).
    """

    path: Path
    summary: BuildSummary
    config: BuildConfig
    cleaned: CleanedMap
    layers: GridLayers
    stamps_ns: NDArray[np.int64]
    poses: NDArray[np.float64]
    odometry_stamps_ns: NDArray[np.int64]
    odometry: NDArray[np.float64]

    @property
    def spec(self) -> GridSpec:
        """The grid: resolution, origin (the lower-left corner of cell (0, 0)), width, height."""
        return self.cleaned.spec

    @property
    def occupied(self) -> NDArray[np.bool_]:
        return self.cleaned.occupied

    @property
    def free(self) -> NDArray[np.bool_]:
        return self.cleaned.free

    @property
    def unknown(self) -> NDArray[np.bool_]:
        return self.cleaned.unknown

    @property
    def semi_static(self) -> NDArray[np.bool_]:
        return self.cleaned.semi_static

    @property
    def objects(self) -> tuple[SemiStaticObject, ...]:
        return self.cleaned.objects

    @property
    def class_names(self) -> tuple[str, ...]:
        return self.layers.class_names


def _need(folder: Path, name: str) -> Path:
    p = folder / name
    if not p.is_file():
        raise MapFolderError(f"{p}: missing (is {folder} a map folder written by semmap build?)")
    return p


def _summary(folder: Path) -> BuildSummary:
    p = _need(folder, "summary.json")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapFolderError(f"{p}: not readable JSON ({exc})") from None
    if not isinstance(data, dict):
        raise MapFolderError(f"{p}: expected a JSON object")
    version = data.get("map_folder_version")
    if version not in (1, MAP_FOLDER_VERSION):
        raise MapFolderError(f"{p}: map_folder_version {version!r}; this semmap reads versions 1 to "
                             f"{MAP_FOLDER_VERSION} (written by semmap {data.get('semmap_version', '?')}): rebuild "
                             f"the map with this semmap, or read it with the semmap that wrote it")
    if version == 1:
        data = _summary_from_v1(data)
    try:
        return BuildSummary.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(x) for x in err["loc"])
        raise MapFolderError(f"{p}: {where}: {err['msg']}") from None


def _summary_from_v1(data: dict[str, Any]) -> dict[str, Any]:
    """A version-1 ``summary.json`` in version 2's keys: its camera images were "frames"."""

    def renamed(part: Any, old: str, new: str) -> None:
        if isinstance(part, dict) and old in part:
            part[new] = part.pop(old)

    data = json.loads(json.dumps(data))  # a deep copy
    topics = data.get("tour", {}).get("topics")
    renamed(topics, "frames", "image")
    renamed(topics, "frames_kind", "image_kind")
    renamed(data.get("counts"), "frames", "images")
    renamed(data.get("counts"), "bad_frames", "bad_images")
    renamed(data.get("cpu_s"), "frames", "images")
    renamed(data.get("peak_rss_mb_workers"), "frames", "images")
    data["map_folder_version"] = MAP_FOLDER_VERSION
    return data


def _grid(folder: Path) -> dict[str, NDArray[Any]]:
    p = _need(folder, "grid.npz")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise MapFolderError(f"{p}: not a readable grid ({exc})") from None
    need = ("format_version", "resolution", "origin", "log_odds", "hits", "free", "mobility", "class_counts",
            "class_ids", "class_names", "occupied", "semi_static", "dynamic_removed")
    missing = [k for k in need if k not in data]
    if missing:
        raise MapFolderError(f"{p}: missing arrays {', '.join(missing)}")
    if int(data["format_version"]) != GRID_FORMAT_VERSION:
        raise MapFolderError(f"{p}: format_version {int(data['format_version'])}; this semmap reads "
                             f"{GRID_FORMAT_VERSION}")
    return data


def load_map_folder(path: str | Path) -> MapFolder:
    """Read the map folder at ``path`` (written by ``semmap build``) back.

    Raises :class:`~semmap.errors.MapFolderError` when a file is missing or damaged, or when the
    folder was written by a semmap with another map-folder layout (``map_folder_version``).
    """
    folder = Path(path)
    if not folder.is_dir():
        raise MapFolderError(f"{folder}: no such map folder")
    summary = _summary(folder)
    g = _grid(folder)
    try:
        seen = read_map(_need(folder, "map.yaml"))
    except SemmapError as exc:
        raise MapFolderError(str(exc)) from None
    spec = seen.spec
    res, origin = float(g["resolution"]), np.asarray(g["origin"], np.float64)
    if (g["occupied"].shape != spec.shape or not np.isclose(res, spec.resolution)
            or not np.allclose(origin, (spec.origin_x, spec.origin_y))):
        raise MapFolderError(f"{folder / 'grid.npz'}: does not match {folder / 'map.yaml'} (size, resolution or "
                             f"origin): files from different builds?")
    names = tuple(str(n) for n in g["class_names"])
    names = () if names == ("",) else names  # a LiDAR-only map: the writer stores one empty name
    try:
        layers = GridLayers(spec=spec, log_odds=g["log_odds"], hits=g["hits"], free=g["free"],
                            mobility=g["mobility"], class_counts=g["class_counts"],
                            class_ids=tuple(int(c) for c in g["class_ids"]), class_names=names,
                            n_scans=summary.counts.scans,
                            sightings=g.get("sightings", np.zeros((0, 4), np.int32)))
    except ValueError as exc:
        raise MapFolderError(f"{folder / 'grid.npz'}: {exc}") from None
    objects_path = _need(folder, "semi_static_objects.json")
    try:
        objects = tuple(SemiStaticObject.from_dict(o)
                        for o in json.loads(objects_path.read_text(encoding="utf-8"))["objects"])
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise MapFolderError(f"{objects_path}: malformed object list ({exc!r})") from None
    try:
        cleaned = CleanedMap(spec=spec, occupied=seen.occupied, free=seen.free, unknown=seen.unknown,
                             semi_static=g["semi_static"], dynamic_removed=g["dynamic_removed"], objects=objects)
    except ValueError as exc:
        raise MapFolderError(f"{folder / 'grid.npz'}: {exc}") from None
    try:
        stamps, poses = read_tum(_need(folder, "trajectory.tum"))
        odom = folder / "odometry.tum"
        o_stamps, o_poses = read_tum(odom) if odom.is_file() else (np.zeros(0, np.int64), np.zeros((0, 3)))
    except SemmapError as exc:
        raise MapFolderError(str(exc)) from None
    config = _config(folder)
    for a in (stamps, poses, o_stamps, o_poses):
        a.setflags(write=False)
    return MapFolder(folder, summary, config, cleaned, layers, stamps, poses, o_stamps, o_poses)


def _config(folder: Path) -> BuildConfig:
    from ..io.tour import load_build_config

    try:
        cfg, _ = load_build_config(_need(folder, "config.yaml"))
    except MapFolderError:
        raise
    except SemmapError as exc:
        raise MapFolderError(str(exc)) from None
    return cfg
