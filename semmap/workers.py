"""Worker processes around the mapping core.

* **Images** (:class:`ImageWorker`): a process that reads the camera topic from the bag,
  decodes the images and runs the segmenter, handing segmentations back through shared
  memory. Image decoding and model inference never share a process with mapping (the
  research separated them after segfaults in continuous CUDA runs), and a model that is
  slower than mapping no longer adds its time to it. Raw label images recorded in the bag
  have nothing to decode or infer: the build reads them in its own process
  (:class:`InProcessImages`), where an image is a view of the bag's bytes, not a copy.
* **Mapping** (:class:`MapperWorkers`): two chained processes, registration then fusion;
  painted scans stream in, the trajectory and the grid layers come back at the end. With
  painting in the calling process the three stages share the machine's cores.

Both have in-process twins (:class:`InProcessImages`, :class:`InProcessMapper`) with the
same methods (:class:`ImageSource`, :class:`Mapper`), used when ``workers: false``
(debugging) and by tests.

**Whatever happens to a process, nothing hangs and nothing is left behind.**

* Processes talk through one-way pipes, and each end is held by one process only: a reader
  sees end-of-file, and a writer a broken pipe, the moment the process at the other end is
  gone, even in the middle of a message. Every wait on a worker also watches its process
  sentinel. There are no queues with feeder threads to flush at exit, and no semaphores.
* A worker that dies becomes one :class:`~semmap.errors.WorkerError` naming its stage and how
  it ended (``killed by SIGKILL``: the out-of-memory killer); a worker's bug becomes an
  :class:`~semmap.errors.InternalError` carrying the worker's traceback; a worker's
  :class:`~semmap.errors.SemmapError` is raised again as itself.
* Workers ignore SIGINT, SIGTERM and SIGHUP (Ctrl-C, a closed terminal or systemd reach the
  whole process group; the caller decides and stops them), die with their parent on Linux
  (``PR_SET_PDEATHSIG``), and are named in ``ps``/``top`` (``semmap-images``,
  ``semmap-register``, ``semmap-fusion``).
* ``close`` kills the workers, joins them, closes the pipes and unlinks the shared memory,
  with SIGINT, SIGTERM and SIGHUP held back until it is done.
* Log records of the workers are sent to the caller and logged there, at the caller's levels.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import logging
import multiprocessing as mp
import os
import signal
import sys
import time
import traceback
import types
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from .config import GridConfig, LoopClosureConfig, RegistrationConfig, SegmentationConfig, segmentation_config
from .errors import InternalError, SemmapError, WorkerError
from .paint.need import NeedContext, make_selector
from .records import PaintedScan, Segmentation
from .runtime import STOP_SIGNALS, peak_rss_mb, signals_held
from .segment.images import ImageReader, ImageSource, InProcessImages, OdometrySource
from .segment.select import SkippedFrame

if TYPE_CHECKING:
    from .grid import GridLayers

__all__ = [
    "ImageSource",
    "ImageWorker",
    "InProcessImages",
    "InProcessMapper",
    "Mapper",
    "MapperResult",
    "MapperWorkers",
    "signals_held",
]

log = logging.getLogger(__name__)

_PIPE_BYTES = 1 << 20  # scans in flight between the mapping stages (Linux; elsewhere the system's pipe size)
_REPORT_S = 3.0  # after a failure, how long the other workers get to report theirs
_EXIT_S = 2.0  # how long workers that sent their last message get to end on their own


def _send_large(conn: Connection, obj: Any) -> None:
    """Send a frozen dataclass holding large arrays (the grid's layers) without pickling the arrays: its
    other fields go in the announcing message, each array's bytes straight from its memory after it."""
    fields = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    arrays = {k: np.ascontiguousarray(v) for k, v in fields.items() if isinstance(v, np.ndarray)}
    conn.send(("large", type(obj), {k: v for k, v in fields.items() if k not in arrays},
               {k: (a.dtype.str, a.shape) for k, a in arrays.items()}))
    for a in arrays.values():
        # an ndarray is a buffer (numpy's stubs do not say so to Python 3.11's type checkers)
        conn.send_bytes(a.reshape(-1).view(np.uint8) if a.size else b"")  # type: ignore[arg-type]


def _recv_large(conn: Connection, cls: type, others: dict[str, Any], layout: dict[str, tuple[str, tuple[int, ...]]]
                ) -> Any:
    """What :func:`_send_large` sent, after its announcing message: each array received into its own
    memory, read-only as in the sender."""
    arrays = {}
    for name, (dtype, shape) in layout.items():
        a = np.empty(shape, dtype)
        if a.size:
            conn.recv_bytes_into(a.reshape(-1).view(np.uint8))
        else:
            conn.recv_bytes()
        a.setflags(write=False)
        arrays[name] = a
    return cls(**others, **arrays)


# ---------------------------------------------------------------------------------------
# Process plumbing


def _context() -> Any:
    """Workers are spawned: forking a process that runs other threads (a GUI, a test runner,
    a logging handler) can deadlock the child."""
    return mp.get_context("spawn")


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (it unlinks shared memory a killed process leaves)
    with the stop signals held: it inherits them blocked, so a SIGHUP to the whole process group
    (a closed terminal) does not kill it before the build has cleaned up. It ignores SIGINT and
    SIGTERM itself, and ends when the last process using it has."""
    from multiprocessing import resource_tracker

    with signals_held():
        resource_tracker.ensure_running()


def _prctl(option: int, arg: int | bytes) -> bool:
    """Linux's prctl(2); False where there is none."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(option, arg, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _widen(conn: Connection) -> None:
    """Let a pipe hold more in flight than the default 64 kB (Linux's F_SETPIPE_SZ)."""
    try:
        import fcntl

        fcntl.fcntl(conn.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), _PIPE_BYTES)
    except (ImportError, OSError):
        pass


def _death(stage: str, exitcode: int | None) -> WorkerError:
    """The error for a worker that ended without its result."""
    if exitcode is None:
        return WorkerError(f"the {stage} worker stopped answering")
    if exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        why = {"SIGKILL": " (the kernel's out-of-memory killer sends it; is the machine short of memory?)",
               "SIGSEGV": " (it crashed in native code)", "SIGBUS": " (it crashed in native code)",
               "SIGABRT": " (it aborted)", "SIGILL": " (it crashed in native code)"}.get(name, "")
        return WorkerError(f"the {stage} worker was killed by {name}{why}")
    return WorkerError(f"the {stage} worker exited with code {exitcode} before it finished")


class _RemoteTraceback(Exception):
    """A worker's formatted traceback, shown as the cause of :class:`InternalError`."""

    def __init__(self, tb: str) -> None:
        super().__init__(tb)
        self.tb = tb

    def __str__(self) -> str:
        return f"\n\n(in the worker process)\n{self.tb}"


def _raise_reported(stage: str, kind: str, name: str, message: str, tb: str) -> None:
    """Raise what a worker reported (``("error", kind, name, message, tb)``)."""
    from . import errors

    if kind == "user":
        cls = getattr(errors, name, None)
        raise (cls if isinstance(cls, type) and issubclass(cls, SemmapError) else SemmapError)(message)
    if kind == "memory":
        raise WorkerError(f"the {stage} worker ran out of memory{': ' + message if message else ''}")
    exc = InternalError(f"in the {stage} worker: {name}: {message}")
    raise exc from _RemoteTraceback(tb)


class _PipeLogHandler(logging.Handler):
    """In a worker: log records travel to the caller, which logs them (with the caller's handlers)."""

    def __init__(self, conn: Connection, process: str) -> None:
        super().__init__()
        self._conn = conn
        self._process = process

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.exc_info:
                text += "\n" + "".join(traceback.format_exception(*record.exc_info)).rstrip()
            self._conn.send(("log", record.name, record.levelno, text, self._process))
        except Exception:
            pass


def _emit(name: str, level: int, text: str, process: str) -> None:
    """In the caller: log a record a worker sent."""
    logger = logging.getLogger(name)
    if logger.isEnabledFor(level):
        logger.handle(logger.makeRecord(name, level, "(worker)", 0, text, (), None, extra={"worker": process}))


def _worker_main(process: str, stage: str, parent_pid: int, levels: dict[str, int], out: Connection,
                 body: Callable[..., None], *args: Any) -> None:
    """Every worker starts here: set the process up, run ``body(out, *args)``, report how it ended."""
    for sig in STOP_SIGNALS:  # Ctrl-C, a closed terminal, systemd reach the whole group: the parent stops us
        signal.signal(sig, signal.SIG_IGN)
    _prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG: die with the parent, however it ends
    if os.getppid() != parent_pid:  # the parent was already gone
        os._exit(0)
    _prctl(15, process.encode()[:15])  # PR_SET_NAME: ps, top and htop show the stage
    root = logging.getLogger()
    root.handlers[:] = [_PipeLogHandler(out, process)]
    for name, level in levels.items():
        logging.getLogger(name or None).setLevel(level)
    try:
        import cv2
        from threadpoolctl import threadpool_limits

        # workers share the machine's cores with each other: a library's own threads only take CPU
        # from the other stages (OpenBLAS's spin while they wait: in the loop closer's small products
        # they doubled the registration worker's CPU time)
        cv2.setNumThreads(1)
        threadpool_limits(1, user_api="blas")
        body(out, *args)
    except (BrokenPipeError, EOFError, ConnectionResetError):
        # the process at the other end of a pipe is gone: whoever waits on us learns why from it
        with contextlib.suppress(OSError):
            out.send(("error", "peer", "", "a pipe to another process closed", ""))
    except SemmapError as exc:
        with contextlib.suppress(OSError):
            out.send(("error", "user", type(exc).__name__, str(exc), ""))
    except MemoryError as exc:
        with contextlib.suppress(OSError):
            out.send(("error", "memory", "MemoryError", str(exc), ""))
    except BaseException as exc:
        with contextlib.suppress(OSError):
            out.send(("error", "bug", type(exc).__name__, str(exc), traceback.format_exc()))
    finally:
        out.close()


@dataclass
class _Worker:
    stage: str  # "images", "registration", "fusion": the stage errors name
    proc: Any
    inbox: Connection  # what the worker sends the caller
    error: tuple[str, str, str, str] | None = None  # what it reported, if it failed
    closed: bool = False  # it closed its end: it has ended or is ending
    finished: bool = False  # its last message arrived: it is ending on its own
    results: list[Any] = field(default_factory=list)  # messages that arrived while checking on it

    def take(self) -> None:
        """Read one message (the caller knows one is there): a log record is logged, an error report
        raises, end of file marks the worker closed, anything else waits in :attr:`results`."""
        try:
            msg = self.inbox.recv()
        except (EOFError, OSError):
            self.closed = True
            return
        if msg[0] == "log":
            _emit(*msg[1:])
        elif msg[0] == "large":  # the object follows at once, out of band
            try:
                self.results.append(("large", _recv_large(self.inbox, *msg[1:])))
            except (EOFError, OSError):
                self.closed = True
        elif msg[0] == "error":
            self.error = msg[1:]
            if msg[1] != "peer":
                _raise_reported(self.stage, *msg[1:])
            raise _PeerGone
        else:
            self.results.append(msg)

    def poll(self) -> None:
        """Take whatever the worker has sent so far, without waiting."""
        while not self.closed and self.inbox.poll():
            self.take()

    def failed(self) -> bool:
        """It reported an error of its own, or ended without its result."""
        if self.error is not None:
            return self.error[0] != "peer"
        if self.closed:
            self.proc.join(0.5)
        return not self.proc.is_alive() and self.proc.exitcode != 0


class _PeerGone(Exception):
    """A pipe to a worker closed, or a worker ended: :meth:`_Workers.failure` says which and why."""


class _Workers:
    """Worker processes started together and stopped together."""

    def __init__(self) -> None:
        self._ctx = _context()
        self.workers: list[_Worker] = []
        self._child_ends: list[Connection] = []  # pipe ends the workers hold: closed here once they start
        self._own: list[Connection] = []

    def pipe(self, to_child: bool | None, wide: bool = False) -> tuple[Connection, Connection]:
        """A one-way pipe ``(reader, writer)``. ``to_child``: this process writes (True), reads (False),
        or neither (None: between two workers)."""
        reader, writer = self._ctx.Pipe(duplex=False)
        if wide:
            _widen(writer)
        self._child_ends += [reader] if to_child else [writer] if to_child is False else [reader, writer]
        self._own += [writer] if to_child else [reader] if to_child is False else []
        return reader, writer

    def add(self, process: str, stage: str, body: Callable[..., None], *args: Any) -> _Worker:
        inbox, out = self.pipe(to_child=False)
        levels = {name: logging.getLogger(name or None).getEffectiveLevel() for name in ("", "semmap")}
        proc = self._ctx.Process(target=_worker_main, name=process, daemon=True,
                                 args=(process, stage, os.getpid(), levels, out, body, *args))
        w = _Worker(stage, proc, inbox)
        self.workers.append(w)
        return w

    def start(self) -> None:
        """Start the workers without making them re-import the caller's main script.

        multiprocessing's spawn re-runs the ``__main__`` module in every child, so a script that
        calls :func:`semmap.build` at top level, without an ``if __name__ == "__main__":`` guard,
        would build again inside each worker. The workers need nothing from ``__main__``: it is
        hidden while they start.
        """
        _start_resource_tracker()
        main = sys.modules.get("__main__")
        sys.modules["__main__"] = types.ModuleType("__main__")
        try:
            # a child inherits the signal mask: held here, the stop signals stay blocked in the workers from
            # their first instruction (a Ctrl-C during their imports would print a KeyboardInterrupt
            # traceback), and one that reaches this process meanwhile is delivered when they have started
            with signals_held():
                for w in self.workers:
                    w.proc.start()
        finally:
            if main is not None:
                sys.modules["__main__"] = main
            for c in self._child_ends:  # only the worker holds its end now
                c.close()
            self._child_ends.clear()

    def check(self) -> None:
        """Raise if a worker has failed; take their log records meanwhile."""
        for w in self.workers:
            try:
                w.poll()
            except _PeerGone:
                raise self.failure() from None
            if w.failed():
                raise self.failure()

    def failure(self) -> SemmapError | InternalError:
        """Why the workers failed: the first worker in the chain that reported an error or ended
        without its result, not those that only saw their pipe to it close. Waits a moment for
        the workers' reports."""
        deadline = time.monotonic() + _REPORT_S
        while True:
            for w in self.workers:
                with contextlib.suppress(_PeerGone, SemmapError, InternalError):
                    w.poll()
            culprit = next((w for w in self.workers if w.failed()), None)
            left = deadline - time.monotonic()
            if culprit is not None or left <= 0 or not any(w.proc.is_alive() for w in self.workers):
                break
            wait([x for w in self.workers if not w.closed for x in (w.inbox, w.proc.sentinel)] or
                 [w.proc.sentinel for w in self.workers], min(left, 0.1))
        if culprit is None:
            culprit = next((w for w in self.workers if w.error is None and not w.proc.is_alive()), self.workers[0])
        if culprit.error is not None and culprit.error[0] != "peer":
            try:
                _raise_reported(culprit.stage, *culprit.error)
            except (SemmapError, InternalError) as exc:
                return exc
        return _death(culprit.stage, culprit.proc.exitcode)

    def recv(self, w: _Worker) -> Any:
        """``w``'s next message. While waiting for it, the other workers' log records are taken too,
        so that none of them blocks on a full pipe while the caller waits for ``w``."""
        try:
            while not w.results:
                if w.closed:
                    raise _PeerGone
                ready = wait([x.inbox for x in self.workers if not x.closed] + [w.proc.sentinel])
                for x in self.workers:
                    if not x.closed and x.inbox in ready:
                        x.take()
                if w.proc.sentinel in ready and not w.results and (w.closed or not w.inbox.poll()):
                    raise _PeerGone
        except _PeerGone:
            raise self.failure() from None
        return w.results.pop(0)

    def close(self) -> None:
        """Stop every worker and close every pipe; SIGINT and SIGTERM wait until this is done.
        A worker that sent its last message gets a moment to end on its own (its interpreter's exit
        handlers run: a profiler, coverage); any other holds nothing that needs its own clean-up,
        so it is killed, not asked."""
        with signals_held():
            deadline = time.monotonic() + _EXIT_S
            for w in self.workers:
                if w.finished and w.proc.pid is not None:
                    w.proc.join(max(0.0, deadline - time.monotonic()))
            for w in self.workers:
                if w.proc.pid is not None and w.proc.is_alive():
                    w.proc.kill()
            for w in self.workers:
                if w.proc.pid is not None:
                    w.proc.join()
            for c in [*self._own, *self._child_ends]:
                c.close()


# ---------------------------------------------------------------------------------------
# Frames: decoding and segmentation

def _images_body(out: Connection, freed: Connection, bag: str, topic: str, seg_cfg: dict[str, Any],
                 shm_name: str | None, shape: tuple[int, int] | None, odometry: OdometrySource | None,
                 need: NeedContext | None) -> None:
    """The image worker: segment the images of ``topic`` the selection takes; labels (and the backend's
    instances) go into free shared-memory slots (the caller hands each back on ``freed``), or through the
    pipe when none is free; a skipped frame is its stamp."""
    from multiprocessing import shared_memory

    counts: dict[str, Any] = {"images": 0, "skipped_frames": 0, "bad_images": 0, "segment_ms": 0}
    shm = shared_memory.SharedMemory(name=shm_name) if shm_name else None
    images: ImageReader | None = None
    try:
        slots = None
        free: list[int] = []
        if shm is not None and shape is not None:
            n = shm.size // (2 * shape[0] * shape[1] * 2)  # the size may be rounded up to whole pages
            slots = np.ndarray((n, 2, *shape), np.uint16, buffer=shm.buf)  # per slot: label, instance
            free = list(range(n))
        cfg = segmentation_config(seg_cfg)
        images = ImageReader(Path(bag), topic, cfg, counts, make_selector(cfg, odometry, need))
        out.send(("ready",))
        cpu0 = time.process_time()
        for seg in images:
            if isinstance(seg, SkippedFrame):
                out.send(("skipped", seg.stamp_ns))
                continue
            while freed.poll():  # EOF here (the caller is gone) raises EOFError
                free.append(freed.recv())
            has_instance = seg.instance is not None
            if slots is not None and seg.label.shape == slots.shape[2:] and free:
                i = free.pop()
                slots[i, 0] = seg.label
                if seg.instance is not None:
                    slots[i, 1] = seg.instance
                out.send(("slot", seg.stamp_ns, i, seg.names, has_instance))
            else:  # no free slot (the caller holds them all), or an image of another size: send it whole
                out.send(("image", seg.stamp_ns, np.ascontiguousarray(seg.label), seg.names,
                          None if seg.instance is None else np.ascontiguousarray(seg.instance)))
        counts["peak_rss_mb"] = round(peak_rss_mb(), 1)
        counts["cpu_s"] = round(time.process_time() - cpu0, 3)
        out.send(("done", counts))
    finally:
        if images is not None:
            images.close()
        if shm is not None:
            del slots
            shm.close()


class ImageWorker:
    """Segmentations of a camera topic from a worker process.

    Label images travel through shared memory: a pool of ``n_slots`` image slots, each handed
    back to the worker when the mapper no longer needs that image (:meth:`release`), so nothing
    large is copied between processes. When the caller holds every slot, the worker sends the
    next label through the pipe instead of waiting (a fast camera never deadlocks the two); the
    pipe's capacity bounds how far it runs ahead.
    """

    def __init__(self, bag: Path, topic: str, seg_cfg: SegmentationConfig,
                 shape: tuple[int, int] | None = None, n_slots: int = 12,
                 odometry: OdometrySource | None = None, need: NeedContext | None = None) -> None:
        from multiprocessing import shared_memory

        self.counts: dict[str, Any] = {"images": 0, "skipped_frames": 0, "bad_images": 0, "segment_ms": 0}
        self._done = False
        self._slot_of: dict[int, int] = {}
        self._shm = None
        self._slots: NDArray[np.uint16] | None = None
        self._group = _Workers()
        try:
            if shape is not None:
                _start_resource_tracker()
                self._shm = shared_memory.SharedMemory(create=True, size=n_slots * 2 * shape[0] * shape[1] * 2)
                self._slots = np.ndarray((n_slots, 2, *shape), np.uint16, buffer=self._shm.buf)
            freed_r, self._freed = self._group.pipe(to_child=True)
            self._worker = self._group.add("semmap-images", "images", _images_body, freed_r, str(bag), topic,
                                           seg_cfg.model_dump(mode="json"), self._shm.name if self._shm else None,
                                           shape, odometry, need)
            self._group.start()
        except BaseException:
            self.close()
            raise

    def wait_ready(self) -> None:
        """Block until the worker has loaded its segmenter (so start-up is not counted as work)."""
        msg = self._group.recv(self._worker)
        if msg[0] != "ready":
            raise InternalError(f"the images worker sent {msg[0]!r} before 'ready'")

    def next(self) -> Segmentation | SkippedFrame | None:
        if self._done:
            return None
        msg = self._group.recv(self._worker)
        if msg[0] == "slot":
            _, stamp, i, names, has_instance = msg
            assert self._slots is not None
            # read-only views, no copy
            seg = Segmentation(stamp, self._slots[i, 0], names, instance=self._slots[i, 1] if has_instance else None)
            self._slot_of[id(seg)] = i
            return seg
        if msg[0] == "skipped":
            return SkippedFrame(msg[1])
        if msg[0] == "image":
            _, stamp, label, names, instance = msg
            return Segmentation(stamp, label, names, instance=instance)
        if msg[0] == "done":
            self.counts = msg[1]
            self._done = self._worker.finished = True
            return None
        raise InternalError(f"the images worker sent {msg[0]!r}")

    def release(self, seg: Segmentation | SkippedFrame) -> None:
        """The mapper is done with ``seg``: its slot may be reused."""
        i = self._slot_of.pop(id(seg), None)
        if i is not None:
            with contextlib.suppress(OSError):  # the worker is gone; the next read says why
                self._freed.send(i)

    def close(self) -> None:
        with signals_held():
            self._group.close()
            self._slot_of.clear()
            self._slots = None
            if self._shm is not None:
                with contextlib.suppress(BufferError):  # segmentations still held are views of it
                    self._shm.close()
                self._shm.unlink()
                self._shm = None


# ---------------------------------------------------------------------------------------
# Mapping: registration, then fusion


@dataclass(frozen=True)
class MapperResult:
    """What the mapping stages return at the end of a tour."""

    poses: NDArray[np.float64]  # (N, 3) base_link in the map frame, one per pushed scan
    layers: GridLayers
    registration: dict[str, Any]  # Registrar.stats
    register_busy_s: float
    fuse_busy_s: float
    peak_rss_mb: dict[str, float] = field(default_factory=dict)  # per worker process
    cpu_s: dict[str, float] = field(default_factory=dict)  # CPU time of each worker process after start-up
    #: a sample of the returns, in their scans' base frames (M, 2), and their scan numbers (M,)
    #: (:class:`~semmap.grid.consistency.EndpointSample`)
    endpoints: tuple[NDArray[np.float32], NDArray[np.int64]] | None = None
    #: returns of scans paired with a skipped frame that took a structure or furniture label
    #: (:class:`~semmap.paint.painter.LabelTransfer`)
    returns_labelled: int = 0


class Mapper(Protocol):
    """Registration and fusion: painted scans in, poses and grid layers out."""

    def wait_ready(self) -> None:
        """Block until the stages have loaded their libraries."""

    def push(self, painted: PaintedScan, odom_pose: NDArray[np.float64] | None) -> None:
        """Register and fuse one painted scan (with the odometry pose at its stamp, if any)."""

    def finish(self) -> MapperResult:
        """Every scan pushed so far registered and fused: the trajectory and the grid."""

    def close(self) -> None:
        """Stop, and free what was held."""


class InProcessMapper:
    """Registration and fusion in this process. ``transfer``: scans paired with a skipped frame take the
    structure and furniture labels of the segmented frames, through the registered poses
    (:class:`~semmap.paint.painter.LabelTransfer`)."""

    def __init__(self, reg_cfg: RegistrationConfig, grid_cfg: GridConfig, class_names: tuple[str, ...],
                 transfer: bool = False) -> None:
        from .grid import SemanticGrid
        from .grid.consistency import EndpointSample
        from .register import Registrar

        self._registrar = Registrar(reg_cfg)
        self._grid = SemanticGrid(grid_cfg, class_names)
        self._grid_args = (grid_cfg, class_names)
        self._sample = EndpointSample()
        self._refuse = _Refusion(reg_cfg, grid_cfg.resolution if transfer else None)
        self._poses = array("d")
        self._busy = [0.0, 0.0]

    def wait_ready(self) -> None:
        pass

    def push(self, painted: PaintedScan, odom_pose: NDArray[np.float64] | None) -> None:
        t0 = time.perf_counter()
        pose = self._registrar.register(painted, odom_pose)
        t1 = time.perf_counter()
        self._refuse.add(self._grid, pose, painted)
        self._sample.add(len(self._poses) // 3, painted)
        self._busy[0] += t1 - t0
        self._busy[1] += time.perf_counter() - t1
        self._poses.extend(pose.tolist())

    def finish(self) -> MapperResult:
        from .grid import SemanticGrid

        poses = _pose_array(self._poses)
        t0 = time.perf_counter()
        final = self._registrar.close_loops()
        t1 = time.perf_counter()
        grid = self._refuse.fuse_at_end(poses, final, lambda: SemanticGrid(*self._grid_args)) or self._grid
        self._busy[0] += t1 - t0
        self._busy[1] += time.perf_counter() - t1
        return MapperResult(poses if final is None else final, grid.layers(), self._registrar.stats, self._busy[0],
                            self._busy[1], endpoints=self._sample.base_points,
                            returns_labelled=self._refuse.returns_labelled)

    def close(self) -> None:
        self._refuse.close()


class _Refusion:
    """With loop closure: the painted scans, spooled to disk, fused once at the end from the poses
    loop closure corrected. Fusing them as they come as well would cost a second fusion of the
    whole tour, and CPU the painter and the registration need while the tour plays (2 cores)."""

    def __init__(self, reg_cfg: RegistrationConfig, transfer_cell: float | None = None) -> None:
        from .grid.spool import ScanSpool
        from .paint.painter import LabelTransfer

        self._spool = ScanSpool() if reg_cfg.loop_closure.enabled else None
        #: the labels of scans paired with a skipped frame, passed on at the poses the scans are fused at
        self.transfer = None if transfer_cell is None else LabelTransfer(transfer_cell)

    @property
    def returns_labelled(self) -> int:
        return 0 if self.transfer is None else self.transfer.returns_labelled

    def _labelled(self, pose: NDArray[np.float64], painted: PaintedScan) -> PaintedScan:
        return painted if self.transfer is None else self.transfer.apply(pose, painted)

    def add(self, grid: Any, pose: NDArray[np.float64], painted: PaintedScan) -> None:
        """Fuse the scan into ``grid`` now, or, with loop closure, keep it for :meth:`fuse_at_end`."""
        if self._spool is not None:
            self._spool.append(painted)
        else:
            grid.integrate(pose, self._labelled(pose, painted))

    def fuse_at_end(self, poses: NDArray[np.float64], final: NDArray[np.float64] | None,
                    new_grid: Callable[[], Any], hand_off: Callable[[NDArray[np.float64], Any], int] | None = None
                    ) -> Any:
        """The grid fused from the ``final`` poses (the registered ``poses`` when loop closure gave
        none); None when scans are not deferred.

        ``hand_off(poses, grid)``, once the first scan is fused (the grid's lattice is set), may hand
        the tour's later scans to another process: it returns the scan to stop before, and the grid
        returned holds the scans before it (see :func:`~semmap.grid.fusion.merge_continued`)."""
        if self._spool is None:
            return None
        use = final if final is not None and final.shape == poses.shape else poses
        if len(self._spool) != len(use):
            raise InternalError(f"fusion: {len(self._spool)} scans kept for {len(use)} poses")
        grid = new_grid()
        stop = len(use)
        if stop == 0 and hand_off is not None:
            hand_off(use, grid)  # nothing to hand over, but the other process waits to hear it
        for i, (pose, painted) in enumerate(zip(use, self._spool)):
            if i == stop:
                break
            grid.integrate(pose, self._labelled(pose, painted))
            if i == 0 and hand_off is not None:
                stop = hand_off(use, grid)
        return grid

    def close(self) -> None:
        if self._spool is not None:
            self._spool.close()


def _pose_array(poses: array) -> NDArray[np.float64]:
    return np.frombuffer(poses, np.float64).reshape(-1, 3).copy() if poses else np.zeros((0, 3))


def _registration_body(out: Connection, inbox: Connection, to_fusion: Connection, cfg: dict[str, Any]) -> None:
    from .register import Registrar

    # loop closure's search runs in the fusion worker (see _fusion_body): each scan's keyframe record,
    # made here, goes there with it
    registrar = Registrar(RegistrationConfig.model_validate(cfg), close_loops_here=False)
    out.send(("ready",))
    cpu0 = time.process_time()
    poses = array("d")  # x, y, yaw per scan: 24 bytes a scan
    busy = 0.0
    while (batch := inbox.recv()) is not None:
        t0 = time.perf_counter()
        done = []
        for painted, odom_pose, prepared in batch:
            pose = registrar.register(painted, odom_pose, prepared)
            poses.extend(pose.tolist())
            done.append((pose, painted, registrar.loop_record))
        busy += time.perf_counter() - t0
        to_fusion.send(done)
    to_fusion.send(None)
    out.send(("poses", _pose_array(poses), registrar.stats, busy, peak_rss_mb(), time.process_time() - cpu0))


def _fusion_body(out: Connection, inbox: Connection, cfg: dict[str, Any], class_names: tuple[str, ...],
                 reg_cfg: dict[str, Any], transfer_cell: float | None) -> None:
    registration = RegistrationConfig.model_validate(reg_cfg)
    # fusion may fall behind (its pipe is bounded); registration is the critical path. Not so with loop
    # closure, whose search runs here: then this worker is the critical path
    if not registration.loop_closure.enabled:
        with contextlib.suppress(OSError):
            os.nice(5)
    from .grid import SemanticGrid
    from .grid.consistency import EndpointSample
    from .register.registrar import loop_closer, solve_loops

    grid_cfg = GridConfig.model_validate(cfg)
    grid = SemanticGrid(grid_cfg, class_names)
    sample = EndpointSample()
    refuse = _Refusion(registration, transfer_cell)
    # with loop closure, fusion waits for the end of the tour (the scans are spooled), so this worker has
    # the time to close the loops: their search stays off the registration's critical path
    closer = loop_closer(registration)
    out.send(("ready",))
    cpu0 = time.process_time()
    busy = loops_s = 0.0
    poses = array("d")
    final = loop_stats = None
    try:
        while (batch := inbox.recv()) is not None:
            t0 = time.perf_counter()
            for pose, painted, loop_record in batch:
                refuse.add(grid, pose, painted)
                sample.add(len(poses) // 3, painted)
                if closer is not None and loop_record is not None:
                    t1 = time.perf_counter()
                    closer.add_record(loop_record)
                    loops_s += time.perf_counter() - t1
                poses.extend(np.asarray(pose, np.float64).tolist())
            busy += time.perf_counter() - t0
        t0 = time.perf_counter()
        if closer is not None:
            final, loop_stats = solve_loops(closer)  # the poses loop closure corrected
            loops_s += time.perf_counter() - t0

        def hand_off(use: NDArray[np.float64], head: SemanticGrid) -> int:
            # the calling process fuses the tour's later scans meanwhile (it spooled them too), on this
            # grid's lattice: two cores for the fusion the build waits for
            split = tail_split(len(use))
            out.send(("tail", use, split, head.lattice))
            return split

        grid = refuse.fuse_at_end(_pose_array(poses), final, lambda: SemanticGrid(grid_cfg, class_names),
                                  hand_off if closer is not None else None) or grid
        busy += time.perf_counter() - t0
    finally:
        refuse.close()
    cpu = time.process_time() - cpu0
    _send_large(out, grid.layers())
    out.send(("endpoints", *sample.base_points))
    # the peak includes taking the layers out
    out.send(("fused", busy - loops_s, peak_rss_mb(), cpu, final, loop_stats, loops_s, refuse.returns_labelled))


#: share of the tour's scans the fusion worker fuses at the end of a tour with loop closure; the calling
#: process fuses the rest, and merges (a build's -vv log says how long each side waited for the other)
HEAD_SHARE = 0.5


def tail_split(n: int) -> int:
    """The first scan the calling process fuses at the end of a tour of ``n`` scans with loop closure."""
    from .grid.fusion import MAX_CONTINUED_SCANS

    if n < 2:
        return n
    return min(n, max(1, round(n * HEAD_SHARE), n - MAX_CONTINUED_SCANS))


class MapperWorkers:
    """Registration and fusion in two chained worker processes; scans travel in small batches.

    Painting stays in the calling process, registration runs one batch behind it and fusion
    one batch behind registration, so the three share the machine's cores.
    """

    def __init__(self, reg_cfg: RegistrationConfig, grid_cfg: GridConfig, class_names: tuple[str, ...],
                 batch: int = 16, transfer: bool = False) -> None:
        self._transfer_cell = grid_cfg.resolution if transfer else None
        self._group = _Workers()
        try:
            scans_r, self._scans = self._group.pipe(to_child=True, wide=True)
            fuse_r, fuse_w = self._group.pipe(to_child=None, wide=True)
            self._reg = self._group.add("semmap-register", "registration", _registration_body, scans_r, fuse_w,
                                        reg_cfg.model_dump(mode="json"))
            self._fuse = self._group.add("semmap-fusion", "fusion", _fusion_body, fuse_r,
                                         grid_cfg.model_dump(mode="json"), tuple(class_names),
                                         reg_cfg.model_dump(mode="json"), self._transfer_cell)
            self._group.start()
        except BaseException:
            self._group.close()
            raise
        self._batch: list[tuple[Any, NDArray[np.float64] | None, Any]] = []
        self._batch_size = batch
        self._grid_args = (grid_cfg, tuple(class_names))
        # with loop closure the grid is fused at the end of the tour; this process fuses its later scans
        # while the fusion worker fuses the earlier ones (_fusion_body), so it keeps them too
        self._spool: Any = None
        if reg_cfg.loop_closure.enabled:
            from .grid.spool import ScanSpool

            self._spool = ScanSpool()
        # the stateless down-sampling runs here, beside the painter, to unload the registration worker
        # (in icp mode: no Kalman filter to build, so its libraries stay out of this process)
        from .register import Registrar

        self._preparer = Registrar(reg_cfg.model_copy(update={"mode": "icp", "loop_closure": LoopClosureConfig()})) \
            if reg_cfg.mode != "odometry" or reg_cfg.loop_closure.enabled else None

    def wait_ready(self) -> None:
        """Block until both workers have loaded their libraries (start-up is not counted as work)."""
        for w in (self._reg, self._fuse):
            msg = self._group.recv(w)
            if msg[0] != "ready":
                raise InternalError(f"the {w.stage} worker sent {msg[0]!r} before 'ready'")

    def _send(self, item: Any) -> None:
        try:
            self._scans.send(item)
        except (BrokenPipeError, ConnectionResetError):
            raise self._group.failure() from None
        self._group.check()

    def push(self, painted: PaintedScan, odom_pose: NDArray[np.float64] | None) -> None:
        self._batch.append((painted, odom_pose, None if self._preparer is None else self._preparer.prepare(painted)))
        if self._spool is not None:
            self._spool.append(painted)
        if len(self._batch) >= self._batch_size:
            self._send(self._batch)
            self._batch = []

    def finish(self) -> MapperResult:
        if self._batch:
            self._send(self._batch)
            self._batch = []
        self._send(None)
        _, poses, stats, reg_busy, reg_rss, reg_cpu = self._expect(self._reg, "poses", last=True)
        tail, tail_s, tail_labelled = None, 0.0, 0
        if self._spool is not None:
            t_wait = time.perf_counter()
            _, use, split, lattice = self._expect(self._fuse, "tail")
            t0 = time.perf_counter()
            tail, tail_labelled = self._fuse_tail(use, split, lattice)
            tail_s = time.perf_counter() - t0
            log.debug("fusion at the end: %.3f s waiting for the corrected poses, scans %d-%d fused here in "
                      "%.3f s", t0 - t_wait, split, len(use), tail_s)
        t_wait = time.perf_counter()
        _, layers = self._expect(self._fuse, "large")
        if tail is not None:
            from .grid.fusion import merge_continued

            t0 = time.perf_counter()
            layers = merge_continued(layers, tail)
            tail_s += time.perf_counter() - t0
            log.debug("fusion at the end: %.3f s waiting for the fusion worker's half, merged in %.3f s",
                      t0 - t_wait, time.perf_counter() - t0)
        _, xy, scan_of = self._expect(self._fuse, "endpoints")
        _, fuse_busy, fuse_rss, fuse_cpu, final, loop_stats, loops_s, labelled = self._expect(self._fuse, "fused",
                                                                                             last=True)
        if final is not None:  # loop closure, in the fusion worker: its time counts as registration's
            poses = final
            from .register.registrar import registration_speed

            reg_busy += loops_s
            stats = {**stats, "loop_closure": loop_stats,
                     **registration_speed(stats["scans"], stats["seconds"] + loops_s)}
        return MapperResult(poses, layers, stats, reg_busy, fuse_busy + tail_s,
                            {"registration": round(reg_rss, 1), "fusion": round(fuse_rss, 1)},
                            {"registration": round(reg_cpu, 3), "fusion": round(fuse_cpu, 3)}, (xy, scan_of),
                            labelled + tail_labelled)

    def _fuse_tail(self, poses: NDArray[np.float64], split: int, lattice: tuple[float, float] | None
                   ) -> tuple[Any, int]:
        """The grid of the scans from ``split`` on, continuing the fusion worker's (None: no scans left), and
        how many of their returns took a label from the segmented frames
        (:class:`~semmap.paint.painter.LabelTransfer`)."""
        from .grid import SemanticGrid

        if lattice is None or split >= len(poses):
            return None, 0
        if len(poses) != len(self._spool):
            raise InternalError(f"fusion: {len(self._spool)} scans kept here for {len(poses)} poses")
        tail = SemanticGrid.continuing(*self._grid_args, lattice, split)
        transfer = None
        if self._transfer_cell is not None:  # the votes of the scans the fusion worker fuses, cast here again
            from .paint.painter import LabelTransfer

            transfer = LabelTransfer(self._transfer_cell)
            for i, (pose, painted) in enumerate(zip(poses[:split], self._spool)):
                transfer.remember(pose, painted)
                if i % 256 == 255:
                    self._group.check()
        for i, (pose, painted) in enumerate(zip(poses[split:], self._spool.iter_from(split))):
            tail.integrate(pose, painted if transfer is None else transfer.apply(pose, painted))
            if i % 64 == 63:
                self._group.check()  # a worker that died meanwhile is reported now, not after this half
        return tail, 0 if transfer is None else transfer.returns_labelled

    def _expect(self, w: _Worker, tag: str, last: bool = False) -> Any:
        msg = self._group.recv(w)
        if msg[0] != tag:
            raise InternalError(f"the {w.stage} worker sent {msg[0]!r}, not {tag!r}")
        w.finished = last
        return msg

    def close(self) -> None:
        try:
            self._group.close()
        finally:
            if self._spool is not None:
                self._spool.close()
