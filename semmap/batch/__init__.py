"""``semmap batch``: a fleet's tours built, compared with their previous sessions, and reported.

>>> import semmap.batch                                                   # doctest: +SKIP
>>> r = semmap.batch.run_batch("fleet.yaml", "maps/2026-11-27")          # doctest: +SKIP
>>> r.ok, r.report_md                                                     # doctest: +SKIP
"""

from __future__ import annotations

from .manifest import BuildJob, Manifest, load_manifest
from .runner import BatchResult, run_batch

__all__ = ["BatchResult", "BuildJob", "Manifest", "load_manifest", "run_batch"]
