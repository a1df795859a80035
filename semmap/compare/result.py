"""``semmap.diff``: compare two sessions, as a typed result."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..records import GridSpec
from .align import AlignInput, Alignment, align_maps
from .changes import CHANGE_TYPES, Change, ChangeSettings, LaidOut, classify_changes, lay_out
from .session import Session, distinct_names, open_session

__all__ = ["WALL_AGREEMENT", "DiffResult", "diff_sessions"]

#: below this share of B's walls on A's after alignment, the diff warns that its maps disagree
WALL_AGREEMENT = 0.85


@dataclass(frozen=True)
class DiffResult:
    """What changed from session A to session B, in A's map frame."""

    a: Session
    b: Session
    alignment: Alignment
    #: both sessions on one grid: A's, grown to hold B's cells
    laid_out: LaidOut
    changes: tuple[Change, ...]
    #: (H, W) uint8 on A's own grid (``a.spec``): 0 none, 1 added, 2 removed
    mask: NDArray[np.uint8]
    #: the same on the common grid (``laid_out.spec``)
    mask_common: NDArray[np.uint8]
    #: False when either side is a plain map_server map: geometry only, no object changes
    semantic: bool
    #: what was not reported and why: objects only one session could see, cells near people
    left_out: dict[str, int]
    settings: ChangeSettings
    seconds: float

    @property
    def warnings(self) -> list[str]:
        """What the user should know before trusting the changes."""
        out = []
        if self.alignment.inlier_fraction < WALL_AGREEMENT:
            out.append(f"the maps agree on only {self.alignment.inlier_fraction:.0%} of B's walls after alignment: "
                       "some changes may be mapping errors of either session (doubled or bent walls), not "
                       "changes of the building")
        return out

    @property
    def spec(self) -> GridSpec:
        """A's grid, the one :attr:`mask` is on."""
        return self.a.spec

    def counts(self) -> dict[str, int]:
        """Changes per type, every type listed."""
        return {t: sum(1 for c in self.changes if c.type == t) for t in CHANGE_TYPES}

    def of_type(self, kind: str) -> list[Change]:
        return [c for c in self.changes if c.type == kind]

    def as_dict(self) -> dict[str, Any]:
        """``changes.json``."""
        from ..version import __version__

        return {
            "semmap_version": __version__,
            "a": str(self.a.path),
            "b": str(self.b.path),
            "frame_id": "map (session A)",
            "semantic": self.semantic,
            "alignment": self.alignment.as_dict(),
            "warnings": self.warnings,
            "counts": self.counts(),
            "left_out": self.left_out,
            "settings": {k: getattr(self.settings, k) for k in self.settings.__dataclass_fields__},
            "seconds": round(self.seconds, 3),
            "changes": [c.as_dict() for c in self.changes],
        }


def diff_sessions(a: str | Path | Session, b: str | Path | Session, *, settings: ChangeSettings | None = None,
                  alignment: Alignment | None = None) -> DiffResult:
    """Compare session ``b`` with session ``a``: align B onto A (unless ``alignment`` is given), then
    classify what changed. ``a`` and ``b``: map folders, map_server YAMLs, or opened sessions."""
    t0 = time.perf_counter()
    sa, sb = distinct_names([a if isinstance(a, Session) else open_session(a),
                             b if isinstance(b, Session) else open_session(b)])
    st = settings or ChangeSettings()
    if alignment is None:
        alignment = align_maps(AlignInput.from_session(sa), AlignInput.from_session(sb))
    t = np.asarray(alignment.T_a_b, np.float64)
    lo = lay_out(sa, sb, t)
    changes, mask_common, left_out = classify_changes(sa, sb, lo, t, st)
    r0, c0, h, w = lo.a_window
    mask = np.ascontiguousarray(mask_common[r0:r0 + h, c0:c0 + w])
    return DiffResult(sa, sb, alignment, lo, tuple(changes), mask, mask_common, sa.semantic and sb.semantic,
                      left_out, st, time.perf_counter() - t0)
