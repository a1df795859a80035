"""The diff folder: ``changes.json``, the change mask, ``overlay.png`` and ``report.md``.

::

    DIFF/
      changes.json     every change (type, class, centroid, area, displacement), the alignment, counts
      changes.yaml     the change mask as a map_server map in A's map frame (mode raw: 0 none,
      changes.png      1 added, 2 removed), with A's resolution and origin
      overlay.png      A's map, B's changes on it, a legend and a scale bar
      report.md        the summary, the alignment, the table of changes
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.artist import Artist
from matplotlib.patches import FancyArrowPatch, Patch
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from ..io.yamlio import write_yaml
from .changes import CHANGE_TYPES, Change
from .result import DiffResult

__all__ = ["TYPE_LABELS", "TYPE_PLURALS", "count_label", "object_name", "summary_lines", "write_diff_files"]

#: how people read each change type
TYPE_LABELS = {
    "static_added": "new static obstacle",
    "static_removed": "removed static obstacle",
    "object_moved": "movable object moved",
    "object_appeared": "movable object appeared",
    "object_disappeared": "movable object disappeared",
    "newly_explored": "area newly explored",
    "no_longer_covered": "area no longer covered",
}

#: the same, for more than one
TYPE_PLURALS = {
    "static_added": "new static obstacles",
    "static_removed": "removed static obstacles",
    "object_moved": "movable objects moved",
    "object_appeared": "movable objects appeared",
    "object_disappeared": "movable objects disappeared",
    "newly_explored": "areas newly explored",
    "no_longer_covered": "areas no longer covered",
}



#: behind a label: white, half see-through, so markers and changed cells under it do not hide it
_LABEL_BOX = {"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7}


def _label_placer(ax: Any, dpi: float) -> Callable[..., tuple[float, float]]:
    """Offsets (points) for labels at map points, each clear of the labels placed before it: the first
    of a few heights beside its point whose box (7 pt text) overlaps none of theirs, else the least
    crowded. Call after the axes' limits are set."""
    boxes: list[tuple[float, float, float, float]] = []  # placed labels, display pixels
    px = dpi / 72.0

    def place(xy: Sequence[float], text: str, dx: float = 4.0) -> tuple[float, float]:
        x0, y0 = ax.transData.transform((float(xy[0]), float(xy[1])))
        w, h = 7 * 0.6 * len(text) * px, 9 * px
        best, best_hits = (dx, -2.0), None
        for dy in (-2.0, 9.0, -13.0, 20.0, -24.0, 31.0, -35.0):
            bx, by = x0 + dx * px, y0 + dy * px
            hits = sum(1 for (a, b, c, d) in boxes if bx < c and a < bx + w and by < d and b < by + h)
            if best_hits is None or hits < best_hits:
                best, best_hits = (dx, dy), hits
            if hits == 0:
                break
        bx, by = x0 + best[0] * px, y0 + best[1] * px
        boxes.append((bx, by, bx + w, by + h))
        return best

    return place

def object_name(c: Change) -> str:
    """What an object change is of: its class, or "unlabelled object" for furniture no camera
    labelled (its move found from its legs alone)."""
    return c.class_name or "unlabelled object"


def count_label(kind: str, n: int) -> str:
    """``n`` changes of ``kind``, as people say it: "1 new static obstacle", "4 movable objects moved"."""
    return f"{n} {TYPE_LABELS[kind] if n == 1 else TYPE_PLURALS[kind]}"


_ADDED = (0.10, 0.62, 0.20)
_REMOVED = (0.85, 0.15, 0.15)
_EXPLORED = (0.35, 0.60, 0.95)
_UNCOVERED = (0.95, 0.70, 0.30)
_MOVED = (0.55, 0.25, 0.75)


def _tint(c: tuple[float, float, float]) -> tuple[float, float, float]:
    """A light shade of ``c`` for areas."""
    return (0.55 * c[0] + 0.45, 0.55 * c[1] + 0.45, 0.55 * c[2] + 0.45)


def summary_lines(r: DiffResult) -> list[str]:
    """The terminal summary: what was compared, how well it aligned, the changes by type."""
    al = r.alignment.as_dict()
    t = al["T_a_b"]
    lines = [f"{r.b.name} against {r.a.name}: " + ("semantic diff" if r.semantic else
                                                  "geometric diff only (a map without classes, a plain "
                                                  "map_server map or a LiDAR-only build: no object changes)"),
             f"  alignment  B in A: x {t[0]:+.3f} m, y {t[1]:+.3f} m, yaw {math.degrees(t[2]):+.2f}°; residual "
             f"{al['residual_m'] * 100:.1f} cm, {al['inlier_fraction'] * 100:.0f} % of B's walls on A's, "
             f"overlap {al['overlap'] * 100:.0f} %"]
    lines += [f"  warning    {w}" for w in r.warnings]
    counts = r.counts()
    shown = [count_label(k, n) for k, n in counts.items() if n]
    lines.append("  changes    " + (", ".join(shown) if shown else "none"))
    for c in r.changes:
        if c.type == "object_moved":
            lines.append(f"    {object_name(c)} moved {c.displacement_m:.2f} m"
                         + (f", turned {c.rotation_deg:+.0f}°" if c.rotation_deg and abs(c.rotation_deg) >= 0.5 else "")
                         + f": ({c.from_xy[0]:.2f}, {c.from_xy[1]:.2f}) -> ({c.to_xy[0]:.2f}, {c.to_xy[1]:.2f})"
                         if c.from_xy and c.to_xy else "")
    left = r.left_out
    if left.get("objects_unobserved_in_b") or left.get("objects_unobserved_in_a"):
        lines.append(f"  unobserved {left.get('objects_unobserved_in_b', 0)} of A's objects not seen by B, "
                     f"{left.get('objects_unobserved_in_a', 0)} of B's not seen by A (not reported as changes)")
    return lines


def write_diff_files(r: DiffResult, out: Path) -> list[str]:
    """Write the diff folder's files into ``out`` (an empty folder); return their names."""
    spec = r.spec
    (out / "changes.json").write_text(json.dumps(r.as_dict(), indent=2), encoding="utf-8")
    if not cv2.imwrite(str(out / "changes.png"), np.flipud(r.mask)):
        raise OSError(0, "cannot write the change mask", str(out / "changes.png"))
    # a map_server map of the raw values: nav2 and ROS1 map_server load 0/1/2 as they are in mode raw
    write_yaml(out / "changes.yaml", {
        "image": "changes.png", "mode": "raw", "resolution": float(spec.resolution),
        "origin": [float(spec.origin_x), float(spec.origin_y), 0.0], "negate": 0,
        "occupied_thresh": 0.65, "free_thresh": 0.196,
    }, "# semmap diff change mask, session A's map frame: 0 no change, 1 added, 2 removed (mode raw)\n")
    _overlay(r, out / "overlay.png")
    _report(r, out / "report.md")
    return ["changes.json", "changes.png", "changes.yaml", "overlay.png", "report.md"]


def _overlay(r: DiffResult, path: Path) -> None:
    lo = r.laid_out
    spec = lo.spec
    seen = lo.occ_a | lo.free_a | lo.occ_b | lo.free_b
    rows, cols = np.nonzero(seen)
    if rows.size == 0:
        rows, cols = np.array([0, spec.height - 1]), np.array([0, spec.width - 1])
    pad = int(round(1.0 / spec.resolution))
    r0, r1 = max(0, rows.min() - pad), min(spec.height, rows.max() + pad + 1)
    c0, c1 = max(0, cols.min() - pad), min(spec.width, cols.max() + pad + 1)
    win = (slice(r0, r1), slice(c0, c1))
    img = np.full((r1 - r0, c1 - c0, 3), 0.80)
    img[lo.free_a[win]] = 1.0
    only_b = (lo.occ_b | lo.free_b)[win] & ~(lo.occ_a | lo.free_a)[win]
    only_a = (lo.occ_a | lo.free_a)[win] & ~(lo.occ_b | lo.free_b)[win]
    img[only_b] = _tint(_EXPLORED)
    img[only_a & lo.free_a[win]] = _tint(_UNCOVERED)
    img[lo.occ_b[win] & ~lo.occ_a[win]] = 0.62  # B's obstacles, faint, where A had none
    img[lo.occ_a[win]] = 0.25
    mask = r.mask_common[win]
    # changed cells grown for the eye (a chair leg is one cell of a map hundreds of cells wide); the
    # change mask itself is not grown
    grow = max(1, int(round(0.004 * max(mask.shape))))
    kernel = np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)
    img[cv2.dilate((mask == 2).astype(np.uint8), kernel) > 0] = _REMOVED
    img[cv2.dilate((mask == 1).astype(np.uint8), kernel) > 0] = _ADDED
    extent = (spec.origin_x + c0 * spec.resolution, spec.origin_x + c1 * spec.resolution,
              spec.origin_y + r0 * spec.resolution, spec.origin_y + r1 * spec.resolution)
    w_m, h_m = extent[1] - extent[0], extent[3] - extent[2]
    fig_w = 11.0
    fig_h = float(np.clip(fig_w * h_m / max(w_m, 1e-6) * 0.8 + 1.2, 3.5, 12.0))
    fig, ax = plt.subplots(figsize=(fig_w, fig_h), dpi=110)
    ax.imshow(img, origin="lower", extent=extent, interpolation="nearest")
    place = _label_placer(ax, fig.dpi)
    for c in r.changes:
        if c.type == "object_moved" and c.from_xy and c.to_xy:
            ax.add_patch(FancyArrowPatch(c.from_xy, c.to_xy, arrowstyle="-|>", mutation_scale=12, lw=1.6,
                                         color=_MOVED))
            text = f"{object_name(c)} {c.displacement_m:.2f} m"
            ax.annotate(text, c.to_xy, xytext=place(c.to_xy, text), textcoords="offset points", fontsize=7,
                        color=_MOVED, zorder=5, bbox=_LABEL_BOX)
        elif c.type in ("object_appeared", "object_disappeared"):
            col = _ADDED if c.type == "object_appeared" else _REMOVED
            ax.plot(*c.centroid, marker="o", ms=14, mfc="none", mec=col, mew=1.5)
            text = f"{c.class_name} {'new' if c.type == 'object_appeared' else 'gone'}"
            ax.annotate(text, c.centroid, xytext=place(c.centroid, text, dx=8.0), textcoords="offset points",
                        fontsize=7, color=col, zorder=5, bbox=_LABEL_BOX)
        elif c.type in ("static_added", "static_removed"):
            col = _ADDED if c.type == "static_added" else _REMOVED
            ax.plot(*c.centroid, marker="s", ms=12, mfc="none", mec=col, mew=1.2)
    handles: list[Artist] = [
        Patch(facecolor="0.25", label="A: obstacle"), Patch(facecolor="1.0", edgecolor="0.6", label="A: free"),
        Patch(facecolor="0.62", label="B: obstacle where A saw nothing (unobserved, not a change)"),
        Patch(facecolor=_ADDED, label="added in B"), Patch(facecolor=_REMOVED, label="removed in B"),
        Patch(facecolor=_tint(_EXPLORED), label="seen only by B (newly explored)"),
        Patch(facecolor=_tint(_UNCOVERED), label="seen only by A (no longer covered)"),
    ]
    if r.semantic:
        handles += [plt.Line2D([], [], color=_MOVED, marker=">", label="movable object moved"),
                    plt.Line2D([], [], ls="", marker="o", mfc="none", mec=_ADDED, label="object appeared"),
                    plt.Line2D([], [], ls="", marker="o", mfc="none", mec=_REMOVED, label="object disappeared")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    bar = 1.0 if w_m < 15 else 5.0
    ax.add_artist(AnchoredSizeBar(ax.transData, bar, f"{bar:g} m", "lower right", pad=0.4, frameon=True,
                                  size_vertical=spec.resolution * 2))
    counts = r.counts()
    ax.set_title(f"{r.b.name} against {r.a.name}: " + ", ".join(
        count_label(k, n) for k, n in counts.items() if n) + ("" if r.semantic else " (geometry only)"),
        fontsize=9)
    ax.set_xlabel(f"x [m] ({r.a.name}'s map frame)")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def _report(r: DiffResult, path: Path) -> None:
    al = r.alignment.as_dict()
    t = al["T_a_b"]
    lines = [f"# Changes: {r.b.name} against {r.a.name}", "",
             f"- A: `{r.a.path}`", f"- B: `{r.b.path}`",
             "- " + ("semantic diff (both are semmap map folders)" if r.semantic else
                     "**geometric diff only**: at least one map has no classes (a plain map_server map or a "
                     "LiDAR-only build), so furniture changes are static changes and people cannot be told apart"),
             "", "## Alignment", "",
             f"B's map frame in A's: x {t[0]:+.3f} m, y {t[1]:+.3f} m, yaw {math.degrees(t[2]):+.2f}°. "
             f"Residual {al['residual_m'] * 100:.1f} cm over {al['inlier_fraction'] * 100:.0f} % of B's walls; "
             f"{al['overlap'] * 100:.0f} % of B's observed floor lies on A's; ambiguity {al['ambiguity']:.2f} "
             "(where the best other fit and this one disagree, the other's evidence over this one's).",
             *[f"\n**Warning:** {w}." for w in r.warnings], "", "![overlay](overlay.png)", "",
             "## Changes", "", "| type | count |", "|---|---|"]
    for k, n in r.counts().items():
        lines.append(f"| {TYPE_LABELS[k]} | {n} |")
    lines += ["", "| # | type | class | centroid (m, A's map frame) | area (m²) | moved (m) | turned (°) |",
              "|---|---|---|---|---|---|---|"]
    order = {t: i for i, t in enumerate(CHANGE_TYPES)}
    for i, c in enumerate(sorted(r.changes, key=lambda c: order[c.type]), 1):
        moved = f"{c.displacement_m:.3f}" if c.displacement_m is not None else ""
        turned = f"{c.rotation_deg:+.1f}" if c.rotation_deg is not None else ("-" if c.type == "object_moved" else "")
        what = object_name(c) if c.type.startswith("object") else ""
        lines.append(f"| {i} | {TYPE_LABELS[c.type]} | {what} | ({c.centroid[0]:.2f}, "
                     f"{c.centroid[1]:.2f}) | {c.area_m2:.3f} | {moved} | {turned} |")
    left = r.left_out
    lines += ["", "Not reported: cells only one session observed (unobserved, not changed); "
              f"{left.get('cells_near_people', 0)} cells where people were seen; "
              f"{left.get('objects_unobserved_in_b', 0)} of A's movable objects B did not see enough of, and "
              f"{left.get('objects_unobserved_in_a', 0)} of B's that A did not see; "
              f"{left.get('wall_faces', 0)} strips along a wall that one session saw from one side only; "
              f"{left.get('hidden_faces', 0)} faces one session saw only edge-on (beside what it never "
              "observed, such as the inside of a pillar); "
              f"{left.get('weak_obstacles', 0)} obstacles most of whose cells rest on one or two LiDAR returns "
              "(a far wall seen once, edge-on); "
              f"{left.get('people_stances', 0)} pair{'' if left.get('people_stances', 0) == 1 else 's'} of "
              "leg-sized blobs alone on the floor that no camera saw "
              "(a person who stood while the robot passed).", ""]
    path.write_text("\n".join(lines), encoding="utf-8")
