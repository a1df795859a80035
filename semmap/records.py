"""Frozen records that cross stage boundaries.

Units are in the field names or docstrings: metres, radians, seconds, and
integer nanoseconds for timestamps (as rosbags gives them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .geometry import is_rotation, se3_inverse

__all__ = [
    "REGION_BASE",
    "Calibration",
    "CameraIntrinsics",
    "GridSpec",
    "Image",
    "Mobility",
    "PaintedScan",
    "Scan",
    "Segmentation",
]


#: ``PaintedScan.instance`` values from here on name a connected region of a class's mask, below it
#: an instance the segmentation backend told apart: a region can join objects, not tell them apart
#: (two legs of one table are two regions when the table top is out of the image)
REGION_BASE = 1 << 16


class Mobility(IntEnum):
    """How a class moves. The value is what label and mobility arrays store."""

    UNKNOWN = 0  #: not seen by the camera (out of view, behind it, or occluded)
    STATIC = 1  #: inside the image, on no object mask: walls, pillars, fixed structure
    SEMI_STATIC = 2  #: movable but currently still: chairs, tables, beds, carts, plants
    DYNAMIC = 3  #: moves on its own: people, animals

    @classmethod
    def parse(cls, name: str) -> Mobility:
        try:
            return cls[name.strip().upper()]
        except KeyError:
            valid = ", ".join(m.name.lower() for m in cls)
            raise ValueError(f"unknown mobility {name!r} (expected one of {valid})") from None

    @property
    def label(self) -> str:
        return self.name.lower()


def _matrix(a: object, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    m = np.array(a, dtype=np.float64)
    if m.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name} contains NaN or inf")
    m.setflags(write=False)
    return m


@dataclass(frozen=True)
class CameraIntrinsics:
    """A camera model: pinhole with OpenCV distortion, or OpenCV fisheye.

    ``K`` is the 3x3 camera matrix in pixels; ``D`` the distortion coefficients
    (pinhole: k1 k2 p1 p2 [k3 [k4 k5 k6]]; fisheye: k1 k2 k3 k4).
    """

    width: int
    height: int
    K: NDArray[np.float64]
    D: NDArray[np.float64] = field(default_factory=lambda: np.zeros(5))
    model: Literal["pinhole", "fisheye"] = "pinhole"

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", _matrix(self.K, (3, 3), "K"))
        d = np.array(self.D, dtype=np.float64).ravel()
        if not np.all(np.isfinite(d)):
            raise ValueError("D contains NaN or inf")
        d.setflags(write=False)
        object.__setattr__(self, "D", d)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.model not in ("pinhole", "fisheye"):
            raise ValueError(f"camera model must be 'pinhole' or 'fisheye', got {self.model!r}")
        if self.model == "fisheye" and d.size != 4:
            raise ValueError(f"fisheye distortion needs 4 coefficients, got {d.size}")
        if self.model == "pinhole" and d.size not in (4, 5, 8, 12, 14):
            raise ValueError(f"pinhole distortion needs 4, 5, 8, 12 or 14 coefficients, got {d.size}")
        if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise ValueError("K must have positive focal lengths fx, fy")
        if abs(self.K[1, 0]) > 1e-9 or not np.allclose(self.K[2], [0.0, 0.0, 1.0], rtol=0.0, atol=1e-9):
            raise ValueError("K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])


@dataclass(frozen=True)
class Calibration:
    """Camera intrinsics plus the LiDAR→camera extrinsic.

    ``T_cam_lidar`` maps points in the LiDAR frame into the camera optical
    frame: ``p_cam = T_cam_lidar @ p_lidar``.
    """

    intrinsics: CameraIntrinsics
    T_cam_lidar: NDArray[np.float64]
    camera_frame: str = "camera_optical_frame"
    lidar_frame: str = "laser"

    def __post_init__(self) -> None:
        t = _matrix(self.T_cam_lidar, (4, 4), "T_cam_lidar")
        if not is_rotation(t[:3, :3], tol=1e-5):
            raise ValueError("T_cam_lidar rotation is not orthonormal with det +1")
        if not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0]):
            raise ValueError("T_cam_lidar last row must be [0, 0, 0, 1]")
        object.__setattr__(self, "T_cam_lidar", t)

    @property
    def T_lidar_cam(self) -> NDArray[np.float64]:
        """The inverse: maps camera-frame points into the LiDAR frame."""
        return se3_inverse(self.T_cam_lidar)


@dataclass(frozen=True)
class Scan:
    """One 2D LiDAR scan as in ``sensor_msgs/LaserScan`` (REP-117 invalid values allowed).

    ``stamp_ns`` is the acquisition time of the first beam.
    """

    stamp_ns: int
    frame_id: str
    angle_min: float
    angle_increment: float
    ranges: NDArray[np.float32]
    range_min: float
    range_max: float
    time_increment: float = 0.0
    scan_time: float = 0.0
    intensities: NDArray[np.float32] | None = None

    def __post_init__(self) -> None:
        r = np.asarray(self.ranges, dtype=np.float32)
        r.setflags(write=False)
        object.__setattr__(self, "ranges", r)

    @property
    def angles(self) -> NDArray[np.float64]:
        return self.angle_min + self.angle_increment * np.arange(self.ranges.size, dtype=np.float64)


@dataclass(frozen=True)
class Image:
    """A camera or label image with its capture stamp.

    ``encoding`` follows ``sensor_msgs/Image``: ``rgb8``, ``bgr8``, ``mono8``,
    ``mono16``, ``16UC1``... Label images are ``uint16`` (``mono16``) or ``uint8``
    (``mono8``): value k > 0 is class ``names[k-1]``, 0 is no object.
    """

    stamp_ns: int
    frame_id: str
    data: NDArray[np.generic]
    encoding: str

    def __post_init__(self) -> None:
        a = np.asarray(self.data)
        a.setflags(write=False)
        object.__setattr__(self, "data", a)

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])


@dataclass(frozen=True)
class GridSpec:
    """A regular 2D grid on the floor.

    Cell ``(row, col)`` covers ``x ∈ [origin_x + col·res, origin_x + (col+1)·res)`` and
    ``y ∈ [origin_y + row·res, …)``: row 0 is the *lowest* y, as in the world. (Map
    images flip this: their top row is the highest y.) ``origin`` is the lower-left
    corner of cell (0, 0), which is what map_server's ``origin`` means.
    """

    resolution: float
    origin_x: float
    origin_y: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not self.resolution > 0:
            raise ValueError(f"grid resolution must be positive, got {self.resolution}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"grid size must be positive, got {self.width}x{self.height}")

    @classmethod
    def covering(cls, x_min: float, y_min: float, x_max: float, y_max: float, resolution: float) -> GridSpec:
        """The smallest grid, aligned to multiples of ``resolution``, covering a box."""
        ox = np.floor(x_min / resolution) * resolution
        oy = np.floor(y_min / resolution) * resolution
        w = int(np.ceil((x_max - ox) / resolution - 1e-9))
        h = int(np.ceil((y_max - oy) / resolution - 1e-9))
        return cls(float(resolution), float(ox), float(oy), max(w, 1), max(h, 1))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def world_to_cell(self, xy: NDArray[np.float64]) -> NDArray[np.intp]:
        """(N, 2) world points → (N, 2) integer (row, col); may be outside the grid."""
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor((xy[..., 0] - self.origin_x) / self.resolution).astype(np.intp)
        row = np.floor((xy[..., 1] - self.origin_y) / self.resolution).astype(np.intp)
        return np.stack([row, col], axis=-1)

    def cell_centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(x, y) of every cell centre, each (H, W)."""
        xs = self.origin_x + (np.arange(self.width) + 0.5) * self.resolution
        ys = self.origin_y + (np.arange(self.height) + 0.5) * self.resolution
        return np.meshgrid(xs, ys)

    def as_dict(self) -> dict[str, float | int]:
        return {"resolution": self.resolution, "origin_x": self.origin_x, "origin_y": self.origin_y,
                "width": self.width, "height": self.height}

    def crop(self, row0: int, row1: int, col0: int, col1: int) -> GridSpec:
        """The sub-grid of rows ``row0:row1`` and columns ``col0:col1``."""
        return GridSpec(self.resolution, self.origin_x + col0 * self.resolution,
                        self.origin_y + row0 * self.resolution, col1 - col0, row1 - row0)


@dataclass(frozen=True)
class Segmentation:
    """A segmentation result for one camera image (see docs/conventions.md, "Label images").

    ``label`` is ``uint16`` (H, W): value k > 0 is ``names[k-1]``, 0 is no object.
    ``confidence`` is ``float32`` (H, W) in [0, 1] where the backend has one.
    ``instance`` is ``uint16`` (H, W) where the backend tells objects apart (YOLO-seg): value i > 0
    is the image's i-th object, 0 is no object. Without it, the connected regions of each class's
    mask stand in for the objects.
    """

    stamp_ns: int
    label: NDArray[np.uint16]
    names: tuple[str, ...]
    confidence: NDArray[np.float32] | None = None
    instance: NDArray[np.uint16] | None = None

    def __post_init__(self) -> None:
        lab = np.asarray(self.label)
        if lab.ndim != 2:
            raise ValueError(f"a label image must be 2-D, got shape {lab.shape}")
        if lab.dtype != np.uint16:
            lab = lab.astype(np.uint16)
        lab.setflags(write=False)
        object.__setattr__(self, "label", lab)
        object.__setattr__(self, "names", tuple(self.names))
        for name, dtype in (("confidence", np.float32), ("instance", np.uint16)):
            value = getattr(self, name)
            if value is None:
                continue
            a = np.asarray(value, dtype=dtype)
            if a.shape != lab.shape:
                raise ValueError(f"{name} shape {a.shape} differs from label shape {lab.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)


@dataclass(frozen=True)
class PaintedScan:
    """One LiDAR scan, motion-compensated into the base frame and painted with classes.

    All beams are kept, in scan order, so rays can clear free space:

    * ``origin`` (2,): the LiDAR's position in the base frame (m) at ``stamp_ns``.
    * ``points`` (N, 2): beam end points in the base frame (m), deskewed to ``stamp_ns``.
      Beams without a return (``hit`` false) end at the free-space range instead.
    * ``hit`` (N,): the beam returned a valid range (finite, within range limits).
    * ``mobility`` (N,): :class:`Mobility` values; 0 where the camera did not see the point.
    * ``class_id`` (N,): index into ``class_names``, -1 for no object / unseen.
    * ``instance`` (N,): the object the camera saw the point on, a number unique within the scan,
      -1 for none: the backend's instance (below ``REGION_BASE``), or else the connected region of
      the point's class's mask (``REGION_BASE`` and above); given for semi-static points only
      (None: all -1).
    * ``stamp_ns``: the time the points are expressed at (the scan's reference time).
    * ``frame_ns``: the stamp of the camera frame the scan was paired with (None: none, or no calibrated
      camera); ``segmented``: whether that frame was segmented (its labels are on the returns) or skipped
      (``segmentation.select``: the returns await the labels of the frames that were, see
      :class:`~semmap.paint.painter.LabelTransfer`).
    * ``in_view`` (N,): for a scan paired with a skipped frame, the returns that frame's camera saw
      (None: all or none).
    """

    stamp_ns: int
    origin: NDArray[np.float64]
    points: NDArray[np.float64]
    hit: NDArray[np.bool_]
    mobility: NDArray[np.uint8]
    class_id: NDArray[np.int16]
    class_names: tuple[str, ...] = ()
    frame_id: str = ""
    instance: NDArray[np.int32] | None = None
    frame_ns: int | None = None
    segmented: bool = False
    in_view: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64).reshape(-1, 2)
        n = pts.shape[0]
        hit = np.asarray(self.hit, dtype=bool).reshape(-1)
        mob = np.asarray(self.mobility, dtype=np.uint8).reshape(-1)
        cls = np.asarray(self.class_id, dtype=np.int16).reshape(-1)
        inst = np.full(n, -1, np.int32) if self.instance is None else np.asarray(self.instance, np.int32).reshape(-1)
        if not (hit.size == mob.size == cls.size == inst.size == n):
            raise ValueError("points, hit, mobility, class_id and instance must have one entry per beam")
        for name, arr in (("origin", np.asarray(self.origin, dtype=np.float64).reshape(2)), ("points", pts),
                          ("hit", hit), ("mobility", mob), ("class_id", cls), ("instance", inst)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if self.in_view is not None:
            view = np.asarray(self.in_view, dtype=bool).reshape(-1)
            if view.size != n:
                raise ValueError("in_view must have one entry per beam")
            view.setflags(write=False)
            object.__setattr__(self, "in_view", view)
        object.__setattr__(self, "class_names", tuple(self.class_names))

    @property
    def n_beams(self) -> int:
        return int(self.points.shape[0])
