"""``semmap batch``: build every tour of a manifest, diff each against its previous session, report.

The engine is Ray when it is installed (``pip install 'semmap[fleet]'``): each build is a Ray task,
each diff a task submitted once its build is done; with no address Ray starts on this machine,
with one (``ray://head:10001``, or ``auto`` for the cluster this machine belongs to) the same run
uses the cluster. Without Ray, the tours are built one after another in this process.

The output folder is resumable. ``report.json`` is rewritten after every finished job and
remembers what each map was built from (:func:`~semmap.batch.jobs.build_fingerprint`): a map folder
whose tour, config, calibration and semmap version have not changed is not built again, nor its diff;
a failed tour is tried again. A failed tour never stops the others.
"""

from __future__ import annotations

import contextlib
import json
import logging
import shutil
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..errors import ConfigError, Interrupted, OutputError
from ..io.atomic import atomic_file
from ..version import __version__
from .jobs import (
    MODEL_BACKENDS,
    build_fingerprint,
    diff_fingerprint,
    job_to_dict,
    run_build,
    run_diff,
    run_segment,
    segmentation_backend,
)
from .manifest import BuildJob, load_manifest

__all__ = ["BatchResult", "Engine", "run_batch"]

log = logging.getLogger(__name__)

Engine = Literal["auto", "ray", "local"]
#: what a job reports as it ends: (kind "build" or "diff", its result, jobs done, running, failed, total)
EventFn = Callable[[str, dict[str, Any], int, int, int, int], None]

REPORT_JSON = "report.json"
REPORT_MD = "report.md"
#: seconds a cancelled job gets to remove its half-written folder before its worker is stopped
_CANCEL_GRACE_S = 20.0


@dataclass
class BatchResult:
    """What :func:`run_batch` did: one row per tour (``build``, and ``diff`` where there is a previous
    session), the engine, and the paths of the report."""

    out: Path
    rows: list[dict[str, Any]]
    engine: str
    address: str | None
    workers: int | None
    seconds: float
    report_md: Path
    report_json: Path
    interrupted: bool = False
    failed: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failed and not self.interrupted


# ---------------------------------------------------------------------------------------------
# Engines: submit a job, take the next finished one


class _Local:
    """One job at a time, in this process."""

    name = "local"

    def __init__(self) -> None:
        self._queue: list[tuple[int, Callable[[dict[str, Any]], dict[str, Any]], dict[str, Any]]] = []
        self._n = 0

    def submit(self, fn: Callable[[dict[str, Any]], dict[str, Any]], arg: dict[str, Any]) -> int:
        self._n += 1
        self._queue.append((self._n, fn, arg))
        return self._n

    @property
    def running(self) -> int:
        return min(1, len(self._queue))

    @property
    def pending(self) -> int:
        return len(self._queue)

    def next_done(self) -> tuple[int, dict[str, Any]]:
        handle, fn, arg = self._queue.pop(0)
        return handle, fn(arg)

    def cancel_all(self) -> None:
        self._queue.clear()

    def close(self) -> None:
        pass


class _Ray:
    """Each job a Ray task; a local Ray started (and stopped) here unless ``address`` names a cluster."""

    name = "ray"

    def __init__(self, address: str | None, workers: int | None, cpus_per_job: float, gpus_per_job: float = 0.0,
                 gpus_per_segment: float = 0.0, local_gpus: float | None = None) -> None:
        import ray

        self._ray = ray
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "logging_level": logging.WARNING}
        if address is None:
            # a local Ray: the machine's cores (or --workers jobs at once); small messages only, so a
            # small object store (Ray's default takes 30 % of the RAM in /dev/shm)
            kwargs |= {"num_cpus": int(workers * cpus_per_job) if workers else None, "num_gpus": local_gpus,
                       "object_store_memory": 100 * 1024 * 1024}
        # Ray's driver installs its own SIGTERM handler (it exits 1 with a stack dump): ours, which stops
        # the jobs, cancels the tasks and shuts Ray down, is put back
        saved = {}
        if threading.current_thread() is threading.main_thread():
            saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
        # its note that a local Ray uses token authentication (the default) is not the user's concern
        quiet = logging.getLogger("ray._private.authentication.authentication_token_setup")
        level = quiet.level
        quiet.setLevel(logging.ERROR)
        try:
            ray.init(address=address, **kwargs)
        except Exception as exc:  # ConnectionError, RuntimeError...: no cluster there
            raise ConfigError(f"--address {address}: cannot start or reach Ray ({type(exc).__name__}: {exc})") \
                from None
        finally:
            quiet.setLevel(level)
            for sig, handler in saved.items():
                if handler is not None:
                    signal.signal(sig, self._noting(sig, handler))
        #: the last termination signal that arrived (Ray's blocking calls turn the exception our
        #: handler raises into a plain KeyboardInterrupt: this says which signal it was)
        self.signum: int | None = None
        # how many jobs run at once: the cluster's cores (and GPUs) over what each job asks for
        res = ray.cluster_resources()
        slots = float(res.get("CPU", 1.0)) / cpus_per_job
        if gpus_per_job > 0:
            slots = min(slots, float(res.get("GPU", 0.0)) / gpus_per_job)
        self._slots = max(int(slots), 1)
        # a task whose worker died (killed, out of memory) is tried once more; a tour that fails is not
        # a build that runs a segmentation model can ask for a GPU: Ray sends it to a node that has one
        self._build = ray.remote(num_cpus=cpus_per_job, num_gpus=gpus_per_job, max_retries=1,
                                 retry_exceptions=False)(run_build)
        self._diff = ray.remote(num_cpus=cpus_per_job, max_retries=1, retry_exceptions=False)(run_diff)
        self._segment = ray.remote(num_cpus=cpus_per_job, num_gpus=gpus_per_segment, max_retries=1,
                                   retry_exceptions=False)(run_segment)
        if gpus_per_segment > 0 and float(res.get("GPU", 0.0)) < gpus_per_segment:
            self.close()
            raise ConfigError(f"--gpus-per-segment {gpus_per_segment:g}: Ray sees {res.get('GPU', 0.0):g} GPUs "
                              f"{'in the cluster' if address else 'on this machine'}; the segmentation tasks "
                              "could never run")
        self._pending: set[Any] = set()

    def _noting(self, sig: int, handler: Any) -> Any:
        if not callable(handler):
            return handler

        def note(signum: int, frame: Any) -> None:
            self.signum = signum
            handler(signum, frame)

        return note

    def submit(self, fn: Callable[[dict[str, Any]], dict[str, Any]], arg: dict[str, Any]) -> Any:
        remote = self._build if fn is run_build else self._segment if fn is run_segment else self._diff
        ref = remote.remote(arg)
        self._pending.add(ref)
        return ref

    @property
    def running(self) -> int:
        """Jobs running now (the rest of :attr:`pending` wait for a free slot)."""
        return min(len(self._pending), self._slots)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def next_done(self) -> tuple[Any, dict[str, Any]]:
        ray = self._ray
        ready, _ = ray.wait(list(self._pending), num_returns=1)
        ref = ready[0]
        self._pending.discard(ref)
        try:
            return ref, ray.get(ref)
        except ray.exceptions.RayError as exc:  # the worker died (killed, out of memory) or was lost
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            return ref, {"status": "failed", "error": f"Ray: {type(exc).__name__}: {first}", "seconds": None}

    def cancel_all(self) -> None:
        ray = self._ray
        refs = list(self._pending)
        for ref in refs:
            with contextlib.suppress(Exception):
                ray.cancel(ref)  # KeyboardInterrupt in the task: its build removes its half-written folder
        if refs:
            with contextlib.suppress(Exception):
                ray.wait(refs, num_returns=len(refs), timeout=_CANCEL_GRACE_S)
        self._pending.clear()

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._ray.shutdown()


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


# ---------------------------------------------------------------------------------------------
# The run


def _read_previous(out: Path) -> dict[str, dict[str, Any]]:
    path = out / REPORT_JSON
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return {row["key"]: row for row in data.get("tours", [])}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        log.warning("%s: unreadable; every tour is built again", path)
        return {}


def _check_out(out: Path) -> bool:
    """``out`` must be new, empty, or an earlier batch's output. True when it is created here."""
    if not out.exists():
        return True
    if not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    if any(out.iterdir()) and not (out / REPORT_JSON).is_file():
        raise OutputError(f"{out}: not empty and not a semmap batch folder (no {REPORT_JSON}); choose another --out")
    return False


def run_batch(manifest: str | Path, out: str | Path, *, address: str | None = None, workers: int | None = None,
              engine: Engine = "auto", cpus_per_job: float = 1.0, gpus_per_job: float = 0.0,
              gpus_per_segment: float = 0.0, local_gpus: float | None = None,
              on_event: EventFn | None = None) -> BatchResult:
    """Build every tour of ``manifest`` into ``out`` and diff each against its previous session.

    ``engine``: ``ray`` (Ray must be installed), ``local`` (one after another in this process), or
    ``auto`` (Ray when installed). ``address``: a Ray cluster (``auto``, ``ray://host:10001``);
    None starts Ray on this machine. ``workers``: jobs at once on a local Ray (default: one per
    core, ``cpus_per_job`` cores each); ``gpus_per_job``: GPUs Ray reserves for each build (a
    build whose config runs a model on the GPU then goes to a node that has one); ``gpus_per_segment``:
    with more than 0, a tour whose config runs a segmentation model is segmented first in a task of its
    own asking for that many GPUs (into ``<site>/labels/<tour>``), and built from those labels in a
    task that asks for none, so the model runs on GPU nodes and the mapping on CPU nodes; ``local_gpus``:
    the GPUs a local Ray offers (default: those it detects). Finished map folders that are up to date
    are kept (see the module's documentation). ``on_event`` hears of each job as it ends.
    """
    t0 = time.perf_counter()
    out = Path(out).expanduser().resolve()
    _, jobs = load_manifest(manifest, out)
    created = _check_out(out)
    if workers is not None and address is not None:
        raise ConfigError(f"--workers {workers} with --address {address}: --workers sizes a local Ray; a cluster runs "
                          "as many jobs at once as its cores allow (--cpus-per-job)")
    if engine == "ray" and not ray_available():
        raise ConfigError("--engine ray: Ray is not installed (pip install 'semmap[fleet]')")
    use_ray = engine == "ray" or (engine == "auto" and ray_available())
    if address is not None and not use_ray:
        raise ConfigError(f"--address {address}: needs Ray (pip install 'semmap[fleet]')")
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if cpus_per_job <= 0:
        raise ConfigError(f"--cpus-per-job must be > 0, got {cpus_per_job}")
    for name, v in (("--gpus-per-job", gpus_per_job), ("--gpus-per-segment", gpus_per_segment)):
        if v < 0 or (v > 0 and not use_ray):
            raise ConfigError(f"{name} {v:g}: must be >= 0, and needs Ray")
    if not use_ray:
        log.info("%s: the %d tours are built one after another in this process",
                 "--engine local" if engine == "local" else "Ray is not installed", len(jobs))

    previous = _read_previous(out)
    rows: dict[str, dict[str, Any]] = {}
    to_build: list[BuildJob] = []
    to_diff: list[BuildJob] = []
    for job in jobs:
        row: dict[str, Any] = {"key": job.key, "site": job.site, "tour": job.name, "tour_path": str(job.tour),
                               "map": str(job.out), "previous": None if job.previous is None else str(job.previous)}
        old = previous.get(job.key, {})
        old_build = old.get("build") or {}
        if (old_build.get("status") in ("built", "up to date") and (job.out / "summary.json").is_file()
                and old_build.get("fingerprint") == build_fingerprint(job)):
            row["build"] = old_build | {"status": "up to date"}
            old_diff = old.get("diff") or {}
            if job.previous is not None:
                if (old_diff.get("status") in ("done", "up to date") and (job.diff_out / "changes.json").is_file()
                        and old_diff.get("fingerprint") == diff_fingerprint(job)):
                    row["diff"] = old_diff | {"status": "up to date"}
                else:
                    to_diff.append(job)
        else:
            to_build.append(job)
        rows[job.key] = row

    # tours whose model runs in a segmentation task of its own (on a GPU node), and the labels it leaves
    labels: dict[str, Path] = {}
    if gpus_per_segment > 0:
        labels = {j.key: out / j.site / "labels" / j.name for j in to_build
                  if segmentation_backend(j) in MODEL_BACKENDS}
    to_segment = []
    for job in to_build:
        if job.key not in labels:
            continue
        old_seg = (previous.get(job.key) or {}).get("segment") or {}
        if (old_seg.get("status") in ("done", "up to date") and old_seg.get("fingerprint") == build_fingerprint(job)
                and (labels[job.key] / "labels" / "classes.json").is_file()):
            rows[job.key]["segment"] = old_seg | {"status": "up to date"}  # its labels are there: build from them
        else:
            to_segment.append(job)
    total = (len(to_build) + len(to_diff) + len(to_segment) + sum(1 for j in to_build if j.previous is not None))
    done = failed = 0
    interrupted = False
    if local_gpus is not None and (address is not None or not use_ray or local_gpus < 0):
        raise ConfigError(f"--gpus {local_gpus:g}: the GPUs of a local Ray (not with --address), at least 0")
    runner: _Local | _Ray = (_Ray(address, workers, cpus_per_job, gpus_per_job, gpus_per_segment, local_gpus)
                             if use_ray else _Local())
    info = {"engine": runner.name, "address": address, "workers": workers}
    handles: dict[Any, tuple[str, BuildJob]] = {}
    fns = {"build": run_build, "diff": run_diff, "segment": run_segment}

    def submit(kind: str, job: BuildJob) -> None:
        arg = job_to_dict(job)
        if job.key in labels:
            arg["labels"] = str(labels[job.key])
        handles[runner.submit(fns[kind], arg)] = (kind, job)

    try:
        out.mkdir(parents=True, exist_ok=True)
        for job in to_build:
            submit("segment" if job in to_segment else "build", job)
        for job in to_diff:
            submit("diff", job)
        _write_reports(out, jobs, rows, info, time.perf_counter() - t0, final=False)
        while runner.pending:
            handle, res = runner.next_done()
            kind, job = handles.pop(handle)
            res = {k: v for k, v in res.items() if k not in ("key", "kind")}
            rows[job.key][kind] = res
            done += 1
            if res["status"] == "failed":
                failed += 1
                if kind == "segment":  # no labels, no map
                    rows[job.key]["build"] = {"status": "failed", "error": f"segmentation: {res['error']}",
                                              "seconds": None}
                    done += 1
                if kind in ("build", "segment") and job.previous is not None:
                    rows[job.key]["diff"] = {"status": "skipped", "error": "the build failed"}
                    done += 1
            elif kind == "segment":
                submit("build", job)
            elif kind == "build" and job.previous is not None:
                submit("diff", job)
            _write_reports(out, jobs, rows, info, time.perf_counter() - t0, final=False)
            if on_event is not None:
                on_event(kind, rows[job.key], done, runner.running, failed, total)
    except KeyboardInterrupt as exc:
        interrupted = True
        runner.cancel_all()
        signum = getattr(runner, "signum", None)
        if signum is not None and signum != signal.SIGINT and not isinstance(exc, Interrupted):
            raise Interrupted(signum) from None
        raise
    finally:
        runner.close()
        if interrupted:
            for row in rows.values():
                row.setdefault("build", {"status": "interrupted"})
            if created and not any(r["build"].get("status") in ("built", "up to date") for r in rows.values()):
                shutil.rmtree(out, ignore_errors=True)  # nothing was finished: leave nothing behind
            else:
                _write_reports(out, jobs, rows, info, time.perf_counter() - t0, final=True, interrupted=True)
    seconds = time.perf_counter() - t0
    _write_reports(out, jobs, rows, info, seconds, final=True)
    failed_keys = [k for k, r in rows.items()
                   if r["build"].get("status") == "failed" or (r.get("diff") or {}).get("status") == "failed"]
    return BatchResult(out, [rows[j.key] for j in jobs], runner.name, address, workers, seconds,
                       out / REPORT_MD, out / REPORT_JSON, failed=failed_keys)


# ---------------------------------------------------------------------------------------------
# Reports


def _write_reports(out: Path, jobs: list[BuildJob], rows: dict[str, dict[str, Any]], info: dict[str, Any],
                   seconds: float, final: bool, interrupted: bool = False) -> None:
    ordered = [rows[j.key] for j in jobs]
    data = {"semmap_version": __version__, "created_unix_s": round(time.time(), 3), "complete": final and not
            interrupted, "interrupted": interrupted, "seconds": round(seconds, 2), **info, "tours": ordered}
    with atomic_file(out / REPORT_JSON, force=True, what="batch report") as tmp:
        tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    with atomic_file(out / REPORT_MD, force=True, what="batch report") as tmp:
        tmp.write_text(report_markdown(data), encoding="utf-8")


def _fmt(v: Any, unit: str = "", digits: int = 1) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}f}{unit}"
    return f"{v}{unit}"


def _percent(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.1f} %"


def _cm(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.1f} cm"


def _changes_text(diff: dict[str, Any] | None) -> str:
    if not diff:
        return "–"
    status = diff.get("status")
    if status in ("failed", "skipped"):
        return f"{status}: {diff.get('error')}"
    if status in ("done", "up to date"):
        counts = diff.get("changes") or {}
        if not counts:
            return "no change"
        return ", ".join(f"{n} {t.replace('_', ' ')}" for t, n in sorted(counts.items()))
    return str(status)


def report_markdown(data: dict[str, Any]) -> str:
    """``report.md``: one row per tour, then the error of each failed one."""
    rows = data["tours"]
    n_failed = sum(1 for r in rows if (r.get("build") or {}).get("status") == "failed")
    state = "interrupted" if data.get("interrupted") else ("complete" if data.get("complete") else "running")
    lines = [
        "# semmap batch",
        "",
        f"{len(rows)} tours, {n_failed} failed; {state}; {data['seconds']:.0f} s with "
        f"{'Ray' if data['engine'] == 'ray' else 'one process'}"
        + (f" at {data['address']}" if data.get("address") else "")
        + (f", {data['workers']} workers" if data.get("workers") else "") + f"; semmap {data['semmap_version']}.",
        "",
        "| site | tour | status | time | scans | map (m) | occupied | movable objects | dynamic removed "
        "| returns on map | walls | changes since the previous session |",
        "|---|---|---|---:|---:|---|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        b = r.get("build") or {}
        s = b.get("scores") or {}
        size = s.get("size_m")
        lines.append(
            f"| {r['site']} | {r['tour']} | {b.get('status', 'waiting')} | {_fmt(b.get('seconds'), ' s')} "
            f"| {_fmt(s.get('scans'))} | {'–' if not size else f'{size[0]:.0f} × {size[1]:.0f}'} "
            f"| {_fmt(s.get('occupied_cells'))} | {_fmt(s.get('semi_static_objects'))} "
            f"| {_fmt(s.get('dynamic_cells_removed'))} "
            f"| {_percent(s.get('endpoints_on_map'))} | {_cm(s.get('wall_thickness_m'))} "
            f"| {_changes_text(r.get('diff'))} |")
    errors = [(r["key"], (r.get("build") or {}).get("error")) for r in rows if (r.get("build") or {}).get("error")]
    errors += [(r["key"] + " (diff)", r["diff"].get("error")) for r in rows
               if (r.get("diff") or {}).get("status") == "failed"]
    if errors:
        lines += ["", "## Failed", ""] + [f"- `{k}`: {e}" for k, e in errors]
    warned = [(r["key"], w) for r in rows for w in (r.get("build") or {}).get("warnings") or []]
    if warned:
        lines += ["", "## Warnings", ""] + [f"- `{k}`: {w}" for k, w in warned]
    return "\n".join(lines) + "\n"
