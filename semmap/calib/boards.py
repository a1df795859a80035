"""Calibration boards: the ``--board`` SPEC syntax, detection in images, and board textures.

SPEC strings (sizes in metres)::

    chessboard:COLSxROWS:SQUARE                 inner corners, e.g. chessboard:11x8:0.02
    charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy]
                                                squares, e.g. charuco:5x7:0.04:0.03:4X4_50
    aruco:COLSxROWS:MARKER:SEPARATION:DICT      a grid of markers, e.g. aruco:5x7:0.04:0.01:4X4_50

``DICT`` is an OpenCV ArUco dictionary: ``4X4_50``, ``4X4_100``, ``4X4_250``, ``4X4_1000`` (the
4×4 family the research used), ``5X5_*``, ``6X6_*``, ``7X7_*``, ``ARUCO_ORIGINAL``,
``APRILTAG_36H11``…, with or without the ``DICT_`` prefix. ``legacy`` selects the ChArUco layout
of OpenCV < 4.6 (boards with an even number of rows printed by older tools).

Board frame: x along the columns, y along the rows, z = 0 on the board (z points into the
board for a board facing the camera). Detections give matched ``object_points`` (board
frame, m) and ``image_points`` (pixels).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal, cast

import cv2
import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError

__all__ = ["BoardDetection", "BoardSpec", "board_texture", "detect_board", "parse_board_spec"]

BoardKind = Literal["chessboard", "charuco", "aruco"]

_SPEC_HELP = ("expected chessboard:COLSxROWS:SQUARE, charuco:COLSxROWS:SQUARE:MARKER:DICT[:legacy] "
              "or aruco:COLSxROWS:MARKER:SEPARATION:DICT (sizes in metres)")


def _dictionary_id(name: str) -> int:
    key = name.strip().upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    value = getattr(cv2.aruco, key, None)
    if not isinstance(value, int):
        known = sorted(n[5:] for n in dir(cv2.aruco) if n.startswith("DICT_") and n.isupper())
        raise ConfigError(f"unknown ArUco dictionary {name!r} (known: {', '.join(known)})")
    return value


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board. ``cols × rows`` count inner corners (chessboard), squares (charuco)
    or markers (aruco). ``square_m`` is the square side (chessboard, charuco) or the marker
    side (aruco); ``marker_m`` the marker side (charuco) or the gap between markers (aruco)."""

    kind: BoardKind
    cols: int
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = ""
    legacy: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco", "aruco"):
            raise ConfigError(f"board: unknown kind {self.kind!r}; {_SPEC_HELP}")
        if self.cols < 2 or self.rows < 2:
            raise ConfigError(f"board: {self} needs at least 2×2")
        if not self.square_m > 0:
            raise ConfigError(f"board: {self}: sizes must be positive metres")
        if self.kind == "charuco":
            if not 0 < self.marker_m < self.square_m:
                raise ConfigError(f"board: {self}: the marker must be smaller than the square")
            _dictionary_id(self.dictionary)
        if self.kind == "aruco":
            if not self.marker_m > 0:
                raise ConfigError(f"board: {self}: the marker separation must be positive")
            _dictionary_id(self.dictionary)

    def __str__(self) -> str:
        if self.kind == "chessboard":
            return f"chessboard:{self.cols}x{self.rows}:{self.square_m:g}"
        extra = ":legacy" if self.legacy else ""
        return f"{self.kind}:{self.cols}x{self.rows}:{self.square_m:g}:{self.marker_m:g}:{self.dictionary}{extra}"

    # -- OpenCV objects ------------------------------------------------------------------
    def _cv_charuco(self) -> cv2.aruco.CharucoBoard:
        d = cv2.aruco.getPredefinedDictionary(_dictionary_id(self.dictionary))
        b = cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, d)
        b.setLegacyPattern(self.legacy)
        return b

    def _cv_grid(self) -> cv2.aruco.GridBoard:
        d = cv2.aruco.getPredefinedDictionary(_dictionary_id(self.dictionary))
        return cv2.aruco.GridBoard((self.cols, self.rows), self.square_m, self.marker_m, d)

    def object_points(self) -> NDArray[np.float64]:
        """All corner points of the board, (M, 3) in the board frame (m)."""
        if self.kind == "chessboard":
            j, i = np.mgrid[0:self.rows, 0:self.cols]
            return np.column_stack([i.ravel() * self.square_m, j.ravel() * self.square_m,
                                    np.zeros(i.size)])
        if self.kind == "charuco":
            return np.asarray(self._cv_charuco().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
        return np.asarray(self._cv_grid().getObjPoints(), dtype=np.float64).reshape(-1, 3)

    @property
    def size_m(self) -> tuple[float, float]:
        """Width and height of the printed pattern's outer edge (m)."""
        if self.kind == "chessboard":
            return ((self.cols + 1) * self.square_m, (self.rows + 1) * self.square_m)
        if self.kind == "charuco":
            return (self.cols * self.square_m, self.rows * self.square_m)
        return (self.cols * self.square_m + (self.cols - 1) * self.marker_m,
                self.rows * self.square_m + (self.rows - 1) * self.marker_m)

    @property
    def min_points(self) -> int:
        """Fewest matched points a detection needs to be used."""
        return self.cols * self.rows if self.kind == "chessboard" else 8


def parse_board_spec(spec: str | BoardSpec) -> BoardSpec:
    """Parse a ``--board`` SPEC (see the module docstring); errors name the bad part."""
    if isinstance(spec, BoardSpec):
        return spec
    parts = [p.strip() for p in str(spec).split(":")]
    kind = parts[0].lower()
    m = re.fullmatch(r"(\d+)[xX](\d+)", parts[1]) if len(parts) > 1 else None
    if kind not in ("chessboard", "checkerboard", "charuco", "aruco") or m is None:
        raise ConfigError(f"board {spec!r}: {_SPEC_HELP}")
    cols, rows = int(m.group(1)), int(m.group(2))

    def num(i: int, what: str) -> float:
        try:
            return float(parts[i])
        except (IndexError, ValueError):
            raise ConfigError(f"board {spec!r}: {what} missing or not a number; {_SPEC_HELP}") from None

    if kind in ("chessboard", "checkerboard"):
        if len(parts) != 3:
            raise ConfigError(f"board {spec!r}: {_SPEC_HELP}")
        return BoardSpec("chessboard", cols, rows, num(2, "square size"))
    if len(parts) not in (5, 6) or (len(parts) == 6 and parts[5].lower() != "legacy"):
        raise ConfigError(f"board {spec!r}: {_SPEC_HELP}")
    dict_name = parts[4].upper().removeprefix("DICT_")
    _dictionary_id(dict_name)
    if kind == "charuco":
        return BoardSpec("charuco", cols, rows, num(2, "square size"), num(3, "marker size"), dict_name,
                         legacy=len(parts) == 6)
    return BoardSpec("aruco", cols, rows, num(2, "marker size"), num(3, "marker separation"), dict_name)


@dataclass(frozen=True)
class BoardDetection:
    """A board found in one image: matched board-frame points (M, 3) and pixels (M, 2)."""

    object_points: NDArray[np.float64]
    image_points: NDArray[np.float64]
    ids: NDArray[np.int32] | None = None

    def __len__(self) -> int:
        return int(self.object_points.shape[0])


def _gray(image: NDArray[np.generic]) -> NDArray[np.uint8]:
    a = np.asarray(image)
    if a.dtype != np.uint8:
        # OpenCV takes dst=None as "allocate the output"; the stubs of some releases do not (the call goes through
        # Any, so that the type check passes with every release's stubs)
        a = cast(Any, cv2).normalize(a, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if a.ndim == 3:
        a = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY if a.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return cast("NDArray[np.uint8]", a)  # uint8 in, uint8 out: cv2's stubs carry no dtype


def detect_board(image: NDArray[np.generic], board: BoardSpec) -> BoardDetection | None:
    """Find the board in an image (grey or BGR); ``None`` if it is not there (or too little of it)."""
    gray = _gray(image)
    if board.kind == "chessboard":
        size = (board.cols, board.rows)
        flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY
        ok, corners = cv2.findChessboardCornersSB(gray, size, flags=flags)
        if not ok:
            ok, corners = cv2.findChessboardCorners(
                gray, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if not ok:
                return None
            corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                                       (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
        return BoardDetection(board.object_points(), corners.reshape(-1, 2).astype(np.float64))
    if board.kind == "charuco":
        charuco = board._cv_charuco()
        cc, ci, _, _ = cv2.aruco.CharucoDetector(charuco).detectBoard(gray)
        if ci is None or len(ci) < board.min_points:
            return None
        ids = ci.ravel().astype(np.int32)
        if charuco.checkCharucoCornersCollinear(ci):
            return None
        obj = np.asarray(charuco.getChessboardCorners(), dtype=np.float64)[ids]
        return BoardDetection(obj, cc.reshape(-1, 2).astype(np.float64), ids)
    grid = board._cv_grid()
    det = cv2.aruco.ArucoDetector(grid.getDictionary())
    params = det.getDetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det.setDetectorParameters(params)
    marker_corners, marker_ids, _ = det.detectMarkers(gray)
    if marker_ids is None or len(marker_ids) < 2:
        return None
    grid_obj, grid_img = grid.matchImagePoints(marker_corners, marker_ids)
    if grid_obj is None or len(grid_obj) < board.min_points:
        return None
    return BoardDetection(grid_obj.reshape(-1, 3).astype(np.float64), grid_img.reshape(-1, 2).astype(np.float64),
                          marker_ids.ravel().astype(np.int32))


def board_texture(board: BoardSpec, px_per_square: int = 40) -> tuple[NDArray[np.uint8], float, NDArray[np.float64]]:
    """A printable picture of the board with a white margin of one square.

    Returns the grey image, metres per pixel, and the board-frame (x, y) of the image's
    outer corner: pixel ``(c, r)`` covers board point ``offset + ((c, r) + 0.5) * metres_per_px``
    at its centre.
    """
    pps = int(px_per_square)
    mpp = board.square_m / pps
    core: NDArray[np.uint8]
    if board.kind == "chessboard":
        nx, ny = board.cols + 1, board.rows + 1
        j, i = np.mgrid[0:ny * pps, 0:nx * pps]
        sq = ((i // pps) + (j // pps)) % 2
        core = np.where(sq == 0, 0, 255).astype(np.uint8)
        origin = np.array([-board.square_m, -board.square_m])  # the outer corner of the pattern
    elif board.kind == "charuco":
        core = cast("NDArray[np.uint8]",  # a grey uint8 picture: cv2's stubs carry no dtype
                    board._cv_charuco().generateImage((board.cols * pps, board.rows * pps), marginSize=0,
                                                      borderBits=1))
        origin = np.zeros(2)
    else:
        # the grid board: markers of square_m with gaps of marker_m; keep an integer pixel pitch
        mpp = board.square_m / pps
        w = int(round((board.cols * board.square_m + (board.cols - 1) * board.marker_m) / mpp))
        h = int(round((board.rows * board.square_m + (board.rows - 1) * board.marker_m) / mpp))
        core = cast("NDArray[np.uint8]", board._cv_grid().generateImage((w, h), marginSize=0, borderBits=1))
        origin = np.zeros(2)
    margin = pps
    tex = cast("NDArray[np.uint8]", cv2.copyMakeBorder(core, margin, margin, margin, margin, cv2.BORDER_CONSTANT,
                                                       value=255))
    return tex, mpp, origin - margin * mpp
