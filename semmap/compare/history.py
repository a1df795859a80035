"""A building's change history: ``semmap diff S1 S2 S3 ...``.

Every session is aligned to the first (no initial guess each time), and each session is compared
with the one before it, through those alignments. Every change is then placed in the first
session's map frame, and changes at the same place (within ``same_place_m``; a move counts at both
its ends) are gathered into one *place* with the sessions in which it changed: a chair that left in
week 2 and came back in week 4 is one place changed twice.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..geometry import se2_apply, se2_compose, se2_inverse, wrap_angle
from .align import AlignInput, Alignment, align_maps
from .changes import CHANGE_TYPES, Change, ChangeSettings
from .result import DiffResult, diff_sessions
from .session import Session, distinct_names, open_session

__all__ = ["HistoryResult", "Place", "diff_history"]


@dataclass(frozen=True)
class Place:
    """Where something changed, in the first session's map frame, and in which sessions."""

    centroid: tuple[float, float]
    #: (session index, change as a dict in the first session's frame), in session order
    events: tuple[tuple[int, dict[str, Any]], ...]

    def as_dict(self, names: list[str]) -> dict[str, Any]:
        return {"centroid": [round(v, 3) for v in self.centroid],
                "changed_in": [names[k] for k, _ in self.events],
                "events": [{"session": names[k], **e} for k, e in self.events]}


@dataclass(frozen=True)
class HistoryResult:
    """The diffs of each session against the one before, and the places that changed."""

    sessions: tuple[Session, ...]
    #: each session's map frame in the first's (the first: identity)
    T_first: tuple[NDArray[np.float64], ...]
    #: ``steps[k - 1]``: session k against session k - 1 (in session k - 1's frame)
    steps: tuple[DiffResult, ...]
    places: tuple[Place, ...]
    seconds: float

    @property
    def names(self) -> list[str]:
        names = [s.name for s in self.sessions]
        return names if len(set(names)) == len(names) else [f"{k + 1}:{n}" for k, n in enumerate(names)]

    def as_dict(self) -> dict[str, Any]:
        from ..version import __version__

        names = self.names
        return {
            "semmap_version": __version__,
            "frame_id": f"map ({names[0]})",
            "sessions": [{"name": n, "path": str(s.path), "T_first": [round(float(v), 4) for v in t]}
                         for n, s, t in zip(names, self.sessions, self.T_first, strict=True)],
            "steps": [{"from": names[k], "to": names[k + 1], "counts": d.counts()} for k, d in enumerate(self.steps)],
            "places": [p.as_dict(names) for p in self.places],
            "seconds": round(self.seconds, 3),
        }


def _in_first(c: Change, t: NDArray[np.float64]) -> dict[str, Any]:
    """A change of a step (in the earlier session's frame), carried into the first session's frame."""
    d = c.as_dict()

    def move(xy: Any) -> list[float]:
        p = se2_apply(t, np.array([xy], np.float64))[0]
        return [round(float(p[0]), 3), round(float(p[1]), 3)]

    d["centroid"] = move(c.centroid)
    if c.from_xy is not None and c.to_xy is not None:
        d["from"], d["to"] = move(c.from_xy), move(c.to_xy)
    return d


def diff_history(paths: list[str | Path | Session], *, settings: ChangeSettings | None = None,
                 same_place_m: float = 0.5) -> HistoryResult:
    """Align every session to the first, compare each with the one before, gather the places."""
    t0 = time.perf_counter()
    sessions = distinct_names([p if isinstance(p, Session) else open_session(p) for p in paths])
    first = AlignInput.from_session(sessions[0])
    t_first = [np.zeros(3)]
    for s in sessions[1:]:
        t_first.append(np.asarray(align_maps(first, AlignInput.from_session(s)).T_a_b, np.float64))
    steps = []
    for k in range(1, len(sessions)):
        # session k in session k - 1's frame, through the first's
        t = se2_compose(se2_inverse(t_first[k - 1]), t_first[k])
        t = np.array([t[0], t[1], float(wrap_angle(t[2]))])
        steps.append(diff_sessions(sessions[k - 1], sessions[k], settings=settings, alignment=Alignment(t)))
    # the places: every change's ends, in the first frame, clustered
    events: list[tuple[int, dict[str, Any], list[NDArray[np.float64]]]] = []
    for k, d in enumerate(steps, start=1):
        for c in d.changes:
            if c.type in ("newly_explored", "no_longer_covered"):
                continue
            e = _in_first(c, t_first[k - 1])
            ends = [np.asarray(e["centroid"])] + ([np.asarray(e["from"])] if "from" in e else [])
            events.append((k, e, ends))
    places: list[tuple[list[NDArray[np.float64]], list[tuple[int, dict[str, Any]]]]] = []
    for k, e, ends in events:
        for pts, evs in places:
            if any(math.dist(a, b) <= same_place_m for a in ends for b in pts):
                pts.extend(ends)
                evs.append((k, e))
                break
        else:
            places.append((list(ends), [(k, e)]))
    order = {t: i for i, t in enumerate(CHANGE_TYPES)}
    out = []
    for pts, evs in places:
        c = np.mean(np.stack(pts), axis=0)
        evs.sort(key=lambda ke: (ke[0], order[ke[1]["type"]]))
        out.append(Place((float(c[0]), float(c[1])), tuple(evs)))
    out.sort(key=lambda p: (-len(p.events), p.events[0][0]))
    return HistoryResult(sessions, tuple(t_first), tuple(steps), tuple(out), time.perf_counter() - t0)


def write_history(h: HistoryResult, out: Path) -> None:
    """``history.json``, ``history.md``, and each step's diff folder under ``steps/``."""
    import json

    from .write import TYPE_LABELS, write_diff_files

    names = h.names
    (out / "steps").mkdir()
    for k, d in enumerate(h.steps, start=1):
        step = out / "steps" / f"{k:02d}_{names[k - 1]}_to_{names[k]}".replace("/", "_").replace(":", "_")
        step.mkdir()
        write_diff_files(d, step)
    (out / "history.json").write_text(json.dumps(h.as_dict(), indent=2), encoding="utf-8")
    lines = [f"# Change history: {', '.join(names)}", "",
             f"Every session aligned to `{names[0]}` and compared with the one before; positions in "
             f"`{names[0]}`'s map frame (m). Each step's diff folder is under `steps/`.", "",
             "| from | to | " + " | ".join(TYPE_LABELS[t] for t in CHANGE_TYPES) + " |",
             "|---|---|" + "---|" * len(CHANGE_TYPES)]
    for k, d in enumerate(h.steps):
        counts = d.counts()
        lines.append(f"| {names[k]} | {names[k + 1]} | " + " | ".join(str(counts[t]) for t in CHANGE_TYPES) + " |")
    lines += ["", "## Places that changed", "", "| place (x, y) | changed in | what |", "|---|---|---|"]
    for p in h.places:
        what = "; ".join(f"{names[k]}: {TYPE_LABELS[e['type']]}" + (f" ({e['class']})" if e.get("class") else "")
                         + (f", {e['displacement_m']:.2f} m" if "displacement_m" in e else "") for k, e in p.events)
        lines.append(f"| ({p.centroid[0]:.2f}, {p.centroid[1]:.2f}) | {', '.join(names[k] for k, _ in p.events)} | "
                     f"{what} |")
    (out / "history.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
