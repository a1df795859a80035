"""The configuration tree: one pydantic model per stage, defaults in code, YAML for overrides.

Every model forbids unknown keys, so a typo in a YAML file is an error that names
the key, not a silently ignored setting. The effective configuration is written
beside every output.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union

from pydantic import (
    AliasChoices,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    TypeAdapter,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from .errors import ConfigError

__all__ = [
    "PLUGIN_SEGMENTATION",
    "SEGMENTATION_BACKENDS",
    "AnySegmentation",
    "BuildConfig",
    "CleaningConfig",
    "EkfConfig",
    "FolderSegmentation",
    "FramesConfig",
    "GridConfig",
    "ModelSegmentationConfig",
    "Mount",
    "OcclusionConfig",
    "OnnxSegmentation",
    "PaintConfig",
    "PluginSegmentation",
    "RefineConfig",
    "RegistrationConfig",
    "Sam3Segmentation",
    "SegmentationConfig",
    "SelfieSegmentation",
    "SimCameraConfig",
    "SimConfig",
    "SimGroundTruthConfig",
    "SimLidarConfig",
    "SimOdometryConfig",
    "SimRobotConfig",
    "SyncConfig",
    "TopicSegmentation",
    "TopicsConfig",
    "UltralyticsSegmentation",
    "config_error",
    "load_model",
    "load_yaml",
    "merge_overrides",
    "register_segmentation_options",
    "segmentation_config",
]

log = logging.getLogger(__name__)


class _Model(BaseModel):
    # NaN and inf pass every bound they are compared with (inf > 0), so no setting takes them
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Mount(_Model):
    """A sensor's pose on the robot: ``T_base_sensor`` as translation (m) and roll-pitch-yaw (rad)."""

    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


# Camera optical frame (z forward, x right, y down) looking along base_link +x.
OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)


class SimRobotConfig(_Model):
    """The simulated base: footprint, frames and motion limits."""

    base_frame: str = "base_link"
    length: float = Field(0.9, gt=0, description="footprint length along x, m (MiR100: 0.89)")
    width: float = Field(0.6, gt=0, description="footprint width along y, m (MiR100: 0.58)")
    body_height: float = Field(0.6, gt=0, description="obstacles below this height block the robot, m")
    max_speed: float = Field(0.7, gt=0, description="m/s")
    max_accel: float = Field(0.5, gt=0, description="m/s²")
    max_lateral_accel: float = Field(0.4, gt=0, description="m/s²")
    max_yaw_rate: float = Field(math.radians(50), gt=0, description="rad/s")
    max_yaw_accel: float = Field(math.radians(90), gt=0, description="rad/s²")
    corner_radius: float = Field(0.8, gt=0, description="largest fillet radius at route corners, m")
    clearance: float = Field(0.04, ge=0, description="minimum distance to obstacles, m")
    settle_s: float = Field(1.0, ge=0, description="standing time before and after the tour, s")


class SimLidarConfig(_Model):
    """A 2D LiDAR publishing ``sensor_msgs/LaserScan``. Default: MiR-style front-left corner mount."""

    topic: str = "/scan"
    frame_id: str = "laser"
    mount: Mount = Mount(xyz=(0.38, 0.23, 0.2), rpy=(0.0, 0.0, math.pi / 4))
    fov_deg: float = Field(270.0, gt=0, le=360)
    resolution_deg: float = Field(0.5, gt=0)
    rate_hz: float = Field(15.0, gt=0)
    range_min: float = Field(0.05, ge=0)
    range_max: float = Field(20.0, gt=0)
    noise_std: float = Field(0.01, ge=0, description="Gaussian range noise, m")
    dropout_prob: float = Field(0.005, ge=0, le=1, description="chance a beam returns nothing (+inf)")
    sweep: bool = Field(True, description="fire beams over the scan period while the robot moves")
    latency_s: float = Field(0.005, ge=0, description="bag time minus header stamp")

    @property
    def n_beams(self) -> int:
        return int(round(self.fov_deg / self.resolution_deg)) + 1


class SimCameraConfig(_Model):
    """An RGB camera plus a ground-truth label image topic and ``CameraInfo``."""

    image_topic: str = "/camera/image_raw"
    info_topic: str = "/camera/camera_info"
    label_topic: str = "/camera/labels"
    frame_id: str = "camera_optical_frame"
    mount: Mount = Mount(xyz=(0.42, 0.0, 0.5), rpy=OPTICAL_RPY)
    width: int = Field(640, gt=0)
    height: int = Field(480, gt=0)
    # The research's intrinsics.
    K: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]] = (
        (601.80, 0.0, 328.17),
        (0.0, 600.12, 240.45),
        (0.0, 0.0, 1.0),
    )
    rate_hz: float = Field(5.0, gt=0)
    image_format: Literal["raw", "jpeg"] = "raw"
    jpeg_quality: int = Field(90, ge=10, le=100)
    label_encoding: Literal["mono16", "mono8"] = "mono16"
    label_classes: str = Field("coco", description="class list in config/classes.yaml naming label values")
    noise_std: float = Field(2.0, ge=0, description="pixel noise, 8-bit levels")
    latency_s: float = Field(0.03, ge=0)

    @field_validator("mount")
    @classmethod
    def _level(cls, v: Mount) -> Mount:
        # The renderer casts one ray per column, exact only for a level, unrolled camera:
        # optical z horizontal and optical y pointing straight down.
        from scipy.spatial.transform import Rotation

        r = Rotation.from_euler("xyz", v.rpy).as_matrix()
        if abs(r[2, 2]) > 1e-6 or r[2, 1] > -1 + 1e-6:
            raise ValueError("the simulated camera must be level (optical z horizontal, y down), "
                             "e.g. rpy = [-1.5708, 0, -1.5708] looking along base_link +x")
        return v


class SimOdometryConfig(_Model):
    """Wheel odometry with realistic error: scale error, yaw drift and noise."""

    topic: str = "/odom"
    frame_id: str = "odom"
    rate_hz: float = Field(50.0, gt=0)
    publish_tf: bool = Field(True, description="also publish odom→base_link on /tf")
    scale_error: tuple[float, float] = Field((0.01, 0.02), description="|distance scale error| range")
    yaw_scale_error: tuple[float, float] = Field((0.01, 0.02), description="|yaw scale error| range")
    yaw_drift_deg_per_m: float = Field(0.15, ge=0, description="heading bias per metre travelled")
    noise_dist: float = Field(0.003, ge=0, description="distance noise, m per sqrt(m)")
    noise_yaw_deg: float = Field(0.25, ge=0, description="heading noise, deg per sqrt(m + rad)")
    latency_s: float = Field(0.002, ge=0)


class SimGroundTruthConfig(_Model):
    """Ground truth: pose topic and the maps written beside the bag."""

    pose_topic: str = "/ground_truth/odom"
    rate_hz: float = Field(50.0, gt=0)
    map_resolution: float = Field(0.05, gt=0, description="m per cell of the ground-truth maps")
    map_margin: float = Field(1.0, ge=0, description="m of free border around the world")
    people_radius: float = Field(0.25, gt=0, description="body disc people sweep, m")


class SimConfig(_Model):
    """Everything ``semmap simulate`` needs besides the world itself."""

    robot: SimRobotConfig = SimRobotConfig()
    lidar: SimLidarConfig = SimLidarConfig()
    camera: SimCameraConfig = SimCameraConfig()
    odometry: SimOdometryConfig = SimOdometryConfig()
    ground_truth: SimGroundTruthConfig = SimGroundTruthConfig()
    tf_topic: str = "/tf"
    tf_static_topic: str = "/tf_static"
    start_time_ns: int = Field(1_767_225_600_000_000_000, description="2026-01-01T00:00:00Z")


# ---------------------------------------------------------------------------------------
# Mapping stages (semmap build)


class TopicsConfig(_Model):
    """Topic names. ``null`` means: detect it from the bag when the choice is unambiguous."""

    scan: str | None = None
    image: str | None = Field(None, description="RGB camera: sensor_msgs/Image or CompressedImage")
    labels: str | None = Field(None, description="label images (mono8/mono16) for the 'topic' backend")
    camera_info: str | None = None
    odometry: str | None = Field(None, description="nav_msgs/Odometry topic; 'tf' (or the tf topic's name) to take "
                                 "odometry from the odom -> base transform on topics.tf; 'none' to build without "
                                 "odometry; null: the only Odometry topic, else /tf when it carries one")
    tf: str = "/tf"
    tf_static: str = "/tf_static"


class FramesConfig(_Model):
    """Frame names; ``null`` means: take them from the data."""

    base: str | None = Field(None, description="robot base frame (default: the odometry's child frame, or the child "
                                               "of the odometry transform on /tf)")
    odom: str | None = Field(None, description="odometry frame of odometry taken from /tf (default: the nearest "
                                               "parent of the base frame on /tf named like 'odom', else one not "
                                               "named like 'map' or 'world')")
    lidar: str | None = Field(None, description="LiDAR frame (default: the scans' frame_id)")
    base_T_lidar: Mount | None = Field(None, description="T_base_lidar when the bag has no /tf_static for it")


class SyncConfig(_Model):
    """Pairing scans with images and odometry."""

    max_image_offset: float = Field(0.1, ge=0, le=3600, description="pair a scan with the nearest image within "
                                                                     "this, s")
    motion_compensation: bool = Field(True, description="move the scan to the image time through odometry")
    deskew: bool = Field(True, description="undo the robot's motion during a scan sweep through odometry")
    odometry_offset: float | Literal["auto"] = Field(
        "auto", description="seconds added to the odometry's stamps to put them on the scans' clock (a driver "
                            "that stamps late or early); 'auto': estimated from the tour's first turns "
                            "(ICP's turn rate against the odometry's), 0 when they do not show it clearly")

    @field_validator("odometry_offset")
    @classmethod
    def _offset_range(cls, v: float | str) -> float | str:
        if isinstance(v, float) and not -10.0 <= v <= 10.0:
            raise ValueError("must be 'auto' or seconds within ±10")
        return v

    max_odom_gap: float = Field(0.5, gt=0, le=3600, description="odometry gaps longer than this are not "
                                                                 "interpolated, s")
    # buffering of the scan stream (semmap.paint.stream): memory stays bounded however long the tour
    max_wait_s: float = Field(2.0, gt=0, le=3600, description="a scan waits for odometry covering its sweep at "
                                                              "most this long in bag time, then is painted "
                                                              "with what there is, s")
    max_wait_scans: int = Field(64, gt=0, description="... or until this many scans wait")
    keep_images_s: float = Field(0.5, ge=0, le=3600, description="segmentations are kept this long after the "
                                                                 "pairing window has passed them, s")
    keep_odometry_s: float = Field(1.0, ge=0, le=3600, description="odometry is kept this long before the "
                                                                   "latest scan (motion compensation and "
                                                                   "deskewing look back), s")


class SegmentationConfig(_Model):
    """What every backend's options share. Each built-in backend has its own model below, holding
    only the options it uses; ``segmentation:`` in a config file is one of them, picked by ``backend``
    (default ``topic``). See docs/segmentation.md.

    A backend added with :func:`semmap.segment.base.register` subclasses this (or
    :class:`ModelSegmentationConfig`) with ``backend: Literal["its-name"]``; it is passed to
    :func:`~semmap.segment.base.create_segmenter` from Python (config files name built-in backends).
    """

    backend: str = Field("topic", description="'topic': label images recorded in the bag; 'folder': label PNGs; "
                                              "'onnx', 'ultralytics', 'sam3', 'mediapipe-selfie': models")
    classes_file: Path | None = Field(None, description="a class table replacing config/classes.yaml")
    # which camera frames the model runs on (semmap.segment.select); the others cost no model time
    select: Literal["all", "motion", "need"] = Field(
        "all", description="'all': every frame; 'motion': a frame once the robot has moved select_distance or "
                           "turned select_angle since the last segmented one, or select_interval has passed; "
                           "'need': a frame when what it looks at lacks camera evidence (need_*)")
    select_distance: float = Field(0.3, gt=0, le=1000, description="select: motion: metres moved, m")
    select_angle: float = Field(10.0, gt=0, le=360, description="select: motion: degrees turned, deg")
    select_interval: float | None = Field(None, ge=0, le=3600,
                                          description="a frame at least this often, s (people move while the robot "
                                                      "stands); 0: never for time alone; null: 1 s with 'motion', "
                                                      "0 with 'need'")
    transfer_window: float = Field(3.0, ge=0, le=3600,
                                   description="a scan paired with a frame not segmented takes, per map cell, the "
                                               "label the segmented frames voted for; a person's label only this "
                                               "long after the frame that gave it, s")
    need_frames: int = Field(2, ge=1, le=100, description="select: need: a cell has the camera evidence it needs "
                                                          "once this many segmented frames in a row gave it one "
                                                          "label (furniture: once one frame did)")
    need_cells: float = Field(2.0, gt=0, le=10000,
                              description="select: need: segment a frame when the cells in its view lack this many "
                                          "cells' worth of evidence (a cell on a small thing counts 1, one on a wall "
                                          "0.1)")
    need_cell: float = Field(0.25, gt=0, le=10, description="select: need: the cells evidence is counted in, m")
    max_rate: float | None = Field(None, gt=0, description="a budget: at most this many frames segmented per "
                                                           "second of tour, on average (null: no limit)")
    max_frames: int | None = Field(None, gt=0, description="a budget: at most this many frames segmented in all, "
                                                           "spread over the tour as max_rate would (null: no "
                                                           "limit)")
    max_seconds: float | None = Field(None, gt=0, description="a budget: at most this many seconds of model time in "
                                                               "all, spread over the tour as max_frames would (a "
                                                               "frame from the mask cache counts the time it took "
                                                               "when it was segmented; null: no limit)")

    @model_validator(mode="after")
    def _backend_is_always_set(self) -> SegmentationConfig:
        # backend picks the model: a dump of the set fields only (model_dump(exclude_unset=True))
        # must name it, or it would load back as the default backend
        self.__pydantic_fields_set__.add("backend")
        return self

    @property
    def weights(self) -> Path | None:
        """The weights file or folder the backend loads (None: none, or the backend's default)."""
        return None


class _ClassList(SegmentationConfig):
    class_list: str = Field("coco", description="class list (config/classes.yaml) naming label values")


class ModelSegmentationConfig(SegmentationConfig):
    """The options of a backend that runs a model on the camera images."""

    model: Path | None = Field(None, description="the weights")
    device: str = Field("cpu", description="'cpu', or 'cuda' / 'cuda:0' where the backend's runtime has it")
    cache_dir: Path | None = Field(None, description="on-disk mask cache: label images keyed by model and "
                                                     "image stamp, so rebuilding does not segment again "
                                                     "(null: no cache)")

    @property
    def weights(self) -> Path | None:
        return self.model


class _Threads(ModelSegmentationConfig):
    threads: int = Field(0, ge=0, description="CPU threads the model may use (0: the runtime's default)")


class _Detection(ModelSegmentationConfig):
    conf: float = Field(0.25, ge=0, le=1, description="keep instances scoring at least this")
    max_det: int = Field(300, gt=0, description="instances kept per image, best first")
    imgsz: int | None = Field(None, gt=0, description="model input size (long side), px: default the model's "
                                                      "(from its metadata)")


class _Nms(_Detection):
    iou: float = Field(0.7, ge=0, le=1, description="NMS: drop boxes overlapping a better one by more than this")


class _MaskThreshold(ModelSegmentationConfig):
    mask_threshold: float = Field(0.5, ge=0, le=1, description="a pixel is on a mask above this probability")


class TopicSegmentation(_ClassList):
    """``topic``: label images recorded in the bag (``topics.labels``), named by ``class_list``."""

    backend: Literal["topic"] = "topic"


class FolderSegmentation(_ClassList):
    """``folder``: label PNGs named ``<stamp_ns>.png`` (``semmap segment`` writes them), named by the
    folder's ``classes.json`` or else by ``class_list``."""

    backend: Literal["folder"] = "folder"
    folder: Path | None = Field(None, description="the folder of label PNGs (<stamp_ns>.png)")


class OnnxSegmentation(_Nms, _MaskThreshold, _Threads, _ClassList):
    """``onnx``: a YOLO-seg or semantic model exported to ONNX, run by onnxruntime. ``class_list``
    names the classes of a model whose metadata only numbers them."""

    backend: Literal["onnx"] = "onnx"
    model: Path | None = Field(None, description="the .onnx file")


class UltralyticsSegmentation(_Nms):
    """``ultralytics``: a ``.pt`` segmentation model run by Ultralytics."""

    backend: Literal["ultralytics"] = "ultralytics"
    model: Path | None = Field(None, description="the .pt file")


class Sam3Segmentation(_Detection, _MaskThreshold, _Threads, _ClassList):
    """``sam3``: SAM 3 with one text prompt per class, from a local model folder."""

    backend: Literal["sam3"] = "sam3"
    model: Path | None = Field(None, description="the model folder (Sam3Model.save_pretrained)")
    imgsz: int | None = Field(None, gt=0, description="upper bound of the adaptive input resolution, px "
                                                      "(default: the model's own)")
    prompts: tuple[str, ...] | None = Field(None, description="one text prompt per class (default: the names of "
                                                               "class_list); each must be a class name of "
                                                               "config/classes.yaml")
    memory_budget_mb: float = Field(4096.0, gt=0, description="peak activation memory the input resolution is "
                                                               "scaled to fit, MB")


class SelfieSegmentation(_MaskThreshold, _Threads):
    """``mediapipe-selfie``: MediaPipe's selfie model (people only), run by LiteRT on the CPU."""

    backend: Literal["mediapipe-selfie"] = "mediapipe-selfie"
    model: Path | None = Field(None, description="the .tflite file (default: "
                                                 "$SEMMAP_DATA/models/selfie_segmentation.tflite)")


#: backend name → its options; what ``segmentation:`` in a config file may be
SEGMENTATION_BACKENDS: dict[str, type[SegmentationConfig]] = {
    m.model_fields["backend"].default: m
    for m in (TopicSegmentation, FolderSegmentation, OnnxSegmentation, UltralyticsSegmentation, Sam3Segmentation,
              SelfieSegmentation)
}


class PluginSegmentation(ModelSegmentationConfig):
    """The options of a backend registered by a plugin without a model of its own: any keys, kept as
    given (``cfg.<key>``), for the plugin to check."""

    model_config = ConfigDict(extra="allow", frozen=True, allow_inf_nan=False)

    backend: str


#: backends registered at run time (:func:`semmap.segment.base.register`) → their options model
PLUGIN_SEGMENTATION: dict[str, type[SegmentationConfig]] = {}


def register_segmentation_options(name: str, model: type[SegmentationConfig] | None = None) -> None:
    """Let ``segmentation: {backend: name, ...}`` in a config file name a plugin's backend, its options
    validated by ``model`` (default :class:`PluginSegmentation`: any keys)."""
    if name in SEGMENTATION_BACKENDS:
        raise ValueError(f"{name!r} is a built-in segmentation backend")
    PLUGIN_SEGMENTATION[name] = model or PluginSegmentation


def _is_default(key: str, value: Any) -> bool:
    """Whether ``value`` is what every backend having option ``key`` takes by default."""
    owners = [m.model_fields[key] for m in SEGMENTATION_BACKENDS.values() if key in m.model_fields]
    return value is None or all(f.default == value for f in owners)


def _one_backends_keys(data: Any) -> Any:
    """Keep only the chosen backend's keys of a ``segmentation:`` mapping.

    Before one model per backend, ``segmentation:`` held every backend's options (and map folders'
    config.yaml dumps them all), so another backend's key is ignored, not an error. It is ignored
    silently when it holds its default (as those dumps do), with a warning naming it otherwise: it
    was set to do something, and does nothing here. A key no backend has stays an error.
    """
    if isinstance(data, SegmentationConfig):
        return data
    if not isinstance(data, dict):
        raise PydanticCustomError("dict_type", "expected a mapping: backend and its options")
    backend = data.get("backend", "topic")
    if isinstance(backend, str) and backend in PLUGIN_SEGMENTATION and backend not in SEGMENTATION_BACKENDS:
        return PLUGIN_SEGMENTATION[backend].model_validate(data)  # a plugin's model, validated as it says
    model = SEGMENTATION_BACKENDS.get(backend) if isinstance(backend, str) else None
    if model is None:
        known = ", ".join(sorted([*SEGMENTATION_BACKENDS, *PLUGIN_SEGMENTATION]))
        raise PydanticCustomError("unknown_backend", "unknown backend {backend} (available: {known})",
                                  {"backend": repr(backend), "known": known})
    other = {k for m in SEGMENTATION_BACKENDS.values() for k in m.model_fields} - set(model.model_fields)
    ignored = [k for k in data if k in other]
    if not ignored:
        return data
    loud = [k for k in ignored if not _is_default(k, data[k])]
    if loud:
        log.warning("segmentation: %s ignored: not %s of the %r backend", ", ".join(loud),
                    "an option" if len(loud) == 1 else "options", backend)
    return {k: v for k, v in data.items() if k not in ignored}


def _backend_tag(v: Any) -> str | None:
    if isinstance(v, dict):
        return str(v.get("backend", "topic"))
    if isinstance(v, SegmentationConfig):  # a model given from Python: a plugin's own, or a built-in one
        return v.backend if v.backend in SEGMENTATION_BACKENDS else "plugin"
    return None


#: ``segmentation:`` of a config file: one of the built-in backends' models, picked by ``backend``, or
#: the options model of a backend a plugin registered (:func:`register_segmentation_options`)
if TYPE_CHECKING:  # to a type checker, any backend's model
    AnySegmentation = SegmentationConfig
else:
    AnySegmentation = Annotated[
        Union[(*(Annotated[m, Tag(name)] for name, m in SEGMENTATION_BACKENDS.items()),
               Annotated[SegmentationConfig, Tag("plugin")])],
        Discriminator(_backend_tag),
        BeforeValidator(_one_backends_keys),
    ]


class OcclusionConfig(_Model):
    """The occlusion filter (docs/occlusion.md): points on a mask that nearer points of the same mask hide
    from the camera become unknown instead of taking the mask's label. Passed as is to
    :func:`semmap.paint.occlusion.hidden_points`."""

    filter: bool = Field(True, description="on or off (off: every point on a mask takes the mask's label)")
    depth_margin: float = Field(0.25, ge=0, description="a point is hidden only by points at least this much "
                                                        "nearer the camera, m")
    depth_margin_rel: float = Field(0.03, ge=0, le=1, description="plus this share of the point's distance from "
                                                                  "the camera")
    ray_width_deg: float = Field(0.5, ge=0, description="added to each occluding point's footprint (one beam "
                                                        "spacing), deg")
    max_gap: float = Field(2.2, ge=0, description="nearer points of the same mask up to this far apart hide the "
                                                  "points between them when the mask joins them in the image, m "
                                                  "(0: off)")
    edge_px: float = Field(8.0, ge=0, description="a mask may spill this many pixels past its object's outermost "
                                                  "point; points there behind the object are hidden too, px (0: off)")
    overhang: float = Field(0.3, ge=0, description="an object may reach this far to the side of its outermost "
                                                   "point seen at LiDAR height (a seat over chair legs), m (0: off)")
    line_step: float = Field(0.06, ge=0, description="neighbouring scan points closer than this are one surface; "
                                                     "a surface that runs off the mask is background behind it, m "
                                                     "(0: off)")
    line_depth_margin: float = Field(0.15, ge=0, description="such background is hidden by mask points at least "
                                                             "this much nearer, m")
    object_extent: float = Field(1.5, ge=0, description="an object spans at most this many times its class's "
                                                        "typical size (class table, sizes:); a point of its mask "
                                                        "farther than that from a nearer point of the mask, behind "
                                                        "it, is hidden (0: off)")
    background: bool = Field(True, description="points off every mask (walls, floor: 'static') are hidden too "
                                               "when another such point stands nearer on the same viewing ray: "
                                               "what a corner LiDAR sees past a wall's edge, the camera cannot")

    @property
    def ray_width(self) -> float:
        """``ray_width_deg`` in radians."""
        return math.radians(self.ray_width_deg)


class PaintConfig(_Model):
    """Turning ranges into points and projecting them into the camera."""

    min_depth: float = Field(0.1, gt=0, description="points closer to the camera than this are not painted, m")
    below_range_min: Literal["invalid", "no_return"] = Field(
        "invalid", description="readings below range_min (0 included): 'invalid' clears nothing (REP-117); "
                               "'no_return' clears free space to the range limit, for drivers such as "
                               "Hokuyo URG that report 'nothing seen' as small error codes; beams masked as "
                               "blocked (blocked_share) clear nothing either way")
    nan_readings: Literal["invalid", "no_return"] = Field(
        "invalid", description="NaN readings: 'invalid' clears nothing (REP-117); 'no_return' clears free space "
                               "to the range limit, for drivers that report 'nothing within range' as NaN; beams "
                               "masked as blocked (blocked_share) clear nothing either way")
    blocked_share: float = Field(
        0.01, ge=0, lt=1, description="a beam (an index in the scan) that has given a real return (or +inf) in at "
                                      "most this share of the scans of its beam layout so far is masked as "
                                      "blocked: its readings below range_min and NaN readings clear nothing, "
                                      "whatever below_range_min and nan_readings say (a sector blocked by the "
                                      "robot's body; in the first scans, every beam that has not returned yet)")
    blocked_min_scans: int = Field(
        50, ge=1, description="masked beams are counted and reported as blocked once their beam layout has been "
                              "seen in this many scans (before that, a beam may just not have returned yet)")
    occlusion: OcclusionConfig = OcclusionConfig()

    @model_validator(mode="before")
    @classmethod
    def _flat_occlusion_keys(cls, data: Any) -> Any:
        # Before the nested section the filter's settings were flat keys, paint.occlusion_<name>
        # (map folders' config.yaml dumped them all); they still load. A nested key given too wins:
        # it is the newer spelling, which overrides (e.g. from the command line) use.
        if not isinstance(data, dict):
            return data
        flat = [k for k in data if isinstance(k, str) and k.startswith("occlusion_")
                and k.removeprefix("occlusion_") in OcclusionConfig.model_fields]
        nested = data.get("occlusion")
        if not flat or not (nested is None or isinstance(nested, dict)):
            return data
        out = {k: v for k, v in data.items() if k not in flat}
        out["occlusion"] = {**{k.removeprefix("occlusion_"): data[k] for k in flat}, **(nested or {})}
        return out

    def with_occlusion_filter(self, on: bool) -> PaintConfig:
        """This config with the occlusion filter switched on or off (its other settings kept)."""
        return self.model_copy(update={"occlusion": self.occlusion.model_copy(update={"filter": on})})


class EkfConfig(_Model):
    """SE(2) EKF fusing wheel odometry (prediction) with KISS-ICP poses (measurement)."""

    odom_trans_noise: float = Field(0.02, ge=0, le=10, description="std of translation per metre driven (fraction)")
    odom_rot_noise: float = Field(0.02, ge=0, le=10, description="std of rotation per radian turned (fraction)")
    odom_trans_per_rad: float = Field(0.01, ge=0, le=10, description="std of translation per radian turned, m/rad "
                                                                      "(a turn on the spot shifts the base)")
    odom_rot_per_m: float = Field(0.005, ge=0, le=10, description="std of heading change per metre driven, rad/m")
    # The random-walk terms are deliberately larger than a wheel encoder's white noise: they also
    # stand for odometry bias the filter does not model. Smaller values let the bias leak into the
    # fused pose (and from there into KISS-ICP's local map); see tools/bench_registration.py.
    odom_trans_rw: float = Field(0.01, ge=0, le=10, description="translation random walk, m per sqrt(m driven)")
    odom_rot_rw: float = Field(0.01, ge=0, le=10, description="heading random walk, rad per sqrt(m driven + rad "
                                                               "turned)")
    odom_heading_drift_std: float = Field(0.05, ge=0, le=10, description="prior std of the odometry's systematic "
                                                                          "heading drift, rad per metre driven (the "
                                                                          "filter learns it from ICP; 0: not modelled)")
    odom_turn_scale_std: float = Field(0.05, ge=0, le=10, description="prior std of the odometry's scale error on "
                                                                       "the angle turned (learnt; 0: not modelled)")
    odom_drive_scale_std: float = Field(0.05, ge=0, le=10, description="prior std of the odometry's scale error on "
                                                                        "the distance driven (learnt; 0: not "
                                                                        "modelled)")
    odom_error_drift: float = Field(0.05, ge=0, le=10, description="the systematic errors drift (a random walk) by "
                                                                    "this share of their prior std per sqrt(m "
                                                                    "driven + rad turned)")
    odom_min_noise: float = Field(1e-4, ge=0, le=10, description="floor on per-step noise std (m and rad)")
    learn_after: float = Field(1.0, ge=0, le=1000, description="m driven before the systematic odometry errors "
                                                               "are learnt from ICP (until then they are only "
                                                               "considered): the first local map is a scan or two "
                                                               "and its ICP errors are correlated, which a short "
                                                               "baseline turns into a scale error")
    icp_xy_std: float = Field(0.005, gt=0, le=100, description="ICP position measurement std, m (with "
                                                                "icp_point_std: its floor)")
    icp_yaw_std: float = Field(0.001, gt=0, le=10, description="ICP heading measurement std, rad (with "
                                                                "icp_point_std: its floor)")
    icp_point_std: float = Field(0.0, ge=0, le=10, description="residual std of one matched point, m: ICP's "
                                                                "covariance is this² times the inverse of the "
                                                                "match's point-to-line Hessian; 0: icp_xy_std and "
                                                                "icp_yaw_std, with the direction a degenerate "
                                                                "match (a corridor) cannot see left to odometry")
    degenerate_ratio: float = Field(0.05, ge=0, le=1, description="a match is degenerate (a corridor, one wall) "
                                                                   "when its Hessian's weakest direction of "
                                                                   "translation has less than this share of the "
                                                                   "strongest's information")
    first_view: tuple[float, float] = Field((1.0, 0.25), description="until the robot has driven this far (m), "
                                                                      "KISS-ICP's local map holds the beam pattern "
                                                                      "of one place, which holds a match to where "
                                                                      "the robot stood: a match is degenerate under "
                                                                      "this share instead (a tour that starts in a "
                                                                      "corridor; (0, 0): off)")
    adapt_window: int = Field(15, ge=0, le=10000, description="the odometry noise is scaled up to what its "
                                                              "disagreement with ICP over the last this many "
                                                              "stretches of adapt_baseline shows (their median; "
                                                              "wheels err more than any fixed model allows); 0: "
                                                              "the configured noise as is")
    adapt_baseline: float = Field(0.5, gt=0, le=1000, description="the stretch (m driven + rad turned) over which "
                                                                  "odometry and ICP are compared")
    adapt_max_scale: float = Field(30.0, ge=1, le=1000, description="the most the odometry noise std is scaled "
                                                                     "up by")
    gate_chi2: float = Field(16.27, gt=0, description="reject ICP poses beyond this Mahalanobis² (3 dof, 99.9 %)")
    reset_after: int = Field(5, ge=0, description="after this many ICP results gated out in a row, trust ICP: "
                                                  "the filter restarts from its pose (odometry slipped); 0: never")
    # Off by default: on real wheel odometry (the CARMEN logs, the Hokuyo bags) 0 is far better, but on
    # one held-out simulated world it let ICP lock onto a person standing by the robot (docs/registration.md)
    fit_margin: float = Field(1.0, ge=0, le=1, description="an ICP pose beyond the gate is still taken when the "
                                                          "scan fits the local map better there than at the "
                                                          "prediction by more than this share (mean squared "
                                                          "distance); 1: never (gate on odometry alone); 0 for "
                                                          "real wheel odometry that drifts")

    @field_validator("first_view")
    @classmethod
    def _first_view_range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (0.0 <= v[0] <= 1000.0 and 0.0 <= v[1] <= 1.0):
            raise ValueError("must be [metres driven (0-1000), share of information (0-1)]")
        return v


class LoopClosureConfig(_Model):
    """Loop closure (:mod:`semmap.register.loops`): keyframes, place recognition, ICP-verified loops and a
    robust pose graph; the grid is fused once, at the end, from the corrected poses."""

    enabled: bool = Field(False, description="close loops: on long tours that come back, walls stop doubling")
    keyframe_distance: float = Field(0.5, gt=0, le=100, description="m driven between keyframes (graph nodes)")
    keyframe_angle: float = Field(0.35, gt=0, le=10, description="rad turned between keyframes")
    min_separation: int = Field(30, ge=0, description="keyframes between the two ends of a loop")
    search_radius: float = Field(3.0, ge=0, le=1000, description="m around the drifted estimate where a place "
                                                                 "is looked for, plus drift_per_m per m driven "
                                                                 "since")
    drift_per_m: float = Field(0.05, ge=0, le=10, description="how far the estimate may have drifted, m per m")
    descriptor: bool = Field(True, description="also recognise places by their shape (a scan-context "
                                               "descriptor), wherever the drifted estimate puts them")
    min_inliers: float = Field(0.6, gt=0, le=1, description="share of a keyframe's points that must lie within "
                                                            "inlier_distance of the place matched")
    inlier_distance: float = Field(0.1, gt=0, le=10, description="m")
    rematch: bool = Field(True, description="re-fit each keyframe to the one before it, point to line, and take "
                                            "that as the pose graph's step where the fit is sure (graph "
                                            "mapping's edge; on the Intel log the step error falls from 0.060 "
                                            "to 0.046 m); false: the registration's steps")
    refuse_min_shift: float = Field(0.025, ge=0, le=100, description="no longer used (accepted so that older "
                                                                      "configurations load): with loop closure the "
                                                                      "grid is fused once, at the end, from the "
                                                                      "corrected poses")


class RefineConfig(_Model):
    """Point-to-line refinement of each ICP result against the local map (semmap/register/refine.py)."""

    enabled: bool = Field(False, description="refine KISS-ICP's point-to-point result by matching each point to "
                                             "the line through its map neighbours (off by default: better steps "
                                             "on the real logs, but registration 2-3x slower and icp mode worse "
                                             "on the ward tour; docs/registration.md)")
    kernel: float = Field(0.05, gt=0, le=10, description="Geman-McClure scale of the point-to-line residuals, m")
    max_distance: float = Field(0.15, gt=0, le=100, description="a point farther than this from the map is not "
                                                               "matched, m")
    neighbours: int = Field(6, ge=3, le=50, description="map points that define a point's line")
    rebuild_distance: float = Field(0.25, ge=0, le=100, description="the map's search tree is rebuilt after the "
                                                                    "robot moved this far (m driven + rad turned) "
                                                                    "since the last build (0: every scan)")


class RegistrationConfig(_Model):
    """Scan registration: KISS-ICP scan-to-map odometry, optionally fused with wheel odometry."""

    mode: Literal["fused", "icp", "odometry"] = Field(
        "fused", description="fused: EKF of wheel odometry + KISS-ICP; icp: KISS-ICP alone; "
                             "odometry: wheel odometry alone")
    voxel_size: float = Field(0.15, gt=0, description="KISS-ICP voxel size, m (0.1-0.5 indoors)")
    max_range: float = Field(20.0, gt=0, le=1000, description="points beyond this range are not registered, m")
    max_source_points: int = Field(100, ge=0, description="thin the ICP source to about this many points "
                                                         "(0: keep KISS-ICP's down-sampling as is)")
    min_range: float = Field(0.1, ge=0, description="points closer than this are not registered, m")
    max_points_per_voxel: int = Field(5, gt=0, le=1000, description="points kept per map voxel (KISS-ICP: 20 for "
                                                                     "3D; a 2D scan plane needs few, and neighbour "
                                                                     "search costs per point)")
    initial_threshold: float = Field(0.5, gt=0, le=1000, description="KISS-ICP adaptive threshold start, m")
    min_motion: float = Field(0.05, ge=0, description="KISS-ICP adaptive threshold min motion, m")
    max_iterations: int = Field(500, gt=0, description="KISS-ICP iteration limit per scan")
    convergence: float = Field(2e-3, gt=0, description="KISS-ICP stops when an update is below this (m and rad; "
                                                        "KISS-ICP's 3D default is 1e-4; 2 mm is a 25th of a 5 cm "
                                                        "cell)")
    max_threads: int = Field(1, ge=0, le=256, description="KISS-ICP threads (0: all cores; 2D scans are fastest on "
                                                           "one)")
    min_points: int = Field(20, ge=3, description="fewer down-sampled points than this: ICP is not run "
                                                  "and the step counts as failed")
    exclude_dynamic: bool = Field(True, description="points painted dynamic are not matched or mapped")
    refine: RefineConfig = RefineConfig()
    ekf: EkfConfig = EkfConfig()
    loop_closure: LoopClosureConfig = LoopClosureConfig()


class GridConfig(_Model):
    """The fused grid: log-odds occupancy plus class evidence per cell."""

    resolution: float = Field(0.05, gt=0, description="m per cell")
    l_occ: float = Field(0.85, gt=0, description="log-odds added at a hit")
    l_free: float = Field(0.4, gt=0, description="log-odds removed along a ray")
    l_min: float = Field(-2.0, lt=0, description="log-odds clamp, low")
    l_max: float = Field(3.5, gt=0, description="log-odds clamp, high")
    max_range: float = Field(20.0, gt=0, le=1000,
                             validation_alias=AliasChoices("max_range", "max_free_range"),
                             description="evidence is taken only this far from the sensor, m: returns farther "
                                         "away count as 'nothing within max_range' (no hit; they clear free "
                                         "space to here), so hits and free space are judged over the same range "
                                         "(far sightings of a person would otherwise add hits that no free ray "
                                         "takes back). Older configs call it max_free_range")
    no_return_range: float = Field(10.0, gt=0, le=1000, description="a beam with no return (REP-117 +inf: nothing "
                                                                   "within the LiDAR's range) clears free space this "
                                                                   "far, m, at most max_range: through a door into "
                                                                   "an unmapped space, or from a beam lost on glass "
                                                                   "or a dark surface, 'nothing seen' is weaker "
                                                                   "evidence than a return")
    tile_margin: float = Field(10.0, gt=0, description="side of the grid's tiles, m: the grid is allocated a tile "
                                                        "at a time as the robot reaches it")
    hit_free_margin: float = Field(0.05, ge=0, description="returns clear free space only to this far short "
                                                            "of their end point, m (keeps grazing rays from "
                                                            "eroding surfaces)")
    free_erode: bool = Field(True, description="erode each scan's free space by one cell, so rays grazing a "
                                               "surface do not clear it")
    free_shadows: bool = Field(True, description="between two neighbouring beams whose ranges differ by more "
                                                 "than two cells, free space reaches only the nearer return when "
                                                 "it is the edge of something wider than a leg (25 cm) and the "
                                                 "two end points are not on one surface seen at a grazing angle: "
                                                 "the wedge beyond it is that object's shadow, not seen free")
    dropout_guard: int = Field(2, ge=0, le=1000, description="a beam without a return whose neighbours within this "
                                                    "many beams on both sides returned is a dropout: it "
                                                    "clears no further than they do (0: off)")

    @model_validator(mode="after")
    def _clamps_fit_the_storage(self) -> GridConfig:
        # the grid keeps log-odds as uint16 steps of 0.001 between the clamps
        if self.l_max - self.l_min > 65.535:
            raise ValueError(f"l_max - l_min is {self.l_max - self.l_min:g}, at most 65.535 "
                             "(log-odds are kept in steps of 0.001 in 16 bits)")
        return self


class CleaningConfig(_Model):
    """Turning the fused grid into the cleaned map."""

    occupied_logodds: float = Field(0.6, ge=-100, le=100, description="cells above this log-odds are occupied")
    free_logodds: float = Field(-0.2, ge=-100, le=100, description="cells below this log-odds are free (one free "
                                                                   "pass: -l_free)")
    hit_ratio: float = Field(0.25, ge=0, le=1, description="also occupied: cells returning at least this share "
                                                           "of the scans that observed them (thin legs; 0: off)")
    min_hits: int = Field(5, ge=1, description="scans that must have returned from a cell for hit_ratio to apply")
    dynamic_fraction: float = Field(0.3, ge=0, le=1, description="drop a cell when this share of its labelled "
                                                                  "hits was dynamic")
    semi_static_fraction: float = Field(0.5, ge=0, le=1, description="flag a cell semi-static when this share "
                                                                       "of its labelled hits was semi-static")
    min_labelled_hits: int = Field(2, ge=1, description="camera-labelled hits a cell needs before its class counts")
    object_link_distance: float = Field(0.45, gt=0, le=10, description="cells of one object are at most this far "
                                                                        "apart, m (a person's legs ~0.2 m, a "
                                                                        "chair's ~0.4 m)")
    wall_min_length: float = Field(0.4, gt=0, le=100, description="straight runs of occupied cells this long are "
                                                                   "walls, judged as a whole segment, m")
    structure_min_size: float = Field(1.0, gt=0, le=1000, description="touching occupied cells longer than this "
                                                                       "are structure: their unlabelled cells stay "
                                                                       "static, m")
    leg_max_size: float = Field(0.0, ge=0, le=10, description="the leg prior: an isolated blob no longer than this "
                                                               "with no camera label is flagged semi-static as a "
                                                               "furniture leg, m (0: off, the default: without "
                                                               "camera evidence far walls' sparse returns look "
                                                               "like legs)")
    person_radius: float = Field(0.35, ge=0, le=5, description="occupied cells this close to a cell labelled dynamic "
                                                               "belong to that person and leave with it (the leg "
                                                               "arcs no camera labelled), unless they are wall or "
                                                               "their own labels say otherwise, m (0: off)")
    face_max_length: float = Field(2.4, ge=0, le=100, description="an unlabelled straight run that meets a cell "
                                                                   "flagged semi-static takes its flag when no longer "
                                                                   "than this (a bed's or couch's side the camera did "
                                                                   "not see), m (0: off)")
    face_size_factor: float = Field(1.5, ge=0, le=100, description="a straight run whose labels say semi-static is "
                                                                    "at most this many times the typical size of "
                                                                    "the largest class labelling it (class table, "
                                                                    "sizes:); a longer one is a wall the labels "
                                                                    "bled onto (0: off)")
    person_leg_width: tuple[float, float] = Field((0.1, 0.25), description="a blob no camera labelled that is this "
                                                                             "wide (min, max) may be a person's leg, m")
    person_leg_spacing: tuple[float, float] = Field((0.12, 0.4), description="two such blobs this far apart (centre "
                                                                               "to centre; min, max) with nothing else "
                                                                               "near are a person's legs and leave, m "
                                                                               "(max 0: off)")
    person_leg_veto_share: float = Field(0.015, ge=0, le=1, description="a blob shaped like a person's legs is "
                                                                         "furniture only when furniture labels are "
                                                                         "at least this share of its returns (or "
                                                                         "structure labels say it is structure: "
                                                                         "on two leg blobs apart, also as this "
                                                                         "share): a few returns painted through a "
                                                                         "chair's mask do not make a person a chair")
    person_leg_seen_share: float = Field(0.1, ge=0, le=1, description="... and never when person labels are at "
                                                                      "least this share of its labelled returns: "
                                                                      "legs seen under a bed's or a table's edge, "
                                                                      "painted through its mask in most frames and "
                                                                      "as a person's in the rest (0: off)")
    person_leg_min_density: float = Field(0.15, ge=0, le=100, description="the legs rule judges only blobs whose "
                                                                         "cells gathered at least this share of the "
                                                                         "returns per cell of the map's obstacles "
                                                                         "(their median): a blob seen by a few "
                                                                         "returns, from afar or in a few scans, is "
                                                                         "a smear whose shape says nothing (0: off)")
    transient_ratio: float = Field(2.0, ge=0, le=1000, description="an occupied cell no camera labelled, off the "
                                                                   "walls, that scans saw free at least this many "
                                                                   "times as often as they hit it is someone who "
                                                                   "paused there, and is dropped; one touching an "
                                                                   "obstacle that stays is its rim (rays grazing "
                                                                   "a thin leg), freed but not dropped as dynamic "
                                                                   "(0: off)")
    faint_leg_ratio: float = Field(0.0, ge=0, le=1, description="(opt-in, 0.1 measured) also occupied: a piece "
                                                                "of cells touching no obstacle that returned at least "
                                                                "this share of the scans "
                                                                "that observed them (3 returns or more), that the "
                                                                "camera labelled furniture and never a person, "
                                                                "farther than faint_leg_people_distance from any "
                                                                "person evidence: a thin leg the rays grazing past it "
                                                                "outvoted (0: off)")
    faint_leg_people_distance: float = Field(0.3, ge=0, le=10, description="how far a faint leg must be from cells "
                                                                             "labelled or dropped as people, m")
    faint_leg_max_cells: int = Field(6, ge=1, le=1000, description="the largest piece of such cells that counts as "
                                                                   "legs")
    person_max_size: float = Field(1.0, ge=0, le=10, description="a blob of touching cells up to this long that "
                                                                "holds dynamic evidence leaves whole, m")
    label_spread_distance: float = Field(0.6, ge=0, le=100, description="unlabelled cells take their object's "
                                                                         "verdict only this close to a cell "
                                                                         "labelled so, m")


class BuildConfig(_Model):
    """Everything ``semmap build`` needs besides the tour and the calibration."""

    topics: TopicsConfig = TopicsConfig()
    frames: FramesConfig = FramesConfig()
    calibration: Path | None = Field(None, description="calibration file; relative paths are relative to the "
                                                         "config file (default: calibration.yaml beside the bag)")
    sync: SyncConfig = SyncConfig()
    segmentation: AnySegmentation = TopicSegmentation()
    paint: PaintConfig = PaintConfig()
    registration: RegistrationConfig = RegistrationConfig()
    grid: GridConfig = GridConfig()
    cleaning: CleaningConfig = CleaningConfig()
    workers: bool = Field(True, description="decode and segment images, and register and fuse scans, in worker "
                                            "processes (raw label images from the bag, with nothing to decode or "
                                            "infer, are read in the mapping process); false: everything in one "
                                            "process, for debugging")


# ---------------------------------------------------------------------------------------


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file safely; errors name the file."""
    from .io.yamlio import read_yaml

    return read_yaml(path, "configuration")


def merge_overrides(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Recursively merge ``over`` into a copy of ``base`` (``over`` wins)."""
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge_overrides(out[k], v)
        else:
            out[k] = v
    return out


def _where(loc: tuple[int | str, ...], kind: str) -> str:
    """A field's dotted name from a validation error's location, as a user writes it in YAML:
    without the backend name pydantic adds after ``segmentation``."""
    out = [x for i, x in enumerate(loc)
           if not (x in SEGMENTATION_BACKENDS and (i == 0 or loc[i - 1] == "segmentation"))]
    if kind == "unknown_backend":
        out.append("backend")
    return ".".join(str(x) for x in out)


def config_error(exc: ValidationError, source: str) -> ConfigError:
    """One line naming the source, the first bad field and what is wrong with it."""
    err = exc.errors()[0]
    loc = _where(tuple(err["loc"]), err["type"])
    msg = err["msg"]
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif err["type"] == "value_error":  # our own check: its message says what is wrong, and may name the field
        msg = msg.removeprefix("Value error, ")
    return ConfigError(f"{source}: {loc}: {msg}" if loc else f"{source}: {msg}")


def load_model(model: type[BaseModel], data: Any, source: str) -> Any:
    """Validate ``data`` into ``model``; the error names the source and the first bad field."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping at the top level")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise config_error(exc, source) from None


_SEGMENTATION: TypeAdapter[SegmentationConfig] = TypeAdapter(AnySegmentation)


def segmentation_config(data: Any, source: str = "segmentation") -> SegmentationConfig:
    """A ``segmentation:`` mapping (or a dump of one) validated into its backend's model, as a config
    file's section is: ``backend`` picks the model (default ``topic``)."""
    try:
        return _SEGMENTATION.validate_python({} if data is None else data)
    except ValidationError as exc:
        raise config_error(exc, source) from None
