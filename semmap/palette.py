"""Colours for classes and mobility, shared by every picture semmap draws."""

from __future__ import annotations

import hashlib

from .records import Mobility

__all__ = ["MOBILITY_COLORS", "class_color", "rgb01"]

_FIXED: dict[str, tuple[int, int, int]] = {
    "person": (230, 25, 75),
    "chair": (0, 130, 200),
    "dining table": (170, 110, 40),
    "table": (170, 110, 40),
    "bed": (70, 240, 240),
    "couch": (145, 30, 180),
    "sofa": (145, 30, 180),
    "potted plant": (60, 180, 75),
    "tv": (255, 225, 25),
    "wall": (60, 60, 60),
    "pillar": (100, 100, 110),
    "cabinet": (128, 128, 0),
}

#: RGB per mobility value
MOBILITY_COLORS: dict[Mobility, tuple[int, int, int]] = {
    Mobility.UNKNOWN: (150, 150, 150),
    Mobility.STATIC: (40, 40, 40),
    Mobility.SEMI_STATIC: (245, 130, 48),
    Mobility.DYNAMIC: (230, 25, 75),
}


def rgb01(color: tuple[int, int, int]) -> tuple[float, float, float]:
    """An 8-bit RGB colour as matplotlib takes it: each channel in [0, 1]."""
    return (color[0] / 255, color[1] / 255, color[2] / 255)


def class_color(name: str) -> tuple[int, int, int]:
    """A stable RGB colour for a class name."""
    if name in _FIXED:
        return _FIXED[name]
    h = hashlib.md5(name.encode("utf-8")).digest()
    return (64 + h[0] % 192, 64 + h[1] % 192, 64 + h[2] % 192)
