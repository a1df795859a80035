"""Which camera frames the model runs on (``segmentation.select``).

A map does not need every frame segmented: a view from nearly the same pose a moment ago adds
almost nothing. The selection is made before the model runs, so a skipped frame costs no model
time; the scans paired with a skipped frame take their labels from the segmented frames cell by cell,
structure's and furniture's through the registered poses (:class:`semmap.paint.painter.LabelTransfer`),
people's through the odometry (:class:`semmap.paint.painter.LabelMemory`), and stay unlabelled where no
segmented frame saw the same cells.

* ``all``: every frame (the default).
* ``motion``: the first frame, then a frame once the robot has moved ``select_distance`` or turned
  ``select_angle`` since the last segmented one, or ``select_interval`` has passed (people move while
  the robot stands still). Without odometry only the interval applies.
* ``need``: a frame when what it looks at lacks camera evidence (:class:`semmap.paint.need.NeedSelector`).
* ``max_rate``: a budget on top of any of them, at most that many frames per second of tour on average
  (a token bucket holding the frames of five seconds, at least two: a frame the selection wants waits for a
  token, and a quiet stretch saves frames for a busy one).
  ``max_frames``: at most that many in all, spent at the rate that spreads them over the tour's length
  (from the bag's index), and never more. ``max_seconds``: at most that much model time in all, spent the
  same way: after each frame the seconds left, at the model's median time over its last five frames,
  become the rate that spreads them over the rest of the tour. A frame read from the mask cache counts
  the time it took when it was segmented, so a rebuild selects the frames the first build did and runs
  no model. (Model time varies from run to run and machine to machine: ``max_frames`` is the budget that
  selects the same frames everywhere.)

A selector sees the bag's records in bag order (:meth:`FrameSelector.on_record`: the odometry, and
whatever else its :attr:`~FrameSelector.topics` name), is asked about each camera frame before the model
runs (:meth:`~FrameSelector.want`), and is told what the model made of it
(:meth:`~FrameSelector.segmented`, :meth:`~FrameSelector.failed`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..config import SegmentationConfig
from ..geometry import wrap_angle
from ..records import Segmentation

if TYPE_CHECKING:
    from ..io.tf import TfOdometry

__all__ = ["FrameSelector", "OdometrySource", "SkippedFrame", "every_frame"]

#: the budget's bucket holds the frames of this many seconds at its rate (at least ``_MIN_BUCKET``): what a
#: stretch the map needs nothing from (a corridor whose walls are known) saves is spent where it needs much
#: (a room of furniture walked into), and the average rate still holds over any few seconds. With two frames
#: (before stop 69) a one-frame-a-second budget refused frames on furniture after a quiet spell and used
#: 76 % of its frames on the development worlds (88 % with five)
_BURST_S = 5.0
_MIN_BUCKET = 2.0
#: ``max_seconds`` estimates the model's time per frame from this many of its last frames
_RECENT = 5


def every_frame(cfg: SegmentationConfig) -> bool:
    """Whether the settings segment every frame: no selection and no budget."""
    return cfg.select == "all" and cfg.max_rate is None and cfg.max_frames is None and cfg.max_seconds is None


@dataclass(frozen=True)
class SkippedFrame:
    """A camera frame the selection did not segment: only its time, so scans are still paired with it."""

    stamp_ns: int


@dataclass(frozen=True)
class OdometrySource:
    """Where the frame selection reads the robot's motion: an Odometry topic, or ``/tf`` (``tf`` names the
    odometry transform); ``offset_ns`` is added to its stamps (``sync.odometry_offset``)."""

    topic: str
    tf: TfOdometry | None = None
    offset_ns: int = 0


class FrameSelector:
    """Decides, frame by frame in time order, whether the model runs on it (``all``, ``motion``, and the
    budget; ``need`` is :class:`semmap.paint.need.NeedSelector`, built on this).

    The odometry (``odometry``, read in the same pass as the images) gives the robot's pose; a frame is
    judged by the latest pose at or before its stamp.
    """

    def __init__(self, cfg: SegmentationConfig, odometry: OdometrySource | None = None) -> None:
        self.mode = cfg.select
        self.distance = cfg.select_distance
        self.angle = math.radians(cfg.select_angle)
        interval = cfg.select_interval if cfg.select_interval is not None else (1.0 if cfg.select == "motion" else 0.0)
        self.interval_ns = int(interval * 1e9)
        self.rate = cfg.max_rate
        self.max_frames = cfg.max_frames
        self.max_seconds = cfg.max_seconds
        self._rate_cap = cfg.max_rate  # the rate the other budgets allow (max_seconds adjusts below it)
        self._tour_s: float | None = None
        self._first_ns: int | None = None
        self.model_seconds = 0.0  # the model time spent so far (``max_seconds``)
        self._recent: deque[float] = deque(maxlen=_RECENT)
        self.trivial = every_frame(cfg)  # every frame is segmented: nothing else needs reading
        self.odometry = None if self.trivial else odometry
        self._pose: NDArray[np.float64] | None = None  # the latest odometry pose
        self._pose_ns: int | None = None
        self._last_ns: int | None = None  # the last segmented frame: its stamp and pose
        self._last_pose: NDArray[np.float64] | None = None
        self._tokens = 1.0
        self._tokens_ns: int | None = None
        self._undo: tuple[int | None, NDArray[np.float64] | None] | None = None
        self.selected = 0
        self.skipped = 0

    def spread_over(self, seconds: float) -> None:
        """The tour lasts ``seconds``: a ``max_frames`` budget becomes the rate that spends it over the tour
        (the lower of it and ``max_rate``); the count caps it too."""
        if seconds > 0:
            self._tour_s = seconds
        if self.max_frames is not None and seconds > 0:
            rate = self.max_frames / seconds
            self.rate = rate if self.rate is None else min(self.rate, rate)
            self._rate_cap = self.rate

    @property
    def topics(self) -> list[str]:
        """The topics it reads besides the camera's."""
        return [self.odometry.topic] if self.odometry is not None else []

    def on_record(self, topic: str, record: Any) -> None:
        """A record of one of :attr:`topics`, in bag order."""
        odo = self.odometry
        if odo is not None and topic == odo.topic:
            if odo.tf is not None:
                for stamp, pose in odo.tf.poses(record):
                    self.add_odometry(stamp + odo.offset_ns, pose)
            else:
                self.add_odometry(record[0] + odo.offset_ns, record[3])

    def add_odometry(self, stamp_ns: int, pose: NDArray[np.float64]) -> None:
        if self._pose_ns is None or stamp_ns >= self._pose_ns:
            self._pose, self._pose_ns = np.asarray(pose, np.float64), stamp_ns

    def _moved(self, stamp_ns: int) -> bool:
        if self._last_ns is None:
            return True
        if self.interval_ns > 0 and stamp_ns - self._last_ns >= self.interval_ns:
            return True
        if self._pose is None or self._last_pose is None:
            return False
        d = self._pose - self._last_pose
        return bool(math.hypot(d[0], d[1]) >= self.distance or abs(float(wrap_angle(float(d[2])))) >= self.angle)

    def _budget(self, stamp_ns: int) -> bool:
        """Whether the budget has a frame to spend at ``stamp_ns`` (tokens accrue with bag time)."""
        if self.rate is None:
            return True
        if self._tokens_ns is not None:
            bucket = max(_MIN_BUCKET, _BURST_S * self.rate)
            self._tokens = min(bucket, self._tokens + max(0, stamp_ns - self._tokens_ns) * 1e-9 * self.rate)
        self._tokens_ns = stamp_ns
        return self._tokens >= 1.0

    def wanted(self, stamp_ns: int) -> bool:
        """Whether the selection (budget aside) wants the frame stamped ``stamp_ns`` segmented."""
        return self.mode == "all" or self._moved(stamp_ns)

    def want(self, stamp_ns: int) -> bool:
        """Whether to segment the frame stamped ``stamp_ns``, budget included; counted either way."""
        if self._first_ns is None:
            self._first_ns = stamp_ns
        spent = (self.max_frames is not None and self.selected >= self.max_frames) or (
            self.max_seconds is not None and self.model_seconds >= self.max_seconds)
        if not spent and self.wanted(stamp_ns) and self._budget(stamp_ns):
            if self.rate is not None:
                self._tokens -= 1.0
            self._undo = (self._last_ns, self._last_pose)
            self._last_ns, self._last_pose = stamp_ns, self._pose
            self.selected += 1
            return True
        self.skipped += 1
        return False

    def segmented(self, seg: Segmentation) -> None:
        """What the model made of the frame just taken."""

    def timed(self, seconds: float, stamp_ns: int) -> None:
        """The model spent ``seconds`` on the frame stamped ``stamp_ns``, just taken: with ``max_seconds``,
        the seconds left at the model's recent time per frame become the rate over the rest of the tour."""
        seconds = max(0.0, seconds)
        self.model_seconds += seconds
        self._recent.append(seconds)
        if self.max_seconds is None or self._tour_s is None or self._first_ns is None:
            return  # (the tour's length unknown: the total still holds, spent as the frames come)
        # the model's time per frame from its last few (a first frame's warm-up is soon forgotten)
        per_frame = max(float(np.median(self._recent)), 1e-6)
        frames_left = max(0.0, (self.max_seconds - self.model_seconds) / per_frame)
        rate = frames_left / max(self._tour_s - (stamp_ns - self._first_ns) * 1e-9, 1e-3)
        if self.rate is None:
            self._tokens, self._tokens_ns = 0.0, stamp_ns  # this frame spent the first token
        self.rate = rate if self._rate_cap is None else min(self._rate_cap, rate)

    def failed(self) -> None:
        """The frame just taken could not be segmented: the next one is judged as if it had not been taken
        (its budget is spent)."""
        if self._undo is not None:
            self._last_ns, self._last_pose = self._undo
            self._undo = None
            self.selected -= 1
