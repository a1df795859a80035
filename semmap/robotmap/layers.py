"""The layers a saved session can be exported as, computed from its map folder without rebuilding.

Every layer is a :class:`Plane`: per cell occupied, free, or neither, and the probability of
occupancy where a scan observed the cell (NaN elsewhere), in the map folder's grid.

* ``cleaned``: the map the build wrote (``map.yaml``): people dropped, furniture kept as obstacles.
* ``static``: static structure only, for localisation maps that must not depend on furniture:
  cells flagged semi-static are neither obstacle nor floor (unknown), everything else as ``cleaned``.
* ``raw``: the occupancy before cleaning (the log-odds and hit-ratio rule of cleaning's first step),
  people and all.
* ``semi_static``: the cells flagged movable, as obstacles on the observed floor.
* ``class:NAME``: cells where ``NAME`` has the most camera-labelled returns (at least half of
  them), for any class the build saw or the class table knows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from ..grid import evidence_occupancy
from ..mapfolder.reader import MapFolder

__all__ = ["BASE_LAYERS", "Plane", "layer_plane", "people_cells"]

#: the layers every map folder can give, in the order they are written
BASE_LAYERS = ("cleaned", "static", "raw", "semi_static")


@dataclass(frozen=True)
class Plane:
    """One layer on a grid: ``occupied`` and ``free`` (H, W) bool, disjoint; ``prob`` (H, W)
    float32, the probability of occupancy, NaN where no scan observed the cell."""

    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    prob: NDArray[np.float32]

    @property
    def unknown(self) -> NDArray[np.bool_]:
        return ~(self.occupied | self.free)


def _probability(m: MapFolder) -> NDArray[np.float32]:
    lo = m.layers.log_odds.astype(np.float32)
    p = (1.0 / (1.0 + np.exp(-lo))).astype(np.float32)
    p[~m.layers.observed] = np.nan
    return p


def _class_plane(m: MapFolder, name: str, known: tuple[str, ...]) -> tuple[Plane, str | None]:
    layers = m.layers
    names = layers.class_names
    if not names:
        raise ConfigError(f"--layer class:{name}: {m.path} has no classes (a LiDAR-only build: the tour had no "
                          f"camera)")
    observed = m.layers.observed
    prob = np.full(observed.shape, np.nan, np.float32)
    if name not in names or names.index(name) not in layers.class_ids:
        if name not in names and name not in known:
            choices = ", ".join(sorted(set(names) | set(known)))
            raise ConfigError(f"--layer class:{name}: no class {name!r} (the build's and the class table's: "
                              f"{choices})")
        occ = np.zeros(observed.shape, bool)
        prob[observed] = 0.0
        return Plane(occ, observed.copy(), prob), f"class {name!r} was never seen in this tour: its layer is empty"
    k = layers.class_ids.index(names.index(name))
    counts = layers.class_counts.astype(np.float32)
    total = counts.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(total > 0, counts[k] / np.maximum(total, 1.0), 0.0).astype(np.float32)
    occ = (counts[k] > 0) & (share >= 0.5)
    prob[observed] = share[observed]
    return Plane(occ, observed & ~occ, prob), None


def layer_plane(m: MapFolder, name: str) -> tuple[Plane, str | None]:
    """The layer ``name`` of the map folder ``m``, and a warning (or None)."""
    c = m.cleaned
    prob = _probability(m)
    if name == "cleaned":
        return Plane(c.occupied.copy(), c.free & ~c.occupied, prob), None
    if name == "static":
        p = prob.copy()
        p[c.semi_static] = np.nan
        return Plane(c.occupied & ~c.semi_static, c.free & ~c.occupied & ~c.semi_static, p), None
    if name == "raw":
        occ, free = evidence_occupancy(m.layers, m.config.cleaning)
        return Plane(occ, free & ~occ, prob), None
    if name == "semi_static":
        known = c.occupied | c.free
        p = np.where(known, np.where(c.semi_static, 1.0, 0.0), np.nan).astype(np.float32)
        return Plane(c.semi_static.copy(), known & ~c.semi_static, p), None
    if name.startswith("class:") and len(name) > len("class:"):
        from ..classes import load_class_table

        return _class_plane(m, name[len("class:"):], tuple(load_class_table().mobility))
    raise ConfigError(f"--layer {name}: unknown layer (choose from {', '.join(BASE_LAYERS)}, or class:NAME)")


def people_cells(m: MapFolder) -> NDArray[np.bool_]:
    """Cells where people were seen: dropped as dynamic by cleaning, or whose camera-labelled returns
    were mostly dynamic."""
    from ..records import Mobility

    mob = m.layers.mobility.astype(np.float32)
    lab = mob[Mobility.STATIC] + mob[Mobility.SEMI_STATIC] + mob[Mobility.DYNAMIC]
    dyn = (mob[Mobility.DYNAMIC] > 0) & (mob[Mobility.DYNAMIC] >= 0.5 * np.maximum(lab, 1.0))
    return np.asarray(m.cleaned.dynamic_removed | dyn, bool)
