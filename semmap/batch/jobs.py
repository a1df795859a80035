"""What one worker does for ``semmap batch``: build a tour, or diff it against the previous session.

Both functions take plain data and return plain data (a dict), so that they run the same in this
process and as Ray tasks on another machine. They never raise for a bad tour: the error's one line
goes in the result, and the batch goes on with the other tours. Only an interrupt (Ctrl-C,
SIGTERM, a cancelled Ray task) propagates; each output folder is written whole or not at all.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ..errors import SemmapError
from ..version import __version__
from .manifest import BuildJob

__all__ = ["MODEL_BACKENDS", "build_fingerprint", "diff_fingerprint", "job_from_dict", "run_build", "run_diff",
           "run_segment", "segmentation_backend"]

#: segmentation backends that run a model (the others read labels from the bag or a folder)
MODEL_BACKENDS = ("onnx", "ultralytics", "sam3", "mediapipe-selfie")

log = logging.getLogger(__name__)


def _file_digest(path: Path | None) -> str | None:
    if path is None:
        return None
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return "unreadable"


def _tree_stat(path: Path) -> list[Any]:
    """Name, size and modification time of a tour's files (a bag can be gigabytes: not hashed)."""
    try:
        if path.is_file():
            st = path.stat()
            return [[path.name, st.st_size, st.st_mtime_ns]]
        out = []
        for f in sorted(p for p in path.rglob("*") if p.is_file()):
            st = f.stat()
            out.append([str(f.relative_to(path)), st.st_size, st.st_mtime_ns])
        return out
    except OSError:
        return ["unreadable"]


def build_fingerprint(job: BuildJob) -> str:
    """What a tour's map depends on: semmap's version, the tour's files, the config and calibration."""
    data = {"semmap": __version__, "tour": str(job.tour), "files": _tree_stat(job.tour),
            "config": [str(job.config), _file_digest(job.config)],
            "calibration": [str(job.calibration), _file_digest(job.calibration)]}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]


def diff_fingerprint(job: BuildJob) -> str:
    """What a diff depends on: semmap's version and the two map folders' summaries."""
    parts = [__version__, str(job.previous)]
    for folder in (job.previous, job.out):
        parts.append(_file_digest(None if folder is None else folder / "summary.json") or "")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def job_to_dict(job: BuildJob) -> dict[str, Any]:
    return {k: (None if v is None else str(v)) for k, v in asdict(job).items()}


def job_from_dict(d: dict[str, Any]) -> BuildJob:
    def path(k: str) -> Path | None:
        return None if d.get(k) is None else Path(d[k])

    return BuildJob(site=str(d["site"]), name=str(d["name"]), tour=Path(d["tour"]), config=path("config"),
                    calibration=path("calibration"), previous=path("previous"), out=Path(d["out"]),
                    diff_out=Path(d["diff_out"]))


def _error_line(exc: BaseException) -> str:
    if isinstance(exc, SemmapError | OSError):
        return str(exc)
    return f"internal error: {type(exc).__name__}: {exc}"


def map_scores(summary: dict[str, Any]) -> dict[str, Any]:
    """The figures of a build's ``summary.json`` that a fleet report shows."""
    m = summary.get("map", {})
    c = summary.get("consistency") or {}
    return {
        "scans": summary.get("counts", {}).get("scans"),
        "duration_s": summary.get("tour", {}).get("duration_s"),
        "size_m": m.get("size_m"),
        "occupied_cells": m.get("occupied_cells"),
        "semi_static_objects": m.get("semi_static_objects"),
        "dynamic_cells_removed": m.get("dynamic_cells_removed"),
        "endpoints_on_map": c.get("endpoints_on_map"),
        "wall_thickness_m": c.get("wall_thickness_m"),
        "real_time_factor": summary.get("throughput", {}).get("real_time_factor"),
        "peak_rss_mb": summary.get("peak_rss_mb"),
        "warnings": len(summary.get("warnings") or []),
    }


def segmentation_backend(job: BuildJob) -> str:
    """The segmentation backend a tour's build runs (its config's), or "" when the config cannot be read
    (the build then fails and says why)."""
    from ..io.tour import load_build_config

    try:
        cfg, _ = load_build_config(job.config)
    except (SemmapError, OSError):
        return ""
    return str(cfg.segmentation.backend)


def run_segment(job_d: dict[str, Any]) -> dict[str, Any]:
    """Segment every camera image of a tour with its config's model into ``job_d["labels"]`` (label PNGs
    and classes.json, as ``semmap segment`` writes them), for its build to read with the folder
    backend: the model runs where this task runs (a GPU node), the mapping elsewhere."""
    from ..io.tour import load_build_config
    from ..segment.run import segment_source

    job = job_from_dict(job_d)
    labels = Path(job_d["labels"])
    t0 = time.perf_counter()
    out: dict[str, Any] = {"key": job.key, "kind": "segment", "fingerprint": build_fingerprint(job)}
    try:
        cfg, _ = load_build_config(job.config)
        res = segment_source(job.tour, labels, cfg.segmentation, overlays=False, force=labels.exists())
    except Exception as exc:
        log.debug("%s: segmentation failed", job.key, exc_info=True)
        return out | {"status": "failed", "error": _error_line(exc), "seconds": round(time.perf_counter() - t0, 2)}
    return out | {"status": "done", "error": None, "seconds": round(time.perf_counter() - t0, 2),
                  "images": res.images, "model_seconds": round(res.seconds, 2), "labels": str(labels)}


def _config_with_labels(job: BuildJob, labels: Path) -> Any:
    """The tour's config, its segmentation replaced by the labels a segmentation task wrote."""
    from ..config import FolderSegmentation
    from ..io.tour import load_build_config

    cfg, base = load_build_config(job.config)
    cal = cfg.calibration
    if cal is not None and not cal.expanduser().is_absolute():  # relative to the config file, as build reads it
        cal = base / cal.expanduser()
    seg = FolderSegmentation(folder=labels / "labels")
    return cfg.model_copy(update={"segmentation": seg, "calibration": cal})


def run_build(job_d: dict[str, Any]) -> dict[str, Any]:
    """Build one tour into its map folder (replacing an older one); the outcome as a dict. With
    ``job_d["labels"]`` the build reads the labels a segmentation task wrote instead of running the model."""
    from ..pipeline import build

    job = job_from_dict(job_d)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"key": job.key, "kind": "build", "fingerprint": build_fingerprint(job)}
    try:
        config = job.config if not job_d.get("labels") else _config_with_labels(job, Path(job_d["labels"]))
        result = build(job.tour, job.out, config=config, calibration=job.calibration,
                       force=job.out.exists())
    except Exception as exc:  # one tour's failure is reported, not raised: the batch goes on
        log.debug("%s failed", job.key, exc_info=True)
        return out | {"status": "failed", "error": _error_line(exc), "seconds": round(time.perf_counter() - t0, 2)}
    summary = result.summary.model_dump(mode="json")
    return out | {"status": "built", "error": None, "seconds": round(time.perf_counter() - t0, 2),
                  "scores": map_scores(summary), "warnings": summary.get("warnings") or []}


def run_diff(job_d: dict[str, Any]) -> dict[str, Any]:
    """Compare a tour's new map with its previous session into its diff folder; the outcome as a dict."""
    from ..compare import diff

    job = job_from_dict(job_d)
    t0 = time.perf_counter()
    out: dict[str, Any] = {"key": job.key, "kind": "diff", "fingerprint": diff_fingerprint(job)}
    assert job.previous is not None
    try:
        result = diff(job.previous, job.out, out=job.diff_out, force=job.diff_out.exists())
    except Exception as exc:
        log.debug("%s: diff failed", job.key, exc_info=True)
        return out | {"status": "failed", "error": _error_line(exc), "seconds": round(time.perf_counter() - t0, 2)}
    counts: dict[str, int] = {}
    for ch in result.changes:
        counts[ch.type] = counts.get(ch.type, 0) + 1
    return out | {"status": "done", "error": None, "seconds": round(time.perf_counter() - t0, 2),
                  "changes": counts, "semantic": result.semantic,
                  "alignment": result.alignment.as_dict(),
                  "warnings": result.warnings}
