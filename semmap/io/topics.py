"""ROS message type names, and which of a bag's topics semmap reads.

One place picks the topics, so ``semmap build``, ``semmap segment`` and ``semmap calibrate check``
read the same camera topic from the same bag. A topic named in the settings (the config's
``topics:``, or a command's option) is taken as it is (after checking it is in the bag and of a
type that fits); a topic not named is detected from the message types when exactly one topic fits,
and otherwise the error lists the candidates and names the setting that chooses one.

Image topics are told apart by name: one named like a label image (:data:`LABEL_HINTS`) carries
label images, one named like a depth image (:data:`NOT_CAMERA_HINTS`) is neither a camera picture
nor a label image, and any other is the camera's pictures.

Odometry comes from a ``nav_msgs/Odometry`` topic, or from the ``odom → base`` transform on ``/tf``
(``topics.odometry: tf``); which transform carries it is found by :func:`semmap.io.tour.open_tour`
(:func:`semmap.io.tf.find_tf_odometry`), which also takes ``/tf`` when the bag has no Odometry topic.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

from ..errors import BagError
from .tf import TfOdometry

__all__ = [
    "COMPRESSED_T",
    "IMAGE_T",
    "IMAGE_TYPES",
    "INFO_T",
    "LABEL_HINTS",
    "NOT_CAMERA_HINTS",
    "ODOM_T",
    "SCAN_T",
    "TF_T",
    "TF_TYPES",
    "TRUTH_HINTS",
    "TopicSettings",
    "Topics",
    "pick_topics",
    "wants_tf_odometry",
]

SCAN_T = "sensor_msgs/msg/LaserScan"
IMAGE_T = "sensor_msgs/msg/Image"
COMPRESSED_T = "sensor_msgs/msg/CompressedImage"
INFO_T = "sensor_msgs/msg/CameraInfo"
ODOM_T = "nav_msgs/msg/Odometry"
TF_T = "tf2_msgs/msg/TFMessage"
#: the transform message types: tf2's, and the ``tf/tfMessage`` of ROS1 bags recorded before tf2
TF_TYPES = (TF_T, "tf/msg/tfMessage")
IMAGE_TYPES = (IMAGE_T, COMPRESSED_T)

#: an image topic whose name holds one of these carries label images (see the conventions, "Label images")
LABEL_HINTS = ("label", "seg", "mask", "semantic", "class")
#: an image topic whose name holds one of these is neither the camera's pictures nor label images
NOT_CAMERA_HINTS = ("depth",)
#: an odometry topic whose name holds one of these is a reference, not the robot's own odometry
TRUTH_HINTS = ("ground_truth", "groundtruth", "gt", "truth", "mocap", "vicon")

Kind = Literal["scan", "odometry", "image", "camera_info"]
_ALL_KINDS: tuple[Kind, ...] = ("scan", "odometry", "image", "camera_info")
_SCAN_ONLY: tuple[Kind, ...] = ("scan",)


class TopicSettings(Protocol):
    """The topic names a user set (the config's ``topics:``); None: detect it from the bag."""

    @property
    def scan(self) -> str | None: ...
    @property
    def image(self) -> str | None: ...
    @property
    def labels(self) -> str | None: ...
    @property
    def camera_info(self) -> str | None: ...
    @property
    def odometry(self) -> str | None: ...
    @property
    def tf(self) -> str: ...
    @property
    def tf_static(self) -> str: ...


@dataclass(frozen=True)
class Topics:
    scan: str  # "" only when the scan topic was not asked for
    image: str | None  # the image stream the segmenter consumes (labels or RGB)
    image_kind: str  # "labels" | "rgb" | "none"
    odometry: str | None  # the Odometry topic, or the /tf topic when odometry comes from /tf
    tf_static: str | None
    camera_info: str | None
    #: odometry from /tf: the transform that carries it (set by :func:`semmap.io.tour.open_tour`)
    odometry_tf: TfOdometry | None = None

    @property
    def odometry_source(self) -> str | None:
        """The odometry as logs and the summary name it: the topic, or ``/tf (odom -> base_footprint)``."""
        return self.odometry_tf.label if self.odometry_tf is not None else self.odometry


def wants_tf_odometry(setting: str | None, tf_topic: str) -> bool:
    """Whether ``topics.odometry`` asks for odometry from /tf: ``tf`` or the tf topic's own name."""
    return setting is not None and (setting.lower() == "tf" or setting == tf_topic)


def _named(topic: str, hints: tuple[str, ...]) -> bool:
    low = topic.lower()
    return any(h in low for h in hints)


def _pick(kind: str, wanted: str | None, candidates: list[str], types: Mapping[str, str], where: str,
          required: bool, option: str, fits: tuple[str, ...] = ()) -> str | None:
    if wanted is not None:
        if wanted.lower() == "none":
            return None
        if wanted not in types:
            raise BagError(f"{where}: topic {wanted} ({kind}) is not in the bag "
                             f"(topics: {', '.join(sorted(types)) or 'none'})")
        if fits and types[wanted] not in fits:
            raise BagError(f"{where}: topic {wanted} is {types[wanted]}, not {' or '.join(fits)} ({kind})")
        return wanted
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        if required:
            raise BagError(f"{where}: no {kind} topic in the bag; name one with {option}")
        return None
    raise BagError(f"{where}: several {kind} topics ({', '.join(sorted(candidates))}); choose one with {option}")


def pick_topics(types: Mapping[str, str], settings: TopicSettings, where: str | Path, consumes: str,
                manifest: Mapping[str, Any] | None = None, *, kinds: Collection[Kind] = _ALL_KINDS,
                required: Collection[Kind] = _SCAN_ONLY, options: Mapping[str, str] | None = None) -> Topics:
    """The topics to read from a bag whose topics have the message ``types``.

    ``settings``: the names the user set; a topic not set is taken from the tour folder's
    ``manifest`` (``tour.yaml``'s ``topics:``) when it names one in the bag, else detected from the
    message types. ``consumes``: ``"labels"`` (the images are label images) or ``"rgb"``. ``kinds``:
    the topics wanted (the others are None); ``required``: those whose absence is an error.
    ``options``: how the user names each kind (``{"image": "--topic"}``), for the error that says
    how to choose; by default ``topics.<kind> in the config``.
    """
    where = str(where)
    known = (manifest or {}).get("topics") or {}

    def want(name: str) -> str | None:
        v = getattr(settings, name)
        if v is None and name in known and known[name] in types:
            return str(known[name])
        return v

    def option(name: str) -> str:
        return (options or {}).get(name) or f"topics.{name} in the config"

    def of(*wanted_types: str) -> list[str]:
        return [k for k, v in types.items() if v in wanted_types]

    scan = odometry = image = camera_info = None
    image_kind = "none"
    if "scan" in kinds:
        scan = _pick("scan", want("scan"), of(SCAN_T), types, where, "scan" in required, option("scan"), (SCAN_T,))
    if "odometry" in kinds:
        odoms = [k for k in of(ODOM_T) if not _named(k, TRUTH_HINTS)]
        if wants_tf_odometry(want("odometry"), settings.tf):  # the frames are found by open_tour
            odometry = _pick("the odometry transforms, topics.odometry: tf", settings.tf, [], types, where, True,
                             option("odometry"), TF_TYPES)
        else:
            odometry = _pick("odometry", want("odometry"), odoms, types, where, "odometry" in required,
                             option("odometry"), (ODOM_T,))
    if "image" in kinds:
        images = [k for k in of(*IMAGE_TYPES) if not _named(k, NOT_CAMERA_HINTS)]
        name = "labels" if consumes == "labels" else "image"
        cands = [k for k in images if _named(k, LABEL_HINTS) == (consumes == "labels")]
        image = _pick(name, want(name), cands, types, where, "image" in required, option(name), IMAGE_TYPES)
        image_kind = ("labels" if consumes == "labels" else "rgb") if image else "none"
    if "camera_info" in kinds:
        infos = of(INFO_T)
        camera_info = _pick("camera_info", want("camera_info"), infos, types, where, "camera_info" in required,
                            option("camera_info"), (INFO_T,)) if infos or settings.camera_info else None
    tf_static = settings.tf_static if settings.tf_static in types else None
    return Topics(scan or "", image, image_kind, odometry, tf_static, camera_info)
