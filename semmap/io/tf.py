"""A minimal transform tree for static transforms read from ``/tf_static`` (and ``/tf``), and
odometry carried by ``/tf``.

Looks up ``T_target_source`` through any chain of frames (``base_footprint → base_link
→ laser_mount → laser``), in either direction. :func:`find_tf_odometry` finds the moving
transform of a robot's odometry (``odom → base_footprint``) among those of ``/tf``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..errors import BagError
from ..geometry import se3_inverse, se3_to_se2

__all__ = ["TfOdometry", "TfTree", "find_tf_odometry"]

#: a frame whose name holds this is an odometry frame (``odom``, ``odom_combined``, ``wheel_odom``)
ODOM_HINT = "odom"
#: a frame whose name holds one of these is a global frame (a SLAM node's ``map``), never odometry
GLOBAL_HINTS = ("map", "world", "earth", "utm")


class TfTree:
    """Static transforms: each child has one parent, ``T_parent_child``."""

    def __init__(self) -> None:
        self._parent: dict[str, tuple[str, NDArray[np.float64]]] = {}
        self._path: list[str] = []

    def add(self, parent: str, child: str, t_parent_child: NDArray[np.float64]) -> None:
        self._parent[child] = (parent, np.asarray(t_parent_child, dtype=np.float64))

    def parent(self, frame: str) -> str | None:
        """The frame's parent (None: a root, or a frame the tree does not know)."""
        link = self._parent.get(frame)
        return link[0] if link is not None else None

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


@dataclass(frozen=True)
class TfOdometry:
    """Odometry carried by ``/tf``: the moving transform ``T_odom_child`` (``odom → base_footprint``),
    and the fixed chain ``T_child_base`` from its child to the robot's base frame (identity when the
    child is the base frame; else taken from ``/tf_static``, or the first messages of ``/tf``)."""

    topic: str
    odom_frame: str
    child_frame: str
    base_frame: str
    T_child_base: NDArray[np.float64] = field(default_factory=lambda: np.eye(4), repr=False, compare=False)
    #: the frames from the child down to the base frame (the child first), for messages
    chain: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        """How logs and the summary name it: ``/tf (odom -> base_footprint)``."""
        frames = [self.odom_frame, *(self.chain or (self.child_frame,))]
        return f"{self.topic} ({' -> '.join(frames)})"

    def poses(self, transforms: Iterable[tuple[int, str, str, NDArray[np.float64]]],
              ) -> Iterator[tuple[int, NDArray[np.float64]]]:
        """``(stamp, (x, y, yaw))`` of the base frame in the odometry frame, for each odometry transform
        among ``transforms`` (one ``/tf`` message's, :func:`~semmap.io.messages.transforms_from_msg`);
        the others are ignored. The stamp is the transform's header stamp."""
        for stamp, parent, child, t_odom_child in transforms:
            if child == self.child_frame and parent == self.odom_frame:
                yield stamp, se3_to_se2(t_odom_child @ self.T_child_base)


def _named_odom(frame: str) -> bool:
    return ODOM_HINT in frame.rsplit("/", 1)[-1].lower()


def _named_global(frame: str) -> bool:
    low = frame.rsplit("/", 1)[-1].lower()
    return any(h in low for h in GLOBAL_HINTS)


def find_tf_odometry(tree: TfTree, moving: Mapping[str, str], start: str, topic: str, base: str | None = None,
                     odom: str | None = None) -> TfOdometry | None:
    """The odometry that ``/tf`` carries, or None when it carries none.

    ``tree``: the transforms of ``/tf_static`` and the first messages of ``/tf``; ``moving``: the
    transforms seen on ``/tf`` (child → parent). ``start``: the frame whose chain of parents is
    searched, the base frame when it is known (``base``), else the LiDAR's frame. Among the
    transforms of that chain that come over ``/tf``, the odometry transform is the nearest to
    ``start`` whose parent is ``odom`` (the config's ``frames.odom``) when that is given; else whose
    parent is named like ``odom`` (``odom``, ``odom_combined``, ``robot1/odom``); else whose parent is
    not named like a global frame (``map``, ``world``: a SLAM node's pose is not odometry). When no
    transform of that chain comes over ``/tf`` and no base frame is given, the one transform of
    ``/tf`` from such a frame is taken (none if there are several). The base frame is ``base``, else
    the odometry transform's child.
    """
    chain = [start]
    while (p := tree.parent(chain[-1])) is not None and p not in chain:
        chain.append(p)
    links = [(chain[i + 1], chain[i], i) for i in range(len(chain) - 1) if moving.get(chain[i]) == chain[i + 1]]
    if not links and base is None:  # the start frame is not linked to the odometry: any one candidate
        links = [(p, c, 0) for c, p in sorted(moving.items())]
        if odom is None:
            named = [x for x in links if _named_odom(x[0])]
            links = named or [x for x in links if not _named_global(x[0])]
        else:
            links = [x for x in links if x[0] == odom]
        if len(links) != 1:
            return None
    if odom is not None:
        found = [x for x in links if x[0] == odom]
    else:
        found = [x for x in links if _named_odom(x[0])] or [x for x in links if not _named_global(x[0])]
    if not found:
        return None
    parent, child, k = found[0]
    base_frame = base or child
    below = tuple(reversed(chain[: k + 1])) if base is not None else (child,)
    t_child_base = tree.lookup(child, base_frame) if base_frame != child else np.eye(4)
    return TfOdometry(topic, parent, child, base_frame, t_child_base, below)
