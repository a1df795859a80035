"""A minimal transform tree for static transforms read from ``/tf_static`` (and ``/tf``).

Looks up ``T_target_source`` through any chain of frames (``base_footprint → base_link
→ laser_mount → laser``), in either direction.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import NDArray

from ..errors import BagError
from ..geometry import se3_inverse

__all__ = ["TfTree"]


class TfTree:
    """Static transforms: each child has one parent, ``T_parent_child``."""

    def __init__(self) -> None:
        self._parent: dict[str, tuple[str, NDArray[np.float64]]] = {}
        self._path: list[str] = []

    def add(self, parent: str, child: str, t_parent_child: NDArray[np.float64]) -> None:
        self._parent[child] = (parent, np.asarray(t_parent_child, dtype=np.float64))

    @property
    def frames(self) -> set[str]:
        return set(self._parent) | {p for p, _ in self._parent.values()}

    def __contains__(self, frame: str) -> bool:
        return frame in self.frames

    def chain(self, target: str, source: str) -> list[str]:
        """The frames from ``source`` to ``target`` (both included), for messages."""
        self.lookup(target, source)
        return self._path[:]

    def lookup(self, target: str, source: str) -> NDArray[np.float64]:
        """``T_target_source``: maps points in ``source`` into ``target``."""
        self._path = [source]
        if target == source:
            return np.eye(4)
        # breadth-first over the undirected tree
        edges: dict[str, list[tuple[str, NDArray[np.float64]]]] = {}
        for child, (parent, t) in self._parent.items():
            edges.setdefault(parent, []).append((child, t))  # parent -> child: T_parent_child
            edges.setdefault(child, []).append((parent, se3_inverse(t)))  # child -> parent
        best: dict[str, NDArray[np.float64]] = {source: np.eye(4)}  # T_frame_source
        came_from: dict[str, str] = {}
        queue = deque([source])
        while queue:
            f = queue.popleft()
            for nxt, t_f_nxt in edges.get(f, []):
                if nxt in best:
                    continue
                # T_nxt_source = inv(T_f_nxt) @ T_f_source
                best[nxt] = se3_inverse(t_f_nxt) @ best[f]
                came_from[nxt] = f
                if nxt == target:
                    path = [nxt]
                    while path[-1] != source:
                        path.append(came_from[path[-1]])
                    self._path = path[::-1]
                    return best[nxt]
                queue.append(nxt)
        known = ", ".join(sorted(self.frames)) or "none"
        raise BagError(f"no transform between frames {target!r} and {source!r} (frames in /tf_static: {known})")
