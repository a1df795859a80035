"""Painted scans kept on disk, to be fused again after loop closure has corrected their poses.

The spool is an anonymous temporary file (unlinked when created, so nothing is left behind however
the process ends); memory holds only an offset per scan. Points are stored as float32 (20 m from the
robot that is a few micrometres), labels as they are.
"""

from __future__ import annotations

import tempfile
from array import array
from collections.abc import Iterator
from typing import BinaryIO

import numpy as np

from ..records import PaintedScan

__all__ = ["ScanSpool"]

_HEAD = np.dtype([("stamp_ns", "<i8"), ("n", "<i8"), ("ox", "<f8"), ("oy", "<f8"), ("instances", "<i8"),
                  ("frame_ns", "<i8"), ("flags", "<i8")])  # flags: 1 a paired frame, 2 segmented, 4 in_view kept


class ScanSpool:
    """Append :class:`~semmap.records.PaintedScan` records; read them back in order."""

    def __init__(self) -> None:
        self._file: BinaryIO = tempfile.TemporaryFile(prefix="semmap-spool-")  # noqa: SIM115 (closed in close())
        self._count = 0
        self._offsets = array("q")  # where each scan's record starts
        self._class_names: tuple[str, ...] = ()
        self._frame_id = ""
        self.nbytes = 0

    def __len__(self) -> int:
        return self._count

    def append(self, scan: PaintedScan) -> None:
        n = scan.points.shape[0]
        inst = scan.instance
        flags = (scan.frame_ns is not None) | 2 * scan.segmented | 4 * (scan.in_view is not None)
        head = np.array([(scan.stamp_ns, n, scan.origin[0], scan.origin[1], 0 if inst is None else 1,
                          scan.frame_ns or 0, flags)], _HEAD)
        parts = [head.tobytes(), np.ascontiguousarray(scan.points, np.float32).tobytes(),
                 np.ascontiguousarray(scan.hit, np.bool_).tobytes(),
                 np.ascontiguousarray(scan.mobility, np.uint8).tobytes(),
                 np.ascontiguousarray(scan.class_id, np.int16).tobytes()]
        if inst is not None:
            parts.append(np.ascontiguousarray(inst, np.int32).tobytes())
        if scan.in_view is not None:
            parts.append(np.ascontiguousarray(scan.in_view, np.bool_).tobytes())
        self._offsets.append(self.nbytes)
        for p in parts:
            self._file.write(p)
            self.nbytes += len(p)
        self._class_names, self._frame_id = scan.class_names, scan.frame_id
        self._count += 1

    def __iter__(self) -> Iterator[PaintedScan]:
        return self.iter_from(0)

    def iter_from(self, start: int) -> Iterator[PaintedScan]:
        """The scans from the ``start``-th on, in order."""
        f = self._file
        f.flush()
        start = max(start, 0)
        if start >= self._count:
            return
        f.seek(self._offsets[start])
        for _ in range(start, self._count):
            head = np.frombuffer(f.read(_HEAD.itemsize), _HEAD)[0]
            n = int(head["n"])
            pts = np.frombuffer(f.read(8 * n), np.float32).reshape(n, 2).astype(np.float64)
            hit = np.frombuffer(f.read(n), np.bool_)
            mob = np.frombuffer(f.read(n), np.uint8)
            cls = np.frombuffer(f.read(2 * n), np.int16)
            inst = np.frombuffer(f.read(4 * n), np.int32) if int(head["instances"]) else None
            flags = int(head["flags"])
            view = np.frombuffer(f.read(n), np.bool_) if flags & 4 else None
            yield PaintedScan(stamp_ns=int(head["stamp_ns"]), origin=np.array([head["ox"], head["oy"]]), points=pts,
                              hit=hit, mobility=mob, class_id=cls, class_names=self._class_names,
                              frame_id=self._frame_id, instance=inst,
                              frame_ns=int(head["frame_ns"]) if flags & 1 else None, segmented=bool(flags & 2),
                              in_view=view)
        f.seek(0, 2)

    def close(self) -> None:
        self._file.close()
