"""Worker processes around the mapping core.

* **Frames** (:class:`FrameWorker`): a process that reads the camera topic from the bag,
  decodes the images and runs the segmenter, handing segmentations back through a
  bounded queue. Image decoding and model inference never share a process with mapping
  (the research separated them after segfaults in continuous CUDA runs), and a model
  that is slower than mapping no longer adds its time to it. Raw label images recorded in
  the bag have nothing to decode or infer: the build reads them in its own process
  (:class:`InProcessFrames`), where a frame is a view of the bag's bytes, not a copy.
* **Mapping** (:class:`MapperWorkers`): two chained processes, registration then fusion;
  painted scans stream in, the trajectory and the grid layers come back at the end. With
  painting in the calling process the three stages share the machine's cores.

Both have in-process twins (:class:`InProcessFrames`, :class:`InProcessMapper`) with the
same methods, used when ``workers: false`` (debugging) and by tests. Errors in a worker
come back as :class:`~semmap.errors.SemmapError` with the worker's one-line message.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import queue
import sys
import time
import types
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .config import GridConfig, RegistrationConfig, SegmentationConfig
from .errors import SemmapError
from .records import Segmentation

__all__ = ["InProcessFrames", "FrameWorker", "InProcessMapper", "MapperWorkers", "MapperResult"]

log = logging.getLogger(__name__)

_POLL_S = 0.2


def peak_rss_mb() -> float:
    """This process's peak resident memory, MB."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _context() -> Any:
    """Workers are spawned: forking a process that runs other threads (a GUI, a test runner,
    a logging handler) can deadlock the child."""
    return mp.get_context("spawn")


def _start(procs: list[Any]) -> None:
    """Start spawned workers without making them re-import the caller's main script.

    multiprocessing's spawn re-runs the ``__main__`` module in every child, so a script that
    calls :func:`semmap.build` at top level, without an ``if __name__ == "__main__":`` guard,
    would build again inside each worker. The workers need nothing from ``__main__``: it is
    hidden while they start.
    """
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        for p in procs:
            p.start()
    finally:
        if main is not None:
            sys.modules["__main__"] = main


class _Parent:
    """Lets a worker notice that the process that started it has gone (killed, crashed)."""

    def __init__(self) -> None:
        self._ppid = os.getppid()

    @property
    def alive(self) -> bool:
        return os.getppid() == self._ppid

    def get(self, q: Any) -> Any:
        while True:
            try:
                return q.get(timeout=1.0)
            except queue.Empty:
                if not self.alive:
                    raise SystemExit(0) from None

    def put(self, q: Any, item: Any) -> None:
        while True:
            try:
                q.put(item, timeout=1.0)
                return
            except queue.Full:
                if not self.alive:
                    raise SystemExit(0) from None


def _single_threaded() -> None:
    """Workers share the machine's cores with each other: no library thread pools of their own."""
    import cv2

    cv2.setNumThreads(1)
_COMPRESSED_T = "sensor_msgs/msg/CompressedImage"


class _FrameSource:
    """Segmentations of a camera topic, one per frame; the segmenter is created and the bag opened
    here, before the first frame is asked for (start-up, not work), and released by :meth:`close`."""

    def __init__(self, bag: Path, topic: str, msgtype: str, seg_cfg: SegmentationConfig,
                 counts: dict[str, int]) -> None:
        from .io.bag import iter_messages, open_bag
        from .segment.base import create_segmenter

        self._stack = contextlib.ExitStack()
        segmenter = create_segmenter(seg_cfg)
        self._stack.callback(segmenter.close)
        try:
            reader = self._stack.enter_context(open_bag(bag))
        except BaseException:
            self._stack.close()
            raise
        self._it = self._frames(iter_messages(bag, [topic], reader=reader), topic, msgtype, segmenter, counts)

    @staticmethod
    def _frames(messages: Iterator[tuple[str, int, Any]], topic: str, msgtype: str, segmenter: Any,
                counts: dict[str, int]) -> Iterator[Segmentation]:
        from .io.messages import compressed_image_from_msg, image_from_msg

        for _, _, msg in messages:
            t0 = time.perf_counter()
            try:
                img = compressed_image_from_msg(msg, topic) if msgtype == _COMPRESSED_T else image_from_msg(msg, topic)
                seg = segmenter.segment(img)
            except SemmapError as exc:  # a bad frame is skipped and counted
                counts["bad_frames"] += 1
                log.debug("skipped frame on %s: %s", topic, exc)
                continue
            counts["frames"] += 1
            counts["segment_ms"] += int((time.perf_counter() - t0) * 1000)
            yield seg

    def __iter__(self) -> Iterator[Segmentation]:
        return self._it

    def close(self) -> None:
        self._it.close()
        self._stack.close()


class InProcessFrames:
    """Segmentations of a camera topic, decoded in this process, one at a time."""

    def __init__(self, bag: Path, topic: str, msgtype: str, seg_cfg: SegmentationConfig) -> None:
        self.counts = {"frames": 0, "bad_frames": 0, "segment_ms": 0}
        self._source = _FrameSource(bag, topic, msgtype, seg_cfg, self.counts)
        self._it = iter(self._source)

    def next(self) -> Segmentation | None:
        return next(self._it, None)

    def wait_ready(self) -> None:
        pass

    def release(self, seg: Segmentation) -> None:
        pass

    def close(self) -> None:
        self._source.close()


def _frame_worker_main(bag: str, topic: str, msgtype: str, seg_cfg: dict[str, Any], out: Any,
                       shm_name: str | None, shape: tuple[int, int] | None, free_slots: Any) -> None:
    from multiprocessing import shared_memory

    counts = {"frames": 0, "bad_frames": 0, "segment_ms": 0}
    parent = _Parent()
    shm = shared_memory.SharedMemory(name=shm_name) if shm_name else None
    frames: _FrameSource | None = None
    _single_threaded()
    try:
        slots = None
        if shm is not None and shape is not None:
            n = shm.size // (shape[0] * shape[1] * 2)  # the size may be rounded up to whole pages
            slots = np.ndarray((n, *shape), np.uint16, buffer=shm.buf)
        cfg = SegmentationConfig.model_validate(seg_cfg)
        frames = _FrameSource(Path(bag), topic, msgtype, cfg, counts)
        parent.put(out, ("ready",))
        cpu0 = time.process_time()
        for seg in frames:
            if slots is not None and seg.label.shape == slots.shape[1:]:
                i = parent.get(free_slots)  # blocks while the mapper holds every slot: back-pressure
                slots[i] = seg.label
                parent.put(out, ("slot", seg.stamp_ns, i, seg.names, seg.confidence))
            else:  # an image of another size: send it whole (the painter will reject it)
                parent.put(out, ("frame", seg.stamp_ns, np.ascontiguousarray(seg.label), seg.names,
                                 seg.confidence))
        counts["peak_rss_mb"] = round(peak_rss_mb(), 1)
        counts["cpu_s"] = round(time.process_time() - cpu0, 3)
        parent.put(out, ("done", counts))
    except SemmapError as exc:
        out.put(("error", type(exc).__name__, str(exc)))
    except Exception as exc:  # noqa: BLE001 - report any failure instead of dying silently
        out.put(("error", type(exc).__name__, f"frame worker failed: {type(exc).__name__}: {exc}"))
    finally:
        if frames is not None:
            frames.close()
        if shm is not None:
            shm.close()


def _raise(kind: str, message: str) -> None:
    from . import errors

    cls = getattr(errors, kind, None)
    if isinstance(cls, type) and issubclass(cls, SemmapError):
        raise cls(message)
    raise SemmapError(message)


class FrameWorker:
    """Segmentations of a camera topic from a worker process.

    Label images travel through shared memory: a pool of ``n_slots`` image slots, each
    handed back to the worker when the mapper no longer needs that frame
    (:meth:`release`), so nothing large is copied between processes and the worker runs
    at most ``n_slots`` frames ahead.
    """

    def __init__(self, bag: Path, topic: str, msgtype: str, seg_cfg: SegmentationConfig,
                 shape: tuple[int, int] | None = None, n_slots: int = 12, queue_size: int = 16) -> None:
        from multiprocessing import shared_memory

        ctx = _context()
        self._queue = ctx.Queue(maxsize=queue_size)
        self._free = ctx.Queue(maxsize=n_slots)
        self._shm = None
        self._slots: NDArray[np.uint16] | None = None
        if shape is not None:
            self._shm = shared_memory.SharedMemory(create=True, size=n_slots * shape[0] * shape[1] * 2)
            self._slots = np.ndarray((n_slots, *shape), np.uint16, buffer=self._shm.buf)
            for i in range(n_slots):
                self._free.put(i)
        self._slot_of: dict[int, int] = {}
        self._proc = ctx.Process(target=_frame_worker_main, name="semmap-frames", daemon=True,
                                 args=(str(bag), topic, msgtype, seg_cfg.model_dump(mode="json"), self._queue,
                                       self._shm.name if self._shm else None, shape, self._free))
        _start([self._proc])
        self.counts = {"frames": 0, "bad_frames": 0, "segment_ms": 0}
        self._done = False

    def next(self) -> Segmentation | None:
        while not self._done:
            try:
                item = self._queue.get(timeout=_POLL_S)
            except queue.Empty:
                if not self._proc.is_alive():
                    self._done = True
                    raise SemmapError(
                        f"the frame worker stopped unexpectedly (exit code {self._proc.exitcode})") from None
                continue
            if item[0] == "ready":
                continue
            if item[0] == "slot":
                _, stamp, i, names, conf = item
                assert self._slots is not None
                seg = Segmentation(stamp, self._slots[i], names, conf)  # a read-only view, no copy
                self._slot_of[id(seg)] = i
                return seg
            if item[0] == "frame":
                _, stamp, label, names, conf = item
                return Segmentation(stamp, label, names, conf)
            if item[0] == "done":
                self.counts = item[1]
                self._done = True
                return None
            self._done = True
            _raise(item[1], item[2])
        return None

    def wait_ready(self) -> None:
        """Block until the worker has loaded its segmenter (so start-up is not counted as work)."""
        while True:
            try:
                item = self._queue.get(timeout=_POLL_S)
            except queue.Empty:
                if not self._proc.is_alive():
                    raise SemmapError(f"the frame worker stopped while starting (exit code {self._proc.exitcode})"
                                      ) from None
                continue
            if item[0] == "ready":
                return
            if item[0] == "error":
                self._done = True
                _raise(item[1], item[2])
            raise SemmapError(f"the frame worker sent {item[0]!r} before 'ready'")

    def release(self, seg: Segmentation) -> None:
        """The mapper is done with ``seg``: its slot may be reused."""
        i = self._slot_of.pop(id(seg), None)
        if i is not None:
            self._free.put(i)

    def close(self) -> None:
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(timeout=5)
        self._queue.close()
        self._free.close()
        self._slot_of.clear()
        self._slots = None
        if self._shm is not None:
            self._shm.close()
            self._shm.unlink()
            self._shm = None


# ---------------------------------------------------------------------------------------
# Mapping: registration, then fusion


@dataclass(frozen=True)
class MapperResult:
    """What the mapping stages return at the end of a tour."""

    poses: NDArray[np.float64]  # (N, 3) base_link in the map frame, one per pushed scan
    layers: Any  # GridLayers
    registration: dict[str, Any]  # Registrar.stats
    register_busy_s: float
    fuse_busy_s: float
    peak_rss_mb: dict[str, float] = field(default_factory=dict)  # per worker process
    cpu_s: dict[str, float] = field(default_factory=dict)  # CPU time of each worker process after start-up


class InProcessMapper:
    """Registration and fusion in this process."""

    def __init__(self, reg_cfg: RegistrationConfig, grid_cfg: GridConfig, class_names: tuple[str, ...]) -> None:
        from .grid import SemanticGrid
        from .register import Registrar

        self._registrar = Registrar(reg_cfg)
        self._grid = SemanticGrid(grid_cfg, class_names)
        self._poses: list[NDArray[np.float64]] = []
        self._busy = [0.0, 0.0]

    def wait_ready(self) -> None:
        pass

    def push(self, painted: Any, odom_pose: NDArray[np.float64] | None) -> None:
        t0 = time.perf_counter()
        pose = self._registrar.register(painted, odom_pose)
        t1 = time.perf_counter()
        self._grid.integrate(pose, painted)
        self._busy[0] += t1 - t0
        self._busy[1] += time.perf_counter() - t1
        self._poses.append(pose)

    def finish(self) -> MapperResult:
        return MapperResult(np.asarray(self._poses, dtype=np.float64).reshape(-1, 3), self._grid.layers(),
                            self._registrar.stats, self._busy[0], self._busy[1])

    def close(self) -> None:
        pass


def _registration_worker_main(cfg: dict[str, Any], inbox: Any, fusion_inbox: Any, outbox: Any) -> None:
    _single_threaded()
    try:
        from .register import Registrar

        parent = _Parent()
        registrar = Registrar(RegistrationConfig.model_validate(cfg))
        outbox.put(("ready",))
        cpu0 = time.process_time()
        poses: list[NDArray[np.float64]] = []
        busy = 0.0
        while True:
            batch = parent.get(inbox)
            if batch is None:
                break
            t0 = time.perf_counter()
            out = []
            for painted, odom_pose, prepared in batch:
                pose = registrar.register(painted, odom_pose, prepared)
                poses.append(pose)
                out.append((pose, painted))
            busy += time.perf_counter() - t0
            parent.put(fusion_inbox, out)
        parent.put(fusion_inbox, None)
        outbox.put(("poses", np.asarray(poses, dtype=np.float64).reshape(-1, 3), registrar.stats, busy,
                    peak_rss_mb(), time.process_time() - cpu0))
    except Exception as exc:  # noqa: BLE001 - report any failure instead of dying silently
        fusion_inbox.put(None)
        outbox.put(("error", type(exc).__name__, f"registration worker failed: {type(exc).__name__}: {exc}"))


def _fusion_worker_main(cfg: dict[str, Any], class_names: tuple[str, ...], inbox: Any, outbox: Any) -> None:
    _single_threaded()
    # fusion may fall behind (its queue is bounded); registration is the critical path
    with contextlib.suppress(OSError):
        os.nice(5)
    try:
        from .grid import SemanticGrid

        parent = _Parent()
        grid = SemanticGrid(GridConfig.model_validate(cfg), class_names)
        outbox.put(("ready",))
        cpu0 = time.process_time()
        busy = 0.0
        while True:
            batch = parent.get(inbox)
            if batch is None:
                break
            t0 = time.perf_counter()
            for pose, painted in batch:
                grid.integrate(pose, painted)
            busy += time.perf_counter() - t0
        outbox.put(("layers", grid.layers(), busy, peak_rss_mb(), time.process_time() - cpu0))
    except Exception as exc:  # noqa: BLE001 - report any failure instead of dying silently
        outbox.put(("error", type(exc).__name__, f"fusion worker failed: {type(exc).__name__}: {exc}"))


class MapperWorkers:
    """Registration and fusion in two chained worker processes; scans travel in small batches.

    Painting stays in the calling process, registration runs one scan behind it and fusion
    one batch behind registration, so the three share the machine's cores.
    """

    def __init__(self, reg_cfg: RegistrationConfig, grid_cfg: GridConfig, class_names: tuple[str, ...],
                 batch: int = 16, queue_size: int = 8) -> None:
        ctx = _context()
        self._to_reg = ctx.Queue(maxsize=queue_size)
        to_fuse = ctx.Queue(maxsize=queue_size)
        self._from_reg = ctx.Queue(maxsize=1)
        self._from_fuse = ctx.Queue(maxsize=1)
        self._procs = [
            ctx.Process(target=_registration_worker_main, name="semmap-register", daemon=True,
                        args=(reg_cfg.model_dump(mode="json"), self._to_reg, to_fuse, self._from_reg)),
            ctx.Process(target=_fusion_worker_main, name="semmap-fusion", daemon=True,
                        args=(grid_cfg.model_dump(mode="json"), tuple(class_names), to_fuse, self._from_fuse)),
        ]
        self._queues = [self._to_reg, to_fuse, self._from_reg, self._from_fuse]
        _start(self._procs)
        self._batch: list[tuple[Any, NDArray[np.float64] | None, Any]] = []
        self._batch_size = batch
        # the stateless down-sampling runs here, beside the painter, to unload the registration worker
        # (in icp mode: no Kalman filter to build, so its libraries stay out of this process)
        from .register import Registrar

        self._preparer = Registrar(reg_cfg.model_copy(update={"mode": "icp"})) if reg_cfg.mode != "odometry" \
            else None

    def wait_ready(self) -> None:
        """Block until both workers have loaded their libraries (start-up is not counted as work)."""
        for box in (self._from_reg, self._from_fuse):
            self._get(box)

    def _alive_or_raise(self) -> None:
        for p in self._procs:
            if not p.is_alive():
                for box in (self._from_reg, self._from_fuse):  # a worker that failed left a message
                    try:
                        item = box.get_nowait()
                    except queue.Empty:
                        continue
                    if item[0] == "error":
                        _raise(item[1], item[2])
                raise SemmapError(f"the {p.name} worker stopped unexpectedly (exit code {p.exitcode})")

    def _put(self, item: Any) -> None:
        while True:
            try:
                self._to_reg.put(item, timeout=_POLL_S)
                return
            except queue.Full:
                self._alive_or_raise()

    def push(self, painted: Any, odom_pose: NDArray[np.float64] | None) -> None:
        self._batch.append((painted, odom_pose, None if self._preparer is None else self._preparer.prepare(painted)))
        if len(self._batch) >= self._batch_size:
            self._put(self._batch)
            self._batch = []

    def _get(self, box: Any) -> Any:
        while True:
            try:
                item = box.get(timeout=_POLL_S)
            except queue.Empty:
                self._alive_or_raise()
                continue
            if item[0] == "error":
                _raise(item[1], item[2])
            return item

    def finish(self) -> MapperResult:
        if self._batch:
            self._put(self._batch)
            self._batch = []
        self._put(None)
        _, poses, stats, reg_busy, reg_rss, reg_cpu = self._get(self._from_reg)
        _, layers, fuse_busy, fuse_rss, fuse_cpu = self._get(self._from_fuse)
        return MapperResult(poses, layers, stats, reg_busy, fuse_busy,
                            {"registration": round(reg_rss, 1), "fusion": round(fuse_rss, 1)},
                            {"registration": round(reg_cpu, 3), "fusion": round(fuse_cpu, 3)})

    def close(self) -> None:
        for p in self._procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=5)
        for q in self._queues:
            q.close()
