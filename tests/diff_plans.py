"""Synthetic floor plans drawn into occupancy maps at 5 cm, for `semmap diff`'s tests.

A :class:`Room` (or any plan of walls) is drawn in world coordinates and rendered into a map frame
whose pose in the world is known, as a session of ``semmap diff``: walls, furniture legs flagged
movable with their object list, people with dynamic evidence, floor observed free.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from semmap.compare import Session
from semmap.geometry import se2_apply, se2_inverse
from semmap.grid import SemiStaticObject
from semmap.records import GridSpec

RES = 0.05


class Room:
    """A drawing of one session in world coordinates, rendered into a map frame at ``T_world_map``."""

    def __init__(self, size=(10.0, 8.0), floor_margin=0.03):
        self.w, self.h = size
        #: free floor reaches this close to the room's walls
        self.floor_margin = floor_margin
        self.walls: list[tuple[float, float, float, float]] = [(0, 0, self.w, 0), (self.w, 0, self.w, self.h),
                                                              (self.w, self.h, 0, self.h), (0, self.h, 0, 0)]
        self.objects: list[tuple[str, tuple[float, float], tuple[float, float], float]] = []  # class, c, size, yaw
        #: which legs (indices 0-3) each object's entry in the object list holds; all when absent (a build
        #: may list a table's far legs as another object, or as none)
        self.listed_legs: dict[int, tuple[int, ...]] = {}
        #: legs (indices 0-3) of an object the session did not see: not drawn, their floor seen free
        #: (rays passing a thin leg carve it away)
        self.unseen_legs: dict[int, tuple[int, ...]] = {}
        self.people: list[tuple[float, float]] = []
        #: points cleaning took for people and dropped (dynamic evidence, no obstacle): a chair's legs
        self.dropped: list[tuple[float, float]] = []
        #: legs flagged movable that no object of the list holds (the nearest object within a metre
        #: takes them)
        self.loose_legs: list[tuple[float, float]] = []
        #: legs flagged movable that the build put in object k (by its place in ``objects``) though they
        #: are another thing's: a chair at a bed's foot grouped with the bed
        self.grouped_legs: dict[int, list[tuple[float, float]]] = {}
        #: legs the map lost to rays grazing past them but which beams hit again and again: free cells,
        #: faint obstacles
        self.faint_legs: list[tuple[float, float]] = []
        #: legs the map lost whose cells beams still ended in a few times among the many that passed
        #: (glimpsed, below the faint share)
        self.glimpsed_legs: list[tuple[float, float]] = []
        #: walls (segments) whose cells rest on one or two returns each: weak obstacles
        self.weak_walls: list[tuple[float, float, float, float]] = []
        self.unseen: list[tuple[float, float, float, float]] = []  # boxes the session did not observe
        #: how far off the heading of an object's box in the list is (rad; a box drawn around three legs
        #: of a table need not follow the table)
        self.box_yaw_error: dict[int, float] = {}
        #: the (length, width) the build gave object k's box in the list, when not its legs' (a box drawn
        #: round the chair its build grouped with it too)
        self.box_size: dict[int, tuple[float, float]] = {}
        #: whether the session knows which object holds each movable cell (a semmap map folder does:
        #: the diff regroups its cells as the build did)
        self.object_layer = True
        #: furniture the camera never labelled: its legs are static obstacles, in no object (class unused)
        self.unlabelled: list[tuple[str, tuple[float, float], tuple[float, float], float]] = []
        #: half the width of those legs (0: a single cell each, a table's thin legs)
        self.unlabelled_leg_half = 0.02
        #: half the width of the listed objects' legs (0: a single cell each)
        self.leg_half = 0.02
        #: round objects (a pot): class, centre, radius, and the bearing (rad, world) the session saw
        #: it from; drawn as the half of its rim facing that way, listed as an object
        self.round: list[tuple[str, tuple[float, float], float, float]] = []
        #: round things no camera labelled: centre, radius and the bearing seen from; static obstacles
        self.unlabelled_round: list[tuple[tuple[float, float], float, float]] = []
        #: faces of furniture the camera labelled (a couch's front seen from the room): class and the
        #: segment (x0, y0, x1, y1), listed as an object
        self.faces: list[tuple[str, tuple[float, float, float, float]]] = []

    def legs(self, c, size, yaw):
        """The four legs of a box object, world frame."""
        half = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * (np.array(size) / 2 - 0.03)
        cs, sn = math.cos(yaw), math.sin(yaw)
        return half @ np.array([[cs, sn], [-sn, cs]]) + np.array(c)

    def session(self, T_world_map, name="s") -> Session:
        """Render into the map frame whose pose in the world is ``T_world_map``."""
        t_map_world = se2_inverse(T_world_map)
        corners = se2_apply(t_map_world, np.array([[0, 0], [self.w, 0], [0, self.h], [self.w, self.h]]))
        spec = GridSpec.covering(*(corners.min(axis=0) - 0.5), *(corners.max(axis=0) + 0.5), RES)
        occ = np.zeros(spec.shape, bool)
        semi = np.zeros(spec.shape, bool)
        dyn = np.zeros(spec.shape, bool)

        def mark(points_world, *layers):
            rc = spec.world_to_cell(se2_apply(t_map_world, np.asarray(points_world, float).reshape(-1, 2)))
            ok = (rc[:, 0] >= 0) & (rc[:, 0] < spec.height) & (rc[:, 1] >= 0) & (rc[:, 1] < spec.width)
            for layer in layers:
                layer[rc[ok, 0], rc[ok, 1]] = True

        weak = np.zeros(spec.shape, bool)
        for walls, layers in ((self.walls, (occ,)), (self.weak_walls, (occ, weak))):
            for x0, y0, x1, y1 in walls:
                n = int(math.hypot(x1 - x0, y1 - y0) / (RES / 3)) + 2
                mark(np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)], axis=1), *layers)
        # the floor: every cell centre inside the room, in the world
        rows, cols = np.mgrid[0:spec.height, 0:spec.width]
        centres = np.stack([spec.origin_x + (cols.ravel() + 0.5) * RES, spec.origin_y + (rows.ravel() + 0.5) * RES],
                           axis=1)
        world = se2_apply(T_world_map, centres)
        m = self.floor_margin
        inside = ((world[:, 0] > m) & (world[:, 0] < self.w - m) & (world[:, 1] > m)
                  & (world[:, 1] < self.h - m)).reshape(spec.shape)
        for bx0, by0, bx1, by1 in self.unseen:
            inside &= ~((world[:, 0] >= bx0) & (world[:, 0] <= bx1) & (world[:, 1] >= by0)
                        & (world[:, 1] <= by1)).reshape(spec.shape)
        objs = []
        index = np.full(spec.shape, -1, np.int32)
        for k, (cls, c, size, yaw) in enumerate(self.objects):
            legs = self.legs(c, size, yaw)
            unseen = self.unseen_legs.get(k, ())
            listed_here = self.listed_legs.get(k, range(4))
            held = np.zeros(spec.shape, bool)
            for i, leg in enumerate(legs):  # a leg: a 4 cm square
                if i not in unseen:
                    lh = self.leg_half
                    square = leg + np.array([[dx, dy] for dx in (-lh, 0, lh) for dy in (-lh, 0, lh)])
                    mark(square, occ, semi)
                    if i in listed_here:
                        mark(square, held)
            for p in self.grouped_legs.get(k, ()):
                mark(np.array(p) + np.array([[dx, dy] for dx in (-0.02, 0, 0.02) for dy in (-0.02, 0, 0.02)]), occ,
                     semi, held)
            index[held] = k
            listed = [i for i in self.listed_legs.get(k, range(4)) if i not in unseen]
            if len(listed) == 4:
                cw = np.asarray(c, float)
                fp = se2_apply(t_map_world, self.legs(c, (size[0] + 0.06, size[1] + 0.06), yaw))
                dims = (max(size), min(size))
            else:  # the entry holds some legs only: its box is theirs
                seen = legs[listed]
                cw = seen.mean(axis=0)
                lo, hi = seen.min(axis=0) - 0.05, seen.max(axis=0) + 0.05
                fp = se2_apply(t_map_world, np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]]))
                dims = (float(max(hi - lo)), float(min(hi - lo)))
            cm = se2_apply(t_map_world, cw[None])[0]
            objs.append(SemiStaticObject(cls, (float(cm[0]), float(cm[1])), self.box_size.get(k, dims),
                                         float(yaw + self.box_yaw_error.get(k, 0.0) - T_world_map[2]), 16, 5,
                                         tuple(map(tuple, fp))))
        for cls, c, radius, seen_from in self.round:
            ang = seen_from + np.linspace(-math.pi / 2, math.pi / 2, 120)
            rim = np.asarray(c, float) + radius * np.column_stack([np.cos(ang), np.sin(ang)])
            held = np.zeros(spec.shape, bool)
            mark(rim, occ, semi, held)
            index[held] = len(objs)
            cm = se2_apply(t_map_world, rim.mean(axis=0)[None])[0]  # a box around what was seen
            fp = se2_apply(t_map_world, np.asarray(c, float) + radius * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]))
            objs.append(SemiStaticObject(cls, (float(cm[0]), float(cm[1])), (2 * radius, radius), 0.0,
                                         int(held.sum()), 5, tuple(map(tuple, fp))))
        for cls, seg in self.faces:
            # one segment (x0, y0, x1, y1), or a list of them: faces of one object (a couch's front and ends)
            segs = [seg] if isinstance(seg, tuple) else list(seg)
            lines = []
            for x0, y0, x1, y1 in segs:
                n = int(math.hypot(x1 - x0, y1 - y0) / (RES / 3)) + 2
                lines.append(np.stack([np.linspace(x0, x1, n), np.linspace(y0, y1, n)], axis=1))
            line = np.concatenate(lines)
            held = np.zeros(spec.shape, bool)
            mark(line, occ, semi, held)
            index[held] = len(objs)
            cm = se2_apply(t_map_world, line.mean(axis=0)[None])[0]
            (x0, y0), (x1, y1) = line.min(axis=0), line.max(axis=0)
            if len(segs) == 1:
                (x0, y0, x1, y1) = segs[0]
                fp = se2_apply(t_map_world, np.array([[x0, y0], [x1, y1], [x1, y1], [x0, y0]], float))
                dims, yaw = (math.hypot(x1 - x0, y1 - y0), RES), math.atan2(y1 - y0, x1 - x0)
            else:  # the box around them, axis-aligned in the world
                fp = se2_apply(t_map_world, np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float))
                dims, yaw = (max(x1 - x0, y1 - y0), min(x1 - x0, y1 - y0)), 0.0 if x1 - x0 >= y1 - y0 else math.pi / 2
            objs.append(SemiStaticObject(cls, (float(cm[0]), float(cm[1])), dims, float(yaw - T_world_map[2]),
                                         int(held.sum()), 5, tuple(map(tuple, fp))))
        for c, radius, seen_from in self.unlabelled_round:
            ang = seen_from + np.linspace(-math.pi / 2, math.pi / 2, 120)
            mark(np.asarray(c, float) + radius * np.column_stack([np.cos(ang), np.sin(ang)]), occ)
        h = self.unlabelled_leg_half
        for _cls, c, size, yaw in self.unlabelled:
            for leg in self.legs(c, size, yaw):
                mark(leg + np.array([[dx, dy] for dx in (-h, 0, h) for dy in (-h, 0, h)]), occ)
        for p in self.loose_legs:
            mark(np.array(p) + np.array([[dx, dy] for dx in (-0.02, 0, 0.02) for dy in (-0.02, 0, 0.02)]), occ, semi)
        faint = np.zeros(spec.shape, bool)
        for p in self.faint_legs:
            mark(np.array(p) + np.array([[dx, dy] for dx in (-0.02, 0, 0.02) for dy in (-0.02, 0, 0.02)]), faint)
        glimpsed = faint.copy()
        for p in self.glimpsed_legs:
            mark(np.array(p) + np.array([[dx, dy] for dx in (-0.02, 0, 0.02) for dy in (-0.02, 0, 0.02)]), glimpsed)
        for p in self.dropped:
            mark(np.array(p) + np.array([[dx, dy] for dx in (-0.02, 0, 0.02) for dy in (-0.02, 0, 0.02)]), dyn)
        for p in self.people:
            mark(np.array(p) + np.array([[dx, dy] for dx in (-0.1, 0, 0.1) for dy in (-0.1, 0, 0.1)]), occ, dyn)
        free = inside & ~occ
        return Session(Path(name), spec, occ & (inside | occ), free, semi, dyn, tuple(objs), True,
                       faint=faint & ~occ, object_index=index if self.object_layer else None,
                       glimpsed=glimpsed & ~occ, weak=weak)


