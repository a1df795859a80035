"""``semmap diff``: what changed between sessions of one building.

:func:`diff` aligns session B's map onto session A's (no initial guess), classifies the changes
(static obstacles added or removed, movable objects moved, appeared or disappeared, floor newly
explored or no longer covered) and, given ``out``, writes the diff folder (see
:mod:`semmap.compare.write`). Exposed as ``semmap.diff``.
"""

from __future__ import annotations

from pathlib import Path

from .changes import CHANGE_TYPES, Change, ChangeSettings
from .result import DiffResult, diff_sessions
from .session import Session, open_session

__all__ = ["CHANGE_TYPES", "Change", "ChangeSettings", "DiffResult", "Session", "diff", "open_session", "write_diff",
           "write_update"]


def diff(a: str | Path | Session, b: str | Path | Session, *, out: str | Path | None = None,
         update: str | Path | None = None, force: bool = False, settings: ChangeSettings | None = None) -> DiffResult:
    """Compare session ``b`` with session ``a`` (map folders written by ``semmap build``, or any
    map_server maps). With ``out``, also write the diff folder there; with ``update``, also write
    A's map folder with B's changes applied (:mod:`semmap.compare.update`)."""
    from ..io.atomic import check_output

    inputs = [p.path if isinstance(p, Session) else Path(p) for p in (a, b)]
    if out is not None:  # refuse a bad output before any work
        check_output(out, force, marker="changes.json", inputs=inputs, what="diff folder")
    if update is not None:
        check_output(update, force, marker="summary.json", inputs=inputs, what="map folder")
    result = diff_sessions(a, b, settings=settings)
    if out is None and update is None:
        return result
    import contextlib

    from ..io.atomic import atomic_dir
    from .update import write_updated_map
    from .write import write_diff_files

    # both folders are written whole before either appears: an interruption leaves neither
    with contextlib.ExitStack() as stack:
        if update is not None:
            tmp_u = stack.enter_context(atomic_dir(update, force, marker="summary.json", inputs=inputs,
                                                   what="map folder"))
            write_updated_map(result, tmp_u)
        if out is not None:
            tmp_d = stack.enter_context(atomic_dir(out, force, marker="changes.json", inputs=inputs,
                                                   what="diff folder"))
            write_diff_files(result, tmp_d)
    return result


def write_update(result: DiffResult, out: str | Path, force: bool = False) -> Path:
    """Write A's map folder with ``result``'s changes applied at ``out``, whole or not at all."""
    from ..io.atomic import atomic_dir
    from .update import write_updated_map

    with atomic_dir(out, force, marker="summary.json", inputs=[result.a.path, result.b.path],
                    what="map folder") as tmp:
        write_updated_map(result, tmp)
    return Path(out)


def write_diff(result: DiffResult, out: str | Path, force: bool = False) -> Path:
    """Write ``result`` as a diff folder at ``out``, whole or not at all."""
    from ..io.atomic import atomic_dir
    from .write import write_diff_files

    inputs = [result.a.path, result.b.path]
    with atomic_dir(out, force, marker="changes.json", inputs=inputs, what="diff folder") as tmp:
        write_diff_files(result, tmp)
    return Path(out)
