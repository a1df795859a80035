"""Comparing map folders across sessions (``semmap diff``): alignment, changes, updated maps."""
