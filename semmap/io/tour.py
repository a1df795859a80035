"""Opening a recorded tour: the bag, its topics, frames, calibration and configuration.

A tour is a bag (ROS1 ``.bag`` or ROS2 folder), or a folder holding one (such as
``semmap simulate`` writes, whose ``tour.yaml`` names its topics). Topic names come
from the config; missing ones are detected from message types when the choice is
unambiguous, and an ambiguous or missing topic is an error that lists the candidates.
Odometry comes from the Odometry topic, or from the ``odom → base`` transform on ``/tf``
(``topics.odometry: tf``, or when the bag has no Odometry topic; see :func:`~semmap.io.tf.find_tf_odometry`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from ..config import BuildConfig, load_model, load_yaml
from ..errors import BagError, ConfigError
from ..geometry import se3_from_xyz_rpy
from ..records import Calibration
from .bag import OpenBag, read_bag, resolve_bag_path
from .calibration import read_calibration
from .messages import camera_info_from_msg, odometry_from_msg, scan_from_msg, transforms_from_msg
from .tf import TfOdometry, TfTree, find_tf_odometry
from .topics import TF_TYPES, Topics, pick_topics

__all__ = [
    "Topics",
    "Tour",
    "TourManifest",
    "load_build_config",
    "open_tour",
    "read_tour_manifest",
    "resolve_topics",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Tour:
    """Everything known about a tour before streaming it."""

    bag: Path
    folder: Path | None  # the semmap tour folder, if the bag sits in one
    manifest: dict[str, Any]
    config: BuildConfig
    topics: Topics
    types: dict[str, str]
    lidar_frame: str
    base_frame: str
    T_base_lidar: NDArray[np.float64]
    calibration: Calibration | None
    calibration_path: Path | None  # None: no camera, or the calibration came from the bag (camera_info + /tf)
    T_base_lidar_source: str = ""  # where T_base_lidar came from, for logs and the summary
    calibration_source: str = ""  # where the calibration came from


class TourManifest(BaseModel):
    """The keys of a tour folder's ``tour.yaml`` (written by ``semmap simulate``) that semmap reads.

    The others (seed, message counts, clearances, ground-truth files...) are for people and other
    tools, and are ignored, as are the keys of a newer semmap's manifest.
    """

    model_config = ConfigDict(extra="ignore", frozen=True)

    scenario: str | None = Field(None, description="the simulated world's name, copied into the build summary")
    topics: Annotated[dict[str, str | None], BeforeValidator(lambda v: v or {})] = Field(
        default_factory=dict, description="kind (scan, labels, odometry...) → topic, for one the config leaves unset")
    label_classes: str | None = Field(None, description="the class list naming the label images' values")


def load_build_config(path: str | Path | None, overrides: dict[str, Any] | None = None) -> tuple[BuildConfig, Path]:
    """The build config from a YAML file (or defaults); returns it and the folder relative paths start from."""
    data: dict[str, Any] = {}
    file_seg: dict[str, Any] = {}
    base = Path.cwd()
    source = "config"
    if path is not None:
        loaded = load_yaml(path)
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: expected a mapping at the top level")
        data = loaded or {}
        file_seg = data.get("segmentation") or {} if isinstance(data.get("segmentation"), dict) else {}
        base = Path(path).resolve().parent
        source = str(path)
    if overrides:
        from ..config import merge_overrides

        data = merge_overrides(data, overrides)
    cfg = load_model(BuildConfig, data, source)
    # the segmentation's files named in the config file are relative to it, as the calibration is
    # (paths given as overrides, e.g. on the command line, stay relative to the working directory)
    seg = cfg.segmentation
    over = (overrides or {}).get("segmentation") or {}
    fixed = {k: base / Path(getattr(seg, k)).expanduser() for k in ("model", "folder", "cache_dir", "classes_file")
             if k in type(seg).model_fields and k in file_seg and k not in over and getattr(seg, k) is not None
             and not Path(getattr(seg, k)).expanduser().is_absolute()}
    if fixed:
        cfg = cfg.model_copy(update={"segmentation": seg.model_copy(update=fixed)})
    return cfg, base


def resolve_topics(cfg: BuildConfig, types: dict[str, str], bag: Path, manifest: dict[str, Any],
                   consumes: str) -> Topics:
    """Resolve topic names from the config, the tour manifest, then the bag's message types
    (:func:`~semmap.io.topics.pick_topics`, as ``segment`` and ``calibrate check`` pick them)."""
    return pick_topics(types, cfg.topics, bag, consumes, manifest)


def _check_camera_info(src: OpenBag, topic: str, calib: Calibration, calib_path: Path) -> None:
    """Warn when the bag's CameraInfo disagrees with the calibration file (a calibration of another camera)."""
    bag = src.path
    try:
        info = camera_info_from_msg(src.first(topic))
    except (BagError, ValueError):
        return
    mine = calib.intrinsics
    if (info.width, info.height) != (mine.width, mine.height):
        log.warning("%s: %s says %dx%d images, calibration %s says %dx%d", bag, topic, info.width, info.height,
                    calib_path, mine.width, mine.height)
    elif np.any(info.K) and not np.allclose(info.K, mine.K, rtol=0.01, atol=1.0):
        log.warning("%s: the intrinsics on %s differ from calibration %s (fx %.1f vs %.1f); using the file",
                    bag, topic, calib_path, info.fx, mine.fx)


def read_tour_manifest(tour: str | Path) -> tuple[Path, Path | None, dict[str, Any]]:
    """The bag of a tour (a bag, or a folder holding one), the semmap tour folder it sits in (None if
    none) and that folder's ``tour.yaml`` (empty if none)."""
    bag = resolve_bag_path(tour)
    p = Path(tour)
    folder = p if p.is_dir() and (p / "tour.yaml").is_file() else (
        bag.parent if (bag.parent / "tour.yaml").is_file() else None)
    manifest: dict[str, Any] = {}
    if folder is not None:
        path = folder / "tour.yaml"
        manifest = load_yaml(path) or {}
        load_model(TourManifest, manifest, str(path))  # the keys semmap reads, checked; the dict is returned whole
    return bag, folder, manifest


def open_tour(tour: str | Path, config: BuildConfig, config_dir: Path, calibration: str | Path | None = None,
              consumes: str = "labels", source: OpenBag | None = None) -> Tour:
    """Inspect a tour: topics, frames, ``T_base_lidar`` and the calibration.

    ``source``: the tour's bag already opened with :func:`~semmap.io.bag.read_bag` (a build opens it
    once, and streams it from the same reader); else it is opened (once) and closed here.
    """
    bag, folder, manifest = read_tour_manifest(tour)
    if source is None:
        with read_bag(bag) as opened:
            return _open_tour(opened, folder, manifest, config, config_dir, calibration, consumes)
    return _open_tour(source, folder, manifest, config, config_dir, calibration, consumes)


def _open_tour(src: OpenBag, folder: Path | None, manifest: dict[str, Any], config: BuildConfig, config_dir: Path,
               calibration: str | Path | None, consumes: str) -> Tour:
    bag = src.path
    types = dict(src.types)
    topics = resolve_topics(config, types, bag, manifest, consumes)

    scan0 = scan_from_msg(src.first(topics.scan), topics.scan)
    lidar_frame = config.frames.lidar or scan0.frame_id
    if not lidar_frame:
        raise BagError(f"{bag}: scans on {topics.scan} have an empty frame_id; set frames.lidar")

    tree: TfTree | None = None
    moving: dict[str, str] = {}  # the transforms seen on /tf: child -> parent

    def tf_tree(keep_reading: Callable[[TfTree, int], bool] | None = None) -> TfTree:
        """/tf_static, and the first messages of /tf, read once when a transform is needed.
        ``keep_reading(tree, bag time)``: whether to read /tf on past its first messages."""
        nonlocal tree
        if tree is None:
            tree = TfTree()
            for tf_topic in [x for x in (topics.tf_static, config.topics.tf) if x and x in types]:
                for n, (_, t_bag, msg) in enumerate(src.messages([tf_topic]), start=1):
                    for _, parent, child, mat in transforms_from_msg(msg, tf_topic):
                        if tf_topic == topics.tf_static or tree.parent(child) is None:
                            tree.add(parent, child, mat)
                        if tf_topic != topics.tf_static:
                            moving.setdefault(child, parent)
                    if (tf_topic != topics.tf_static and n > 200  # /tf: a first look is enough
                            and (keep_reading is None or not keep_reading(tree, t_bag))):
                        break
        return tree

    topics = _odometry_from_tf(src, config, topics, types, lidar_frame, tf_tree, moving)
    base_frame = config.frames.base
    if topics.odometry_tf is not None:
        base_frame = topics.odometry_tf.base_frame
    elif base_frame is None and topics.odometry:
        base_frame = odometry_from_msg(src.first(topics.odometry), topics.odometry)[2]
    base_frame = base_frame or "base_link"

    # T_base_lidar: the config, else /tf_static (any chain of frames)
    if config.frames.base_T_lidar is not None:
        t_base_lidar = se3_from_xyz_rpy(config.frames.base_T_lidar.xyz, config.frames.base_T_lidar.rpy)
        t_source = "frames.base_T_lidar in the config"
    elif base_frame == lidar_frame:
        t_base_lidar, t_source = np.eye(4), "identity (the scans are in the base frame)"
    else:
        tf = tf_tree()
        if base_frame in tf and lidar_frame in tf:
            t_base_lidar = tf.lookup(base_frame, lidar_frame)
            t_source = "the transform chain " + " -> ".join(tf.chain(lidar_frame, base_frame))
        elif topics.odometry is None:
            log.warning("no transform %s -> %s; mapping in the LiDAR frame", base_frame, lidar_frame)
            base_frame, t_base_lidar = lidar_frame, np.eye(4)
            t_source = "identity (no transform found and no odometry: mapping in the LiDAR frame)"
        else:
            raise BagError(f"{bag}: no transform from {base_frame} to {lidar_frame} in /tf_static or /tf; "
                           f"set frames.base_T_lidar in the config")

    calib = None
    calib_path: Path | None = None
    calib_source = ""
    if topics.image is not None:
        if calibration is not None:
            calib_path = Path(calibration)
        elif config.calibration is not None:
            c = Path(config.calibration)
            calib_path = c if c.is_absolute() else config_dir / c
        elif folder is not None and (folder / "calibration.yaml").is_file():
            calib_path = folder / "calibration.yaml"
        elif (bag.parent / "calibration.yaml").is_file():
            calib_path = bag.parent / "calibration.yaml"
        if calib_path is not None:
            calib = read_calibration(calib_path)
            calib_source = str(calib_path)
            if topics.camera_info is not None:
                _check_camera_info(src, topics.camera_info, calib, calib_path)
            if calib.lidar_frame and calib.lidar_frame != lidar_frame:
                log.warning("%s: calibration is for LiDAR frame %r, scans are in %r", calib_path,
                            calib.lidar_frame, lidar_frame)
        else:
            calib, calib_source = _calibration_from_bag(src, topics, lidar_frame, tf_tree)
    return Tour(bag, folder, manifest, config, topics, types, lidar_frame, base_frame, t_base_lidar, calib, calib_path,
                t_source, calib_source)


#: odometry from /tf is looked for up to this long (bag time) after the first scan, s
_TF_ODOMETRY_SEARCH_S = 10.0


def _odometry_from_tf(src: OpenBag, config: BuildConfig, topics: Topics, types: dict[str, str], lidar_frame: str,
                      tf_tree: Callable[[Callable[[TfTree, int], bool] | None], TfTree],
                      moving: dict[str, str]) -> Topics:
    """The topics with the odometry taken from /tf where the config asks for it (``topics.odometry: tf``),
    or leaves it open (null) and the bag has no Odometry topic but /tf carries one
    (:func:`~semmap.io.tf.find_tf_odometry`)."""
    tf_topic = config.topics.tf
    asked = topics.odometry is not None and topics.odometry == tf_topic  # pick_topics: topics.odometry: tf
    if not asked and not (topics.odometry is None and config.topics.odometry is None
                          and types.get(tf_topic) in TF_TYPES):
        return topics

    def find(tree: TfTree) -> TfOdometry | None:
        return find_tf_odometry(tree, moving, config.frames.base or lidar_frame, tf_topic,
                                base=config.frames.base, odom=config.frames.odom)

    # odometry often starts after the recording (map -> odom alone at first): read /tf on until it is
    # found, or until _TF_ODOMETRY_SEARCH_S after the first scan
    until = next((t for _, t, _ in src.messages([topics.scan])), 0) + int(_TF_ODOMETRY_SEARCH_S * 1e9)
    found = find(tf_tree(lambda tree, t_bag: t_bag <= until and find(tree) is None))
    if found is None:
        if asked:
            seen = ", ".join(f"{p} -> {c}" for c, p in sorted(moving.items(), key=lambda x: (x[1], x[0])))
            want = f"frame {config.frames.odom!r}" if config.frames.odom else "a frame named like 'odom'"
            of = (f"the base frame {config.frames.base!r}" if config.frames.base
                  else f"the LiDAR frame {lidar_frame!r}")
            raise BagError(f"{src.path}: topics.odometry is 'tf' but {tf_topic} has no transform from {want} "
                           f"to {of} or a parent of it up to {_TF_ODOMETRY_SEARCH_S:g} s after the first scan "
                           f"(transforms on {tf_topic}: {seen or 'none'}); set frames.odom and frames.base")
        return replace(topics, odometry=None)
    if not asked:
        log.info("odometry: %s %s -> %s (no nav_msgs/Odometry topic)", tf_topic, found.odom_frame, found.child_frame)
    return replace(topics, odometry=tf_topic, odometry_tf=found)


def _calibration_from_bag(src: OpenBag, topics: Topics, lidar_frame: str,
                          tf_tree: Any) -> tuple[Calibration, str]:
    """The calibration a bag carries: intrinsics from ``camera_info``, ``T_cam_lidar`` from the
    transform chain between the LiDAR frame and the camera_info's frame."""
    bag = src.path
    hint = "pass --calibration FILE or set 'calibration:' in the config"
    if topics.camera_info is None:
        raise ConfigError(f"{bag}: the tour has camera topic {topics.image} but no calibration file and no "
                          f"sensor_msgs/CameraInfo topic; {hint}")
    msg = src.first(topics.camera_info)
    try:
        intr = camera_info_from_msg(msg)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{bag}: {topics.camera_info}: unusable camera info ({exc}); {hint}") from None
    if not np.any(intr.K):
        raise ConfigError(f"{bag}: {topics.camera_info}: the camera info has no intrinsics (K is zero); {hint}")
    cam_frame = str(msg.header.frame_id).lstrip("/")
    tf = tf_tree()
    if not cam_frame or cam_frame not in tf or lidar_frame not in tf:
        raise ConfigError(f"{bag}: no calibration file, and no transform from the LiDAR frame {lidar_frame!r} to "
                          f"the camera frame {cam_frame!r} of {topics.camera_info} in /tf_static or /tf; {hint}")
    T_cam_lidar = tf.lookup(cam_frame, lidar_frame)
    chain = " -> ".join(tf.chain(cam_frame, lidar_frame))
    log.info("no calibration file: intrinsics from %s, T_cam_lidar from the transform chain %s",
             topics.camera_info, chain)
    return (Calibration(intrinsics=intr, T_cam_lidar=T_cam_lidar, camera_frame=cam_frame, lidar_frame=lidar_frame),
            f"{topics.camera_info} and the transform chain {chain}")


