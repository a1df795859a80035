"""The pictures and the Markdown report of a map folder."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.artist import Artist
from matplotlib.patches import Patch, Polygon
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

from ..geometry import se2_between, se2_compose
from ..palette import MOBILITY_COLORS, class_color, rgb01
from ..records import Mobility

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from ..grid import CleanedMap, GridLayers
    from .writer import BuildOutcome

__all__ = ["camera_line", "consistency_line", "loops_line", "registration_line", "render_pictures", "semantic_image",
           "write_report"]

_FREE = (255, 255, 255)
_UNKNOWN = (205, 205, 205)
_REMOVED = (255, 190, 190)


def semantic_image(cleaned: CleanedMap, layers: GridLayers, class_names: tuple[str, ...]
                   ) -> tuple[np.ndarray, dict[str, tuple[int, int, int]]]:
    """An RGB image (grid order) of the cleaned map coloured by mobility and class, and its legend."""
    img = np.empty(cleaned.spec.shape + (3,), np.uint8)
    img[:] = _UNKNOWN
    img[cleaned.free] = _FREE
    legend: dict[str, tuple[int, int, int]] = {"free": _FREE, "unknown": _UNKNOWN}
    static = cleaned.occupied & ~cleaned.semi_static
    img[static] = MOBILITY_COLORS[Mobility.STATIC]
    legend["static"] = MOBILITY_COLORS[Mobility.STATIC]
    if cleaned.dynamic_removed.any():
        img[cleaned.dynamic_removed] = _REMOVED
        legend["dynamic (removed)"] = _REMOVED
    if cleaned.semi_static.any():
        img[cleaned.semi_static] = MOBILITY_COLORS[Mobility.SEMI_STATIC]
        named = np.zeros(cleaned.spec.shape, bool)
        if layers.class_counts.shape[0] and class_names:
            best = np.argmax(layers.class_counts, axis=0)
            has = layers.class_counts.max(axis=0) > 0
            # a flagged cell no camera labelled (a bed's side the camera did not see) is drawn in
            # the class of the nearest labelled one, as the object list names it
            own = cleaned.semi_static & has
            if own.any() and (cleaned.semi_static & ~own).any():
                from ..grid.clean import nearest_value

                best = np.where(own, best, nearest_value(own, best)[1])
                has = has | cleaned.semi_static
            for k, cid in enumerate(layers.class_ids):
                name = class_names[cid]
                sel = cleaned.semi_static & has & (best == k)
                if sel.any():
                    img[sel] = class_color(name)
                    named |= sel
                    legend[f"semi-static: {name}"] = class_color(name)
        if (cleaned.semi_static & ~named).any():
            legend["semi-static, class not seen"] = MOBILITY_COLORS[Mobility.SEMI_STATIC]
    return img, legend


_OUTLINE = "#333333"  # the outline of a movable object's footprint


def _grey(cleaned: CleanedMap, extent: tuple[float, float, float, float], px: int
          ) -> tuple[NDArray[np.uint8], tuple[float, float, float, float]]:
    """The map in grey (occupied dark, free white, unknown light grey) and its extent, fitted to a figure
    about ``px`` pixels wide (:func:`_fit`)."""
    grey = np.full(cleaned.occupied.shape, 217, np.uint8)  # 0.85 of white
    grey[cleaned.free] = 255
    grey[cleaned.occupied] = 64  # 0.25
    return _fit(grey, cleaned, extent, px)


def _fit(img: NDArray[Any], cleaned: CleanedMap, extent: tuple[float, float, float, float], px: int
         ) -> tuple[NDArray[Any], tuple[float, float, float, float]]:
    """``img`` (H, W[, C]) as drawn in a figure about ``px`` pixels wide: a map wider is shrunk here, each
    block of cells showing the one that matters most (semi-static, then occupied, then dropped as dynamic,
    then free, then unknown). matplotlib would pick one cell per pixel, losing thin walls, and
    resample in float RGBA (a 150 m floor at 5 cm: half a gigabyte). The extent grows to the padded blocks."""
    h, w = cleaned.occupied.shape
    k = max(1, -(-max(h, w) // px))  # blocks of k x k cells: at most px of them across
    if k == 1:
        return img, extent
    rank = np.zeros((-(-h // k) * k, -(-w // k) * k), np.uint8)
    hp, wp = rank.shape
    rank[:h, :w][cleaned.free] = 1
    rank[:h, :w][cleaned.dynamic_removed] = 2
    rank[:h, :w][cleaned.occupied] = 3
    rank[:h, :w][cleaned.semi_static] = 4
    pick = rank.reshape(hp // k, k, wp // k, k).transpose(0, 2, 1, 3).reshape(hp // k, wp // k, k * k).argmax(-1)
    rows = (np.arange(hp // k)[:, None] * k + pick // k).clip(max=h - 1)
    cols = (np.arange(wp // k)[None, :] * k + pick % k).clip(max=w - 1)
    res_x = (extent[1] - extent[0]) / w
    res_y = (extent[3] - extent[2]) / h
    return img[rows, cols], (extent[0], extent[0] + wp * res_x, extent[2], extent[2] + hp * res_y)


def render_pictures(out: Path, outcome: BuildOutcome) -> dict[str, str]:
    """Draw semantic.png, report/trajectory.png and report/classes.png; return their relative paths."""
    (out / "report").mkdir(exist_ok=True)
    cleaned, layers, class_names = outcome.cleaned, outcome.layers, outcome.class_names
    spec = cleaned.spec
    extent = (spec.origin_x, spec.origin_x + spec.width * spec.resolution,
              spec.origin_y, spec.origin_y + spec.height * spec.resolution)
    poses = np.asarray(outcome.poses).reshape(-1, 3)
    img, legend = semantic_image(cleaned, layers, class_names)
    w_m, h_m = extent[1] - extent[0], extent[3] - extent[2]
    fig_w = 11.0
    fig_h = float(np.clip(fig_w * h_m / max(w_m, 1e-6) * 0.8 + 1.0, 3.5, 12.0))
    fig, ax = plt.subplots(figsize=(fig_w, fig_h), dpi=110)
    shown, shown_extent = _fit(img, cleaned, extent, 1210)
    ax.imshow(shown, origin="lower", extent=shown_extent, interpolation="nearest")
    ax.plot(poses[:, 0], poses[:, 1], "-", color="#1f5fbf", lw=0.8, alpha=0.7)
    # the object list: each movable object's footprint, outlined
    for o in cleaned.objects:
        if len(o.footprint) >= 3:
            ax.add_patch(Polygon(np.asarray(o.footprint), closed=True, fill=False, lw=0.7, ls="--",
                                 edgecolor=_OUTLINE))
    handles: list[Artist] = [Patch(facecolor=rgb01(c), edgecolor="0.6", label=k) for k, c in legend.items()]
    handles.append(plt.Line2D([], [], color="#1f5fbf", label="robot path"))
    if cleaned.objects:
        handles.append(Patch(fill=False, ls="--", lw=0.7, edgecolor=_OUTLINE, label="movable object"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    bar = 1.0 if w_m < 15 else 5.0
    ax.add_artist(AnchoredSizeBar(ax.transData, bar, f"{bar:g} m", "lower right", pad=0.4, frameon=True,
                                  size_vertical=spec.resolution * 2))
    ax.set_xlabel("x [m] (map frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(f"cleaned semantic map: {int(cleaned.occupied.sum())} occupied cells, "
                 f"{int(cleaned.semi_static.sum())} semi-static, {int(cleaned.dynamic_removed.sum())} dynamic "
                 f"removed, {len(cleaned.objects)} movable objects", fontsize=9)
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out / "semantic.png", bbox_inches="tight")
    plt.close(fig)

    # trajectory: the map-frame estimate and the wheel odometry, aligned at the first scan
    fig, ax = plt.subplots(figsize=(7, 6), dpi=100)
    grey, grey_extent = _grey(cleaned, extent, 700)
    ax.imshow(grey, origin="lower", extent=grey_extent, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    ax.plot(poses[:, 0], poses[:, 1], "-", color="#1f5fbf", lw=1.4,
            label=f"estimate ({outcome.config.registration.mode})")
    odom = outcome.odometry
    have = np.flatnonzero(np.isfinite(odom[:, 0]))
    if have.size:
        i0 = int(have[0])
        o_map = se2_compose(poses[i0], se2_between(odom[i0], odom[have]))
        ax.plot(o_map[:, 0], o_map[:, 1], "--", color="#f58231", lw=1.0, label="wheel odometry (aligned at start)")
    ax.plot(poses[0, 0], poses[0, 1], "s", color="#1f5fbf", label="start")
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="best")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("trajectory", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "report" / "trajectory.png")
    plt.close(fig)

    # painted hits by class and by mobility
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6), dpi=100, gridspec_kw={"width_ratios": [1, 2]})
    names = ["unknown", "static", "semi_static", "dynamic"]
    painting = outcome.summary.painting
    mobility_hits = np.array([painting.hits_by_mobility.get(k, 0) for k in names], np.int64)
    class_hits = np.array([painting.hits_by_class.get(k, 0) for k in class_names], np.int64)
    a1.bar(names, mobility_hits, color=[np.array(MOBILITY_COLORS[Mobility(i)]) / 255 for i in range(4)])
    a1.set_title("LiDAR hits by mobility", fontsize=9)
    a1.tick_params(axis="x", labelrotation=30, labelsize=8)
    idx = [i for i in np.argsort(class_hits)[::-1] if class_hits[i] > 0][:15]
    if idx:
        a2.barh([class_names[i] for i in idx][::-1], [class_hits[i] for i in idx][::-1],
                color=[np.array(class_color(class_names[i])) / 255 for i in idx][::-1])
    a2.set_title("LiDAR hits painted with an object class" if idx else "no object classes painted", fontsize=9)
    a2.set_xscale("log" if idx else "linear")
    fig.tight_layout()
    fig.savefig(out / "report" / "classes.png")
    plt.close(fig)
    pictures = {"semantic": "semantic.png", "trajectory": "report/trajectory.png", "classes": "report/classes.png"}
    fs = painting.frame_selection
    src = outcome.labels_from
    selected = fs is not None and (fs.select != "all" or fs.frames_skipped > 0)
    if fs is not None and selected and src is not None and src.size == len(poses):
        _frames_picture(out / "report" / "frames.png", cleaned, extent, poses, src, fs.select)
        pictures["frames"] = "report/frames.png"
    return pictures


def _frames_picture(path: Path, cleaned: CleanedMap, extent: tuple[float, float, float, float],
                    poses: NDArray[np.float64], labels_from: NDArray[np.uint8], select: str) -> None:
    """The robot's path, coloured by the share of its scans painted from a segmented frame over the last
    few metres (``segmentation.select``): where the model ran, and where earlier frames' labels served."""
    from matplotlib.collections import LineCollection

    fig, ax = plt.subplots(figsize=(9, 6), dpi=100)
    grey, grey_extent = _grey(cleaned, extent, 900)
    ax.imshow(grey, origin="lower", extent=grey_extent, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    fresh = (labels_from == 1).astype(np.float64)
    # the share over a window of about a metre of path (at least 5 scans), so a dense camera reads as well
    # as a sparse one
    step = np.r_[0.0, np.hypot(*np.diff(poses[:, :2], axis=0).T)]
    along = np.cumsum(step)
    lo = np.searchsorted(along, along - 0.5)
    hi = np.searchsorted(along, along + 0.5, side="right")
    lo, hi = np.minimum(lo, np.maximum(hi - 5, 0)), np.maximum(hi, np.minimum(lo + 5, len(along)))
    c = np.r_[0.0, np.cumsum(fresh)]
    share = (c[hi] - c[lo]) / np.maximum(hi - lo, 1)
    seg = np.stack([poses[:-1, :2], poses[1:, :2]], axis=1)
    lines = LineCollection(list(seg), cmap="plasma", norm=plt.Normalize(0.0, 1.0), linewidths=4.0)
    lines.set_array(share[1:])
    ax.add_collection(lines)
    bar = fig.colorbar(lines, ax=ax, fraction=0.035, pad=0.02, shrink=0.7)
    bar.set_label("share of scans painted from a segmented frame", fontsize=8)
    n1, n2 = int((labels_from == 1).sum()), int((labels_from == 2).sum())
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"where the model ran (segmentation.select: {select})\n{n1} scans painted from a segmented "
                 f"frame, {n2} from earlier frames' labels", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def write_report(path: Path, s: dict[str, Any], pictures: dict[str, str]) -> None:
    """A Markdown report a person reads."""
    m, c, t, th = s["map"], s["counts"], s["timings_s"], s["throughput"]
    lines = [
        "# semmap build report",
        "",
        f"Tour `{s['tour']['bag']}`" + (f" (scenario `{s['tour']['scenario']}`)" if s["tour"]["scenario"] else "")
        + f", {s['tour']['duration_s']:.1f} s, {c['scans']} scans.",
        "",
        f"![semantic map]({pictures['semantic']})",
        "",
        "## Map",
        "",
        "| | |",
        "|---|---|",
        f"| size | {m['size_m'][0]} m × {m['size_m'][1]} m ({m['size_cells'][0]} × {m['size_cells'][1]} cells at "
        f"{m['resolution']} m) |",
        f"| occupied cells | {m['occupied_cells']} |",
        f"| semi-static cells (flagged, kept as obstacles) | {m['semi_static_cells']} |",
        f"| dynamic cells removed | {m['dynamic_cells_removed']} |",
        f"| movable objects | {m['semi_static_objects']} "
        + ("(" + ", ".join(f"{k}: {v}" for k, v in sorted(m["semi_static_objects_by_class"].items())) + ")"
           if m["semi_static_objects_by_class"] else "") + " |",
        "",
        "## Trajectory",
        "",
        "Registration " + registration_line(s["registration"]) + ".",
        *(["", f"Loop closure: {loops_line(s['registration'])}."] if loops_line(s["registration"]) else []),
        "",
        *([f"Agreement of the scans with the map (no ground truth needed): {consistency_line(s['consistency'])}.",
           ""] if s.get("consistency") else []),
        f"![trajectory]({pictures['trajectory']})",
        "",
        "## Classes",
        "",
        f"Segmentation: backend `{s['painting']['backend']}`, class list `{s['painting']['class_list']}`; "
        f"{s['painting']['scans_painted']} of {c['scans']} scans had an image, "
        f"{100 * s['painting']['points_in_view_fraction']:.0f} % of their returns were in view.",
        "",
        _occlusion_line(s['painting'].get('occlusion_filter')),
        "",
        *([camera_line(s).capitalize() + ".", ""] if s['painting'].get('frame_selection') else []),
        *([f"![where the model ran]({pictures['frames']})", ""] if "frames" in pictures else []),
        f"![classes]({pictures['classes']})",
        "",
        "## Timings",
        "",
        "| stage | seconds |",
        "|---|---:|",
        *[f"| {k} | {v:.2f} |" for k, v in t.items() if isinstance(v, float)],
        "",
        "`loop` is the wall time of the streaming loop; with worker processes (`workers: "
        f"{str(t['workers']).lower()}`) fusion and segmentation run beside it (their busy time is listed).",
        "",
        f"Throughput: {th['scans_per_s']} scans/s through read, paint, register and fuse "
        f"({th['real_time_factor']}× real time); peak memory {s['peak_rss_mb']:.0f} MB in the main process"
        + ("" if not s.get("peak_rss_mb_workers") else ", " + ", ".join(
            f"{v:.0f} MB in the {k} worker" for k, v in s["peak_rss_mb_workers"].items())) + ".",
        "",
        _cpu_line(s.get("cpu_s")),
        "",
        *(["## Warnings", "", *[f"- {w}" for w in s["warnings"]], ""] if s.get("warnings") else []),
        "## Messages",
        "",
        "| topic | read | skipped |",
        "|---|---:|---:|",
        *[f"| {k} | {v} | {s['messages']['skipped'].get(k, 0)} |" for k, v in sorted(s["messages"]["read"].items())],
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")


def registration_line(r: dict[str, Any]) -> str:
    """How registration went, in words: ICP results used, rejected and failed, filter restarts."""
    mode = r["mode"]
    text = {"fused": "wheel odometry and KISS-ICP in an EKF", "icp": "KISS-ICP alone",
            "odometry": "wheel odometry alone"}.get(mode, mode)
    parts = []
    if mode != "odometry":
        over = r.get("icp_over_odometry", 0)
        parts.append(f"{r.get('icp_accepted', 0)} ICP results used" + (
            f" ({over} beyond the gate, fitting the map better than the odometry's prediction)" if over else ""))
        if mode == "fused":
            parts.append(f"{r.get('icp_rejected', 0)} rejected by the filter's gate")
        parts.append(f"{r.get('icp_failed', 0)} failed")
    if mode == "fused":
        n = r.get("filter_resets", 0)
        parts.append(f"the filter restarted {n} time{'s' if n != 1 else ''}")
    if r.get("icp_degenerate"):
        parts.append(f"{r['icp_degenerate']} degenerate matches (a corridor: odometry holds the direction along it)"
                     if mode == "fused" else f"{r['icp_degenerate']} degenerate matches (a corridor)")
    if r.get("odom_missing"):
        parts.append(f"{r['odom_missing']} scans without odometry")
    return f"{mode} ({text})" + (": " + ", ".join(parts) if parts else "")


def loops_line(r: dict[str, Any]) -> str | None:
    """What loop closure did, in words, from a build summary's ``registration`` (None: loop closure off)."""
    lc = r.get("loop_closure")
    if not lc:
        return None
    kept = len(lc.get("loops") or [])
    verified = lc.get("verified", 0)
    kf = lc.get("keyframes", 0)
    if kept:
        head = (f"{kept} loop{'s' if kept != 1 else ''} closed ({verified} places verified among {kf} keyframes), "
                f"largest correction {lc.get('max_correction_m', 0.0):.2f} m and "
                f"{math.degrees(lc.get('max_correction_rad', 0.0)):.1f}°")
    elif verified or lc.get("candidates", 0):  # (candidates all beyond the gate are not verified)
        head = f"no loop found ({verified} places verified among {kf} keyframes, none matched well enough)"
    else:
        head = f"no loop found (the tour came back to no place it had passed: {kf} keyframes)"
    refit = lc.get("rematched")  # (rematch_kept: the steps whose re-fit failed, the registration's kept)
    if refit:
        head += f"; {refit} of {max(lc.get('keyframes', 1) - 1, 1)} keyframe steps re-fitted to the keyframe before"
    return head


def camera_line(s: dict[str, Any]) -> str:
    """The model's work, from a build summary: frames segmented of those read, the selection, the scans
    labelled from earlier frames, and the share of the build spent waiting for the model."""
    fs = s["painting"]["frame_selection"]
    total = fs["frames_segmented"] + fs["frames_skipped"]
    t = s["timings_s"]
    loop = t.get("loop") or 0.0
    recorded = s["painting"].get("backend") in ("topic", "folder")  # label images, no model
    source = "the label images" if recorded else "the model"
    wait = f"; waiting for {source} {100 * t.get('wait_images', 0.0) / loop:.0f} % of the build" if loop > 0 else ""
    used = "label images used for" if recorded else "model ran on"
    line = f"{used} {fs['frames_segmented']} of {total} frames (select: {fs['select']}"
    line += f", at most {fs['max_rate']:g} a second" if fs.get("max_rate") else ""
    line += f", at most {fs['max_frames']} in all" if fs.get("max_frames") else ""
    line += f", at most {fs['max_seconds']:g} s of model time" if fs.get("max_seconds") else ""
    line += ")"
    if fs["scans_from_memory"]:
        line += f", {fs['scans_from_memory']} scans labelled from earlier frames"
    return line + wait


def consistency_line(c: dict[str, Any] | None) -> str:
    """The truth-free consistency score in words ('' for folders written before it existed)."""
    if not c:
        return ""
    return (f"{100 * c['endpoints_on_map']:.1f} % of {c['endpoints_sampled']} sampled returns within a cell of an "
            f"occupied cell; walls {100 * c['wall_thickness_m']:.1f} cm thick on average")


def _cpu_line(cpu: dict[str, float] | None) -> str:
    if not cpu:
        return ""
    parts = ", ".join(f"{k} {v:.2f} s" for k, v in cpu.items() if k not in ("total", "per_scan_ms"))
    return (f"CPU time of the loop: {parts}; {cpu['total']:.2f} s in all, {cpu['per_scan_ms']:.2f} ms per scan "
            "(with fewer cores than busy processes, the sum bounds the speed).")


def _occlusion_line(o: dict | None) -> str:
    if not o:
        return ""
    if not o["on"]:
        return "Occlusion filter: off (`paint.occlusion.filter: false`)."
    return (f"Occlusion filter: {o['points_relabelled']} points on a mask the camera could not see became unknown "
            f"({o['points_relabelled_per_painted_scan']} per painted scan, at most "
            f"{o['points_relabelled_max_per_scan']} in one scan; {o['scans_with_relabelled_points']} scans).")
