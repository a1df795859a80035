"""One side of a diff: a map folder from ``semmap build``, or a plain map_server map from any tool.

A :class:`Session` holds what the comparison needs, in the map's own grid (row 0 = lowest y):
the occupancy as map_server loads it, and, for map folders, the semantic layers (cells flagged
movable, cells where people were seen) and the object list. A map from slam_toolbox, Cartographer
or any other tool (``map.yaml`` + image) has only the occupancy: the diff is geometric, and says so.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import cKDTree

from ..config import CleaningConfig
from ..errors import ConfigError, MapFolderError, SemmapError
from ..geometry import dilate_mask
from ..grid import SemiStaticObject
from ..grid.clean import group_objects
from ..io.mapserver import read_map
from ..io.yamlio import read_yaml
from ..records import GridSpec, Mobility

if TYPE_CHECKING:
    from ..mapfolder.reader import MapFolder

__all__ = ["FAINT_MIN_HITS", "FAINT_MIN_SHARE", "LEG_M", "Session", "distinct_names", "open_session", "people_cells"]

#: a cell the map calls free is a faint obstacle when at least this many beams ended in it, and this
#: share of the beams that reached it (a person walking through ends a beam or two among hundreds)
FAINT_MIN_HITS = 3
FAINT_MIN_SHARE = 0.1
#: a cell is bare floor when at least this many rays passed through it and no beam ended in it or beside it:
#: a thin leg that stood there would have caught some (a 4 cm leg in a 5 cm cell catches a beam in five)
BARE_MIN_PASSES = 20


@dataclass(frozen=True)
class Session:
    """A map to compare (grid order, every mask (H, W) bool)."""

    path: Path
    spec: GridSpec
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    #: occupied cells flagged movable (all False for a plain map)
    semi_static: NDArray[np.bool_]
    #: cells where people were seen: dynamic hits, or cells cleaning dropped as dynamic
    dynamic: NDArray[np.bool_]
    objects: tuple[SemiStaticObject, ...]
    #: True for a semmap map folder; False for a plain map_server map (geometry only)
    semantic: bool
    #: the map's yaw in its YAML (map_server's third ``origin`` value); 0 for semmap's maps
    yaw: float = 0.0
    #: cells not occupied whose LiDAR hits were outweighed by rays passing through them, but which
    #: were hit again and again (a thin chair leg in a cell, grazed by passing rays): something
    #: stood there. None for a plain map (no hit counts)
    faint: NDArray[np.bool_] | None = None
    #: per cell, the index in ``objects`` of the object that holds it (-1: none), as the build grouped
    #: them; None when it cannot be told (a plain map, or an object list that is not the build's)
    object_index: NDArray[np.int32] | None = None
    #: cells not occupied that beams ended in again and again however many passed (``FAINT_MIN_HITS``):
    #: too weak to call an obstacle, but no evidence that an object the other session saw there is gone.
    #: None for a plain map
    glimpsed: NDArray[np.bool_] | None = None
    #: occupied cells that fewer than ``FAINT_MIN_HITS`` returns ended in (a wall seen once, edge-on, from
    #: across a room): too little to call a change on alone. None for a plain map
    weak: NDArray[np.bool_] | None = None
    #: the name reports give the session (None: its folder's, see :attr:`name`)
    label: str | None = None
    #: cells the camera painted (any class: hits with a label): None for a plain map, whose cells no
    #: camera saw
    labelled: NDArray[np.bool_] | None = None
    #: bare floor: cells ``BARE_MIN_PASSES`` rays or more passed through with no return in them or their
    #: eight neighbours. Nothing stood there, not even a thin leg the map lost. None for a plain map
    bare: NDArray[np.bool_] | None = None

    @property
    def name(self) -> str:
        """The session's name in reports: its map folder's name (the YAML's folder for a plain map), or
        its ``label``."""
        if self.label is not None:
            return self.label
        return _base(self.path).name

    @property
    def observed(self) -> NDArray[np.bool_]:
        return self.occupied | self.free

    @property
    def static(self) -> NDArray[np.bool_]:
        """Obstacles that are structure: occupied, not movable."""
        return self.occupied & ~self.semi_static


def _base(path: Path) -> Path:
    """The folder that names a session: the map folder, or the folder of a plain map's YAML."""
    return path if path.name not in ("map.yaml", "") else path.parent


def distinct_names(sessions: Sequence[Session]) -> tuple[Session, ...]:
    """The sessions, labelled so that no two share a name: sessions whose folders have one name
    (``site1/fused`` and ``site2/fused``) are named by as many parent folders as tell them apart."""
    out = list(sessions)
    names = [s.name for s in out]
    if len(set(names)) == len(names):
        return tuple(out)
    parts = [_base(s.path.absolute()).parts for s in out]
    cand = names
    for depth in range(2, max(len(p) for p in parts) + 1):
        cand = [Path(*p[-depth:]).as_posix() for p in parts]  # (a path from the root keeps one slash)
        if len(set(cand)) == len(cand):
            break
    return tuple(dataclasses.replace(s, label=c) if c != n else s for s, c, n in zip(out, cand, names))


def people_cells(occupied: NDArray[np.bool_], dropped: NDArray[np.bool_], person_hits: NDArray[np.integer],
                 labelled_hits: NDArray[np.integer], resolution: float = 0.05) -> NDArray[np.bool_]:
    """Where a map saw people: cells cleaning ``dropped`` as dynamic, and cells a good share (30 %)
    of whose camera-labelled hits were people (a person cleaning left in; a stray person label on a
    chair leg is not enough). A dropped cell no camera labelled a person is none when it lies in a gap
    of a surface (obstacles on two opposite sides) or in a line of such cells one cell thick: beams
    grazing a face seen obliquely pass some of its cells now and then, and cleaning drops them as
    "seen through"; a person's leg is two or three cells across. Nor is one in a piece of one or two
    such cells beside a kept surface (its fringe), a surface being longer than a leg is wide: beside a
    kept blob no wider than a leg they are a person's leg the cleaning kept part of."""
    person = np.asarray(person_hits, np.float32)
    unlabelled = dropped & (person == 0)
    lab, n = ndimage.label(unlabelled, structure=np.ones((3, 3), bool))  # its pieces, 8-connected
    fringe = _fringe(occupied, unlabelled, lab, n, min_extent=LEG_M / resolution)
    faces = (_surface_gaps(occupied) | _lines(unlabelled, lab, n) | fringe) & unlabelled
    return (dropped & ~faces) | ((person > 0) & (person >= 0.3 * np.asarray(labelled_hits, np.float32)))


#: a person's leg is at most this wide (m): a kept blob no larger has no fringe of its own
LEG_M = 0.2


def _fringe(occupied: NDArray[np.bool_], cells: NDArray[np.bool_], lab: NDArray[np.int32], n: int,
            max_cells: int = 2, min_surface: int = 5, min_extent: float = 0.0) -> NDArray[np.bool_]:
    """The pieces of ``cells`` (``lab``: their ``n`` 8-connected labels) of at most ``max_cells`` cells
    touching a kept obstacle of ``min_surface`` cells or more that spans more than ``min_extent``
    cells: the fringe of a surface whose beam ends scatter by a cell, seen through now and then. A
    person who walked away leaves the whole leg dropped, two or three cells across, and nothing kept
    beside it; one who stood still may leave part of a leg kept, no wider than a leg."""
    if n == 0:
        return np.zeros_like(cells)
    small = np.bincount(lab.ravel(), minlength=n + 1) <= max_cells
    small[0] = False
    olab, m = ndimage.label(occupied, structure=np.ones((3, 3), bool))
    big = np.bincount(olab.ravel(), minlength=m + 1) >= min_surface
    if min_extent > 0:
        for k, sl in enumerate(ndimage.find_objects(olab), start=1):
            if big[k] and sl is not None and max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) <= min_extent:
                big[k] = False
    big[0] = False
    beside = ndimage.binary_dilation(big[olab], np.ones((3, 3), bool))
    touching = np.zeros(n + 1, bool)
    touching[np.unique(lab[beside & cells])] = True
    touching[0] = False
    return np.asarray((small & touching)[lab], bool)


def _surface_gaps(occupied: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Cells with obstacles on two opposite sides (left and right, above and below, or across a
    diagonal): a gap in a surface. Cleaning drops such a cell of a face seen obliquely as "seen
    through" (beams grazing the face pass it now and then); that is no person."""
    p = np.pad(occupied, 1)
    pairs = ((p[1:-1, :-2], p[1:-1, 2:]), (p[:-2, 1:-1], p[2:, 1:-1]), (p[:-2, :-2], p[2:, 2:]),
             (p[:-2, 2:], p[2:, :-2]))
    out = np.zeros_like(occupied)
    for u, v in pairs:
        out |= u & v
    return out


def _lines(cells: NDArray[np.bool_], lab: NDArray[np.int32], n: int) -> NDArray[np.bool_]:
    """The pieces of ``cells`` (``lab``: their ``n`` 8-connected labels) one cell thick (no 2 x 2
    block) and three cells long or more: a face carved by beams grazing it, not a person's leg (two
    or three cells across)."""
    if n == 0:
        return np.zeros_like(cells)
    block = ndimage.binary_erosion(cells, np.ones((2, 2), bool), border_value=0)  # a corner of a 2 x 2 block
    thick = np.zeros(n + 1, bool)
    thick[np.unique(lab[block])] = True
    out = np.zeros(n + 1, bool)
    for k, sl in enumerate(ndimage.find_objects(lab), start=1):
        if sl is not None and not thick[k] and max(sl[0].stop - sl[0].start, sl[1].stop - sl[1].start) >= 3:
            out[k] = True
    out[0] = False
    return np.asarray(out[lab], bool)


def _object_index(folder: Path, m: MapFolder) -> NDArray[np.int32] | None:
    """Which object holds each movable cell, by regrouping the cells as the build did (its cleaning
    settings from ``config.yaml``); None unless the regrouped objects are the listed ones, one for
    one (an object list edited by hand, or by another semmap)."""
    if not m.objects or not m.class_names:
        return None
    link = CleaningConfig().object_link_distance
    cfg_path = folder / "config.yaml"
    if cfg_path.is_file():
        try:
            cfg = read_yaml(cfg_path)
            link = float(cfg.get("cleaning", {}).get("object_link_distance", link))
        except (SemmapError, AttributeError, TypeError, ValueError):
            return None
    objs, index = group_objects(np.asarray(m.semi_static, bool), m.layers, m.class_names,
                                link / m.spec.resolution)
    if len(objs) != len(m.objects):
        return None
    # one for one by class and centroid, in any order: two objects whose centroids tie in y are
    # listed in the order the build's uncropped grid gave them, which the cropped one may not
    # (candidates from a tree of the listed centroids: a building may list thousands of objects)
    tol = 2e-3
    listed = np.array([b.centroid for b in m.objects], np.float64)
    near = cKDTree(listed).query_ball_point(np.array([a.centroid for a in objs], np.float64), tol * math.sqrt(2))
    place = np.full(len(objs) + 1, -1, np.int32)  # regrouped index -> listed index; [-1] stays -1
    taken = np.zeros(len(m.objects), bool)
    for k, a in enumerate(objs):
        for j in sorted(near[k]):
            b = m.objects[j]
            if not taken[j] and a.class_name == b.class_name and abs(a.centroid[0] - b.centroid[0]) <= tol \
                    and abs(a.centroid[1] - b.centroid[1]) <= tol:
                place[k], taken[j] = j, True
                break
        else:
            return None
    return place[index]


def open_session(path: str | Path) -> Session:
    """Open a map folder (a folder with ``summary.json``), a folder holding a ``map.yaml``, or a
    map_server ``*.yaml`` file. Errors are one line naming the path."""
    from ..mapfolder.reader import load_map_folder

    p = Path(path)
    if p.is_dir() and (p / "summary.json").is_file():
        m = load_map_folder(p)
        layers = m.layers
        mob = layers.mobility
        occupied = np.asarray(m.occupied, bool)
        labelled_hits = mob[Mobility.STATIC:].sum(axis=0)  # hits the camera gave a class, per cell
        dynamic = people_cells(occupied, np.asarray(m.cleaned.dynamic_removed, bool), mob[Mobility.DYNAMIC],
                               labelled_hits, m.spec.resolution)
        hits = layers.hits.astype(np.float32)
        seen = hits + layers.free.astype(np.float32)
        glimpsed = ~occupied & ~dynamic & (hits >= FAINT_MIN_HITS)
        faint = glimpsed & (hits >= FAINT_MIN_SHARE * np.maximum(seen, 1.0))
        bare = (layers.free >= BARE_MIN_PASSES) & ~dilate_mask(hits > 0, 1.5)
        semi = np.asarray(m.semi_static, bool)
        # a LiDAR-only map folder has no classes: its diff is geometric, as a plain map's
        return Session(p, m.spec, occupied, np.asarray(m.free, bool), semi, dynamic,
                       m.objects, bool(m.class_names), faint=faint,
                       object_index=_object_index(p, m), glimpsed=glimpsed,
                       weak=occupied & (hits < FAINT_MIN_HITS),
                       labelled=labelled_hits > 0, bare=bare)
    if p.is_dir():
        if not (p / "map.yaml").is_file():
            raise MapFolderError(f"{p}: neither a map folder (no summary.json) nor a folder with a map.yaml")
        p = p / "map.yaml"
    if not p.is_file():
        raise MapFolderError(f"{p}: no such map folder or map YAML")
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise MapFolderError(f"{p}: not a map_server YAML (expected a .yaml file or a map folder)")
    try:
        img = read_map(p)
    except SemmapError as exc:
        raise MapFolderError(str(exc)) from None
    if abs(img.yaw) > 1e-9:
        raise ConfigError(f"{p}: origin yaw {img.yaw:g} rad: semmap diff does not read maps with a rotated "
                          "origin yet (slam_toolbox, Cartographer and map_saver write yaw 0)")
    none = np.zeros(img.spec.shape, bool)
    return Session(p, img.spec, np.asarray(img.occupied, bool), np.asarray(img.free, bool), none, none.copy(), (),
                   False, img.yaw)
