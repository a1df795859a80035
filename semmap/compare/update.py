"""``semmap diff A B --update OUT``: session A's map with B's changes applied, as a map folder.

The updated folder is A's folder with the map files rewritten: cells the diff found added are
occupied, cells it found removed are free (the change mask's cells: static changes and the cells of
movable objects that moved, appeared or disappeared), and the object list has the moved objects at
their new place, the new ones added and the vanished ones dropped. Everything else is A's: its
grid, frame and origin (a robot localised in A's map stays localised), its trajectory and
configuration. Floor only B explored is not added: A's grid does not hold it (``newly_explored``
says where it is; rebuild or merge the tours to map it).

``grid.npz`` keeps A's evidence layers (hit and free counts, classes); its ``occupied`` and
``semi_static`` arrays are the updated ones. ``update.json`` records what was applied, from where.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..geometry import se2_apply, wrap_angle
from ..grid import CleanedMap, SemiStaticObject
from ..io.mapserver import write_map
from ..mapfolder.reader import MapFolder
from .changes import Change
from .result import DiffResult

__all__ = ["updated_objects", "write_updated_map"]

#: the files of A's folder the update rewrites; the rest are copied as they are
_REWRITTEN = ("map.yaml", "map.pgm", "semi_static.yaml", "semi_static.pgm", "semi_static_objects.json", "grid.npz",
              "summary.json", "semantic.png", "report.md")


def _moved_object(o: SemiStaticObject, r: DiffResult) -> SemiStaticObject:
    """B's object carried into A's frame."""
    t = np.asarray(r.alignment.T_a_b, np.float64)
    c = se2_apply(t, np.array([o.centroid]))[0]
    fp = se2_apply(t, np.asarray(o.footprint, np.float64).reshape(-1, 2)) if o.footprint else np.zeros((0, 2))
    return SemiStaticObject(o.class_name, (round(float(c[0]), 3), round(float(c[1]), 3)), o.size,
                            float(wrap_angle(o.yaw + float(t[2]))), o.n_cells, o.views,
                            tuple((round(float(x), 3), round(float(y), 3)) for x, y in fp))


def updated_objects(r: DiffResult) -> tuple[SemiStaticObject, ...]:
    """A's objects with B's object changes applied: gone ones dropped, moved and new ones from B."""
    from scipy.spatial import cKDTree

    keep = list(r.a.objects)
    changed = [c for c in r.changes if c.type in ("object_moved", "object_disappeared", "object_appeared")]
    if not changed:
        return tuple(keep)
    # drop A's objects that moved or vanished: the ones nearest where each change starts
    dropped: dict[int, SemiStaticObject] = {}
    for n, c in enumerate(changed):
        if c.type == "object_appeared" or not keep:
            continue
        start = c.from_xy if c.type == "object_moved" and c.from_xy else c.centroid
        same = [i for i, o in enumerate(keep) if o.class_name == c.class_name]
        if same:
            d = [float(np.hypot(keep[i].centroid[0] - start[0], keep[i].centroid[1] - start[1])) for i in same]
            if min(d) <= 1.5:
                dropped[n] = keep.pop(same[int(np.argmin(d))])
    # add B's objects where each move ends and each new object is; an object moved to where B's camera
    # did not label it is A's, carried by the move
    b_objs = [_moved_object(o, r) for o in r.b.objects]
    tree = cKDTree(np.array([o.centroid for o in b_objs])) if b_objs else None
    for n, c in enumerate(changed):
        if c.type == "object_disappeared":
            continue
        end = c.to_xy if c.type == "object_moved" and c.to_xy else c.centroid
        found = False
        if tree is not None:
            d, k = tree.query(end, k=min(4, len(b_objs)))
            for dist, j in zip(np.atleast_1d(d), np.atleast_1d(k), strict=True):
                if b_objs[j].class_name == c.class_name and dist <= 1.5 and b_objs[j] not in keep:
                    keep.append(b_objs[j])
                    found = True
                    break
        if not found and n in dropped and c.from_xy and c.to_xy:
            keep.append(_carried(dropped[n], c))
    return tuple(keep)


def _carried(o: SemiStaticObject, c: Change) -> SemiStaticObject:
    """A's object ``o`` moved as ``c`` says: turned by its rotation about where it was, then shifted."""
    assert c.from_xy is not None and c.to_xy is not None
    turn = math.radians(c.rotation_deg or 0.0)
    f, t = np.asarray(c.from_xy, np.float64), np.asarray(c.to_xy, np.float64)
    motion = np.array([*(t - se2_apply(np.array([0.0, 0.0, turn]), f[None])[0]), turn])
    cen = se2_apply(motion, np.array([o.centroid], np.float64))[0]
    fp = se2_apply(motion, np.asarray(o.footprint, np.float64).reshape(-1, 2)) if o.footprint else np.zeros((0, 2))
    return SemiStaticObject(o.class_name, (round(float(cen[0]), 3), round(float(cen[1]), 3)), o.size,
                            float(wrap_angle(o.yaw + turn)), o.n_cells, o.views,
                            tuple((round(float(x), 3), round(float(y), 3)) for x, y in fp))


def write_updated_map(r: DiffResult, out: Path) -> list[str]:
    """Write A's map folder with B's changes applied into ``out`` (an empty folder); the changes applied."""
    from ..mapfolder.reader import load_map_folder

    if not r.a.semantic:
        raise ConfigError(f"{r.a.path}: --update needs session A to be a semmap map folder (it rewrites its "
                          "grid and object list); this one is a plain map_server map")
    a = load_map_folder(r.a.path)
    for p in a.path.iterdir():
        if p.name not in _REWRITTEN and not p.name.startswith("."):
            if p.is_dir():
                shutil.copytree(p, out / p.name)
            else:
                shutil.copy2(p, out / p.name)
    cl = a.cleaned
    occupied = cl.occupied.copy()
    free = cl.free.copy()
    occupied[r.mask == 1] = True
    free[r.mask == 1] = False
    occupied[r.mask == 2] = False
    free[r.mask == 2] = True
    unknown = ~(occupied | free)
    semi = cl.semi_static & occupied
    # the cells of moved and new objects are movable, as B flagged them
    lo = r.laid_out
    r0, c0, h, w = lo.a_window
    semi |= (lo.semi_b & lo.occ_b)[r0:r0 + h, c0:c0 + w] & (r.mask == 1)
    objects = updated_objects(r)
    write_map(out / "map.yaml", a.spec, occupied, known=~unknown)
    write_map(out / "semi_static.yaml", a.spec, semi, known=~unknown)
    (out / "semi_static_objects.json").write_text(
        json.dumps({"frame_id": "map", "objects": [o.as_dict() for o in objects]}, indent=2), encoding="utf-8")
    with np.load(a.path / "grid.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["occupied"], arrays["semi_static"] = occupied, semi
    np.savez_compressed(out / "grid.npz", **arrays)
    applied = [c.as_dict() for c in r.changes if c.type not in ("newly_explored", "no_longer_covered")]
    (out / "update.json").write_text(json.dumps({
        "base": str(r.a.path), "changes_from": str(r.b.path), "alignment": r.alignment.as_dict(),
        "applied": applied, "cells_added": int((r.mask == 1).sum()), "cells_removed": int((r.mask == 2).sum()),
    }, indent=2), encoding="utf-8")
    summary = json.loads((a.path / "summary.json").read_text(encoding="utf-8"))
    summary["map"].update({"occupied_cells": int(occupied.sum()), "free_cells": int(free.sum()),
                           "semi_static_cells": int(semi.sum()), "semi_static_objects": len(objects)})
    by_class: dict[str, int] = {}
    for o in objects:
        by_class[o.class_name] = by_class.get(o.class_name, 0) + 1
    summary["map"]["semi_static_objects_by_class"] = by_class
    summary["warnings"] = [*summary.get("warnings", []),
                           f"updated by semmap diff with {len(applied)} changes from {r.b.path} (update.json)"]
    files = sorted({*summary.get("files", []), "update.json"})
    summary["files"] = files
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    _picture(out, CleanedMap(a.spec, occupied, free, unknown, semi, cl.dynamic_removed & unknown, objects), a,
             f"{r.a.name} updated with {len(applied)} changes from {r.b.name}: {int((r.mask == 1).sum())} cells "
             f"added, {int((r.mask == 2).sum())} removed, {len(objects)} movable objects")
    (out / "report.md").write_text(
        f"# Updated map\n\n`{r.a.path}` with {len(applied)} changes from `{r.b.path}` applied "
        f"({int((r.mask == 1).sum())} cells added, {int((r.mask == 2).sum())} removed; see update.json).\n\n"
        "![map](semantic.png)\n", encoding="utf-8")
    return [c["type"] for c in applied]


def _picture(out: Path, cleaned: CleanedMap, a: MapFolder, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch, Polygon
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    from ..mapfolder.report import semantic_image
    from ..palette import rgb01

    img, legend = semantic_image(cleaned, a.layers, a.class_names)
    spec = cleaned.spec
    extent = (spec.origin_x, spec.origin_x + spec.width * spec.resolution,
              spec.origin_y, spec.origin_y + spec.height * spec.resolution)
    w_m, h_m = extent[1] - extent[0], extent[3] - extent[2]
    fig, ax = plt.subplots(figsize=(11.0, float(np.clip(11.0 * h_m / max(w_m, 1e-6) * 0.8 + 1.0, 3.5, 12.0))),
                           dpi=110)
    ax.imshow(img, origin="lower", extent=extent, interpolation="nearest")
    for o in cleaned.objects:
        if len(o.footprint) >= 3:
            ax.add_patch(Polygon(np.asarray(o.footprint), closed=True, fill=False, lw=0.7, ls="--",
                                 edgecolor="#333333"))
    handles = [Patch(facecolor=rgb01(c), edgecolor="0.6", label=k) for k, c in legend.items()]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    bar = 1.0 if w_m < 15 else 5.0
    ax.add_artist(AnchoredSizeBar(ax.transData, bar, f"{bar:g} m", "lower right", pad=0.4, frameon=True,
                                  size_vertical=spec.resolution * 2))
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x [m] (map frame)")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out / "semantic.png", bbox_inches="tight")
    plt.close(fig)
