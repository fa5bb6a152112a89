"""Board poses for a camera-projector calibration: chessboard corners in the camera and,
from the decoded phase, in the projector.

A pose is one placement of a flat chessboard, scanned with fringes in both directions
(columns, x_p, and rows, y_p). Its camera corners are found by OpenCV in the mean of
every phase-shift frame of both directions (the board as a camera sees it under uniform
light) and placed to sub-pixel by a model of the blurred corner
(:mod:`scanqa.calibration.corners`; ``corner_method="model"``, the default); or, with
``corner_method="opencv"``, by OpenCV's own sub-pixel search in the mean of the finest
column set. Its projector corners come from local homographies
(Moreno and Taubin [1]_): around each camera corner the decoded (x_p, y_p) of the valid
pixels within ``window_px`` are fitted by a homography of the camera pixels,
(x_p, y_p, 1) ~ H (u, v, 1), and the corner is mapped through it. The board is flat, so
within the window the camera-to-projector map is a homography up to the lenses'
distortion, and the fit averages the phase noise of a few thousand pixels into each
corner.

References
----------
.. [1] D. Moreno and G. Taubin, "Simple, Accurate, and Robust Projector-Camera
   Calibration", 3DIMPVT 2012, pp. 464-471, Sec. 3 (local homographies).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scanqa.calibration.corners import refine_corners
from scanqa.decoding.coding import GrayCodeSet, PatternDescription, ReferenceSet
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.patternset import read_pattern_images
from scanqa.errors import InputError

#: Half-width of the window of each local homography [camera px] (Moreno and Taubin use
#: 47 px on a 1600 x 1200 camera; the projector corners of the SLStudio board move by
#: < 0.02 px between 15 and 45 px).
WINDOW_PX = 30
#: Fewest valid pixels a local homography needs [-].
MIN_WINDOW_PIXELS = 50
#: Margin around the board's corners that is decoded [camera px].
CROP_MARGIN_PX = 60
#: Margin around the corners found at half size where they are sought again [px].
CORNER_MARGIN_PX = 40
#: Corner detectors: "opencv" (``findChessboardCornersSB`` with its sub-pixel flag, in the
#: finest column set's mean) and "model" (those corners placed by the blurred-corner model,
#: :mod:`scanqa.calibration.corners`, in the mean of every phase-shift frame).
CORNER_METHODS = ("opencv", "model")
#: Square sizes a printed or machined chessboard can have [mm].
SQUARE_RANGE_MM = (0.2, 500.0)


@dataclass(frozen=True)
class Board:
    """A chessboard: its inner corners (saddle points) and square size.

    Attributes
    ----------
    rows, columns : int
        Inner corners along the board's short and long side [-] (OpenCV's pattern size
        is (columns, rows)).
    square_mm : float
        Side of a square [mm].
    """

    rows: int
    columns: int
    square_mm: float

    def __post_init__(self) -> None:
        for name in ("rows", "columns"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 2):
                raise InputError(f"board {name} must be a whole number >= 2 of inner "
                                 f"corners, got {value!r}")
        if not (math.isfinite(self.square_mm) and self.square_mm > 0):
            raise InputError(f"board square_mm must be > 0, got {self.square_mm} [mm]")
        low, high = SQUARE_RANGE_MM
        if not low <= self.square_mm <= high:
            raise InputError(f"board square_mm {self.square_mm:g} mm is no chessboard's "
                             f"square ({low:g}-{high:g} mm): give the side of one square in mm")

    @property
    def object_points(self) -> np.ndarray:
        """(rows * columns, 3) float32 corners on the board, row by row, Z = 0 [mm]."""
        j, i = np.meshgrid(np.arange(self.columns), np.arange(self.rows))
        pts = np.zeros((self.rows * self.columns, 3), np.float32)
        pts[:, 0], pts[:, 1] = j.ravel() * self.square_mm, i.ravel() * self.square_mm
        return pts


@dataclass(frozen=True)
class BoardPose:
    """One pose: the board's corners in the camera and the projector.

    Attributes
    ----------
    name : str
        The pose (its folder's name).
    camera_px : (n, 2) float64
        Corners in the camera image, in :attr:`Board.object_points` order [camera px].
    projector_px : (n, 2) float64
        The same corners on the projector panel [projector px]; NaN where a window had
        too few decoded pixels.
    crop : (int, int, int, int)
        The decoded region (u0, v0, u1, v1) of the camera image [camera px].
    xp, yp : (v1 - v0, u1 - u0) float64
        Decoded projector column and row in the crop [projector px]; NaN where masked.
    camera_size : (int, int)
        Camera (width, height) [px].
    board : Board or None
        The board the corners belong to (its corner grid as found in the frames).
    """

    name: str
    camera_px: np.ndarray
    projector_px: np.ndarray
    crop: tuple
    xp: np.ndarray
    yp: np.ndarray
    camera_size: tuple
    board: Board | None = None


def _grey(image: np.ndarray) -> np.ndarray:
    """8-bit copy of an image stretched to its 99.5th percentile (dark captures too)."""
    image = np.nan_to_num(np.asarray(image, dtype=float))
    top = np.percentile(image, 99.5)
    return np.clip(image * (255.0 / top if top > 0 else 1.0), 0, 255).astype(np.uint8)


def corner_grid(image: np.ndarray) -> tuple[int, int] | None:
    """The inner-corner grid (rows, columns) of the chessboard in an image, or None.

    Parameters
    ----------
    image : (H, W) float
        The board under uniform light [DN], any range.

    Returns
    -------
    (int, int) or None
        Inner corners along the board's short and long side [-] (rows <= columns).

    Notes
    -----
    ``cv2.findChessboardCornersSBWithMeta`` with ``CALIB_CB_LARGER`` looks for a 4 x 4
    grid of saddle points at half size and grows it to every square it can follow;
    its meta array has the shape of the whole grid it found. No board size is given.
    """
    found = _grid_corners(_grey(image))
    return None if found is None else found[0]


def _grid_corners(grey: np.ndarray) -> tuple[tuple[int, int], np.ndarray] | None:
    """:func:`corner_grid` of an 8-bit image (:func:`_grey`) and the grid's corners at
    half size [half px], or None."""
    import cv2

    small = cv2.resize(grey, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(
        small, (4, 4), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_LARGER)
    if not found or meta is None:
        return None
    return (int(min(meta.shape)), int(max(meta.shape))), corners.reshape(-1, 2)


def find_corners(image: np.ndarray, board: Board, method: str = "opencv"
                 ) -> np.ndarray | None:
    """The board's inner corners in a grey image, or None when OpenCV finds no board.

    Parameters
    ----------
    image : (H, W) float
        The board under uniform light [DN], any range (stretched to its 99.5th
        percentile first: dark captures are found as well).
    board : Board
        What to look for.
    method : str
        "opencv" or "model" (``CORNER_METHODS``).

    Returns
    -------
    (n, 2) float64 or None
        Corners row by row [camera px].

    Notes
    -----
    ``cv2.findChessboardCornersSB`` finds the board in the image at half size, then
    again with its sub-pixel accuracy flag in the full-size region around it (three
    times faster than the whole image at full size, corners within 0.05 px of it on
    the SLStudio board but for one pose, 0.19 px). With ``method="model"`` each corner is
    then placed by the blurred-corner model
    (:func:`scanqa.calibration.corners.refine_corners`) fitted to the image itself, not
    the stretched copy OpenCV is given. On the SLStudio board the model's corners repeat
    between the column and the row frames of a pose to 0.014 px (OpenCV's own sub-pixel
    corners 0.031 px in the same images).
    """
    return _find_corners(image, board, method)


def _find_corners(image: np.ndarray, board: Board, method: str,
                  seen: tuple | None = None) -> np.ndarray | None:
    """:func:`find_corners`; ``seen``: the 8-bit image and the half-size corners of the
    board's grid where :func:`_grid_corners` found it already."""
    if method not in CORNER_METHODS:
        raise InputError(f"corner method must be one of {CORNER_METHODS}, got {method!r}")
    corners = _opencv_corners(image, board, seen)
    if corners is None or method == "opencv":
        return corners
    return refine_corners(np.nan_to_num(np.asarray(image, dtype=float)), corners,
                          board.rows, board.columns)


def _opencv_corners(image: np.ndarray, board: Board, seen: tuple | None = None
                    ) -> np.ndarray | None:
    """OpenCV's corners (``findChessboardCornersSB``, half size then the region) [px];
    ``seen`` as :func:`_find_corners`: the same corners at half size, only their
    bounding box is taken from them (the region)."""
    import cv2

    size, flags = (board.columns, board.rows), cv2.CALIB_CB_EXHAUSTIVE
    if seen is None:
        grey = _grey(image)
        found, rough = _half_size_corners(grey, size)
    else:
        (grey, rough), found = seen, True
    u0, v0, u1, v1 = (_crop(rough.reshape(-1, 2) * 2 + 0.5, grey.shape, 2 * CORNER_MARGIN_PX)
                      if found else (0, 0, grey.shape[1], grey.shape[0]))
    found_full, corners = cv2.findChessboardCornersSB(
        np.ascontiguousarray(grey[v0:v1, u0:u1]), size, flags=flags | cv2.CALIB_CB_ACCURACY)
    if found_full:
        return corners.reshape(-1, 2).astype(float) + np.array([u0, v0])
    if seen is not None:  # the fallback below needs the corners in the board's order
        found, rough = _half_size_corners(grey, size)
    if not found:
        return None
    # the board found at half size but not again at full size (rendered 1024 x 768 poses
    # of 31 px squares, issue 42's held-out scanner): the half-size corners, doubled and
    # placed by OpenCV's saddle-point search in the full image
    start = (rough.reshape(-1, 1, 2) * 2 + 0.5).astype(np.float32)
    half = max(2, int(0.25 * np.median(np.linalg.norm(np.diff(start[:size[0], 0], axis=0),
                                                      axis=1))))
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    return cv2.cornerSubPix(grey, start, (half, half), (-1, -1), criteria).reshape(
        -1, 2).astype(float)


def _half_size_corners(grey: np.ndarray, size: tuple[int, int]) -> tuple[bool, np.ndarray]:
    """``findChessboardCornersSB`` of the (columns, rows) grid at half size [half px]."""
    import cv2

    small = cv2.resize(grey, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    return cv2.findChessboardCornersSB(small, size, flags=cv2.CALIB_CB_EXHAUSTIVE)


def projector_corners(camera_px: np.ndarray, xp: np.ndarray, yp: np.ndarray,
                      offset: tuple[int, int] = (0, 0), window_px: int = WINDOW_PX
                      ) -> np.ndarray:
    """Projector coordinates of camera points through local homographies (module notes).

    Parameters
    ----------
    camera_px : (n, 2) float
        Points in the camera image [camera px].
    xp, yp : (H, W) float
        Decoded projector column and row of a region of the image, NaN where masked
        [projector px].
    offset : (int, int)
        (u, v) of the region's first pixel in the image [camera px].
    window_px : int
        Half-width of each window [camera px].

    Returns
    -------
    (n, 2) float64
        (x_p, y_p) of each point [projector px]; NaN where its window holds fewer than
        ``MIN_WINDOW_PIXELS`` valid pixels.
    """
    import cv2

    out = np.full((len(camera_px), 2), np.nan)
    height, width = xp.shape
    for n, (u, v) in enumerate(np.asarray(camera_px, dtype=float) - offset):
        r0, r1 = max(round(v) - window_px, 0), min(round(v) + window_px + 1, height)
        c0, c1 = max(round(u) - window_px, 0), min(round(u) + window_px + 1, width)
        rows, cols = np.mgrid[r0:r1, c0:c1]
        x, y = xp[r0:r1, c0:c1], yp[r0:r1, c0:c1]
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum() < MIN_WINDOW_PIXELS:
            continue
        src = np.column_stack([cols[ok] - u, rows[ok] - v]).astype(float)  # centred
        hom, _ = cv2.findHomography(src, np.column_stack([x[ok], y[ok]]), 0)
        if hom is not None and abs(hom[2, 2]) > 0:
            out[n] = hom[:2, 2] / hom[2, 2]
    return out


def decode_pose(folder: str | os.PathLike, columns: PatternDescription,
                rows: PatternDescription, board: Board | float,
                window_px: int = WINDOW_PX, corner_method: str = "model") -> BoardPose:
    """Find and decode one board pose.

    Parameters
    ----------
    folder : str or PathLike
        The pose's images, named as in the two descriptions' ``files``.
    columns, rows : PatternDescription
        What was projected: vertical fringes (x_p) and horizontal ones (y_p, with
        ``projector_width_px`` the panel's height); their file names are read in
        ``folder``.
    board : Board or float
        The chessboard; or its square size [mm], the corner grid then found in the
        frames (:func:`corner_grid`). A Board's grid is checked against the frames.
    window_px : int
        Half-width of the local homographies [camera px].
    corner_method : str
        The corner detector (``CORNER_METHODS``): "opencv" in the mean of the finest
        column set, "model" in the mean of every phase-shift frame (:func:`find_corners`).

    Returns
    -------
    BoardPose

    Raises
    ------
    InputError
        The descriptions have the wrong orientations, no board is found, or the board
        found is not the one given.
    """
    where = Path(folder)
    if columns.orientation != "vertical" or rows.orientation != "horizontal":
        raise InputError("the board's patterns: the first description must code columns "
                         "(orientation = \"vertical\"), the second rows (\"horizontal\"); "
                         f"got {columns.orientation!r} and {rows.orientation!r}")
    stacks = [read_pattern_images(replace(d, source=str(where / "patterns.toml")))
              for d in (columns, rows)]
    if corner_method == "model" or not columns.phase_sets:
        image = _offset_image(stacks, (columns, rows))
    else:
        finest = columns.sets.index(columns.phase_sets[-1])
        image = np.asarray(stacks[0][finest], dtype=float).mean(axis=0)
    grey = _grey(image)
    grid = _grid_corners(grey)
    board = _board_in(None if grid is None else grid[0], board, where)
    # the grid's own corners give the board's region when it is the board's whole grid
    seen = (grey, grid[1]) if grid is not None and grid[0] == (board.rows,
                                                                board.columns) else None
    corners = _find_corners(image, board, corner_method, seen)
    if corners is None:
        raise InputError(f"{where}: no {board.rows} x {board.columns} chessboard found "
                         "(check the board's corner counts and that the board is lit)")
    crop = _crop(corners, image.shape, CROP_MARGIN_PX)
    u0, v0, u1, v1 = crop
    maps = [decode_images(desc, [s[:, v0:v1, u0:u1] for s in stack]).xp
            for desc, stack in zip((columns, rows), stacks, strict=True)]
    proj = projector_corners(corners, *maps, offset=(u0, v0), window_px=window_px)
    return BoardPose(where.name, corners, proj, crop, maps[0], maps[1],
                     (image.shape[1], image.shape[0]), board)


def _offset_image(stacks: list, descriptions: tuple) -> np.ndarray:
    """The board under uniform light [DN]: the mean of every phase-shift frame of both
    directions (each N-step set's mean is its offset); without phase sets, the mean of
    the white frames of a reference set, else of every Gray-code frame (a bit and its
    inverse light every pixel once)."""
    frames = [np.asarray(stack[desc.sets.index(phase)], dtype=float)
              for stack, desc in zip(stacks, descriptions, strict=True)
              for phase in desc.phase_sets]
    if not frames:
        frames = [np.asarray(stack[k], dtype=float)[[i for i, level in enumerate(s.levels)
                                                     if level == "white"]]
                  for stack, desc in zip(stacks, descriptions, strict=True)
                  for k, s in enumerate(desc.sets) if isinstance(s, ReferenceSet)]
    if not frames:
        frames = [np.asarray(stack[k], dtype=float)
                  for stack, desc in zip(stacks, descriptions, strict=True)
                  for k, s in enumerate(desc.sets) if isinstance(s, GrayCodeSet)]
    return np.mean([f.mean(axis=0) for f in frames], axis=0)


def _board_in(grid: tuple[int, int] | None, board: Board | float, where: Path) -> Board:
    """The board of a pose: its grid found in the image (:func:`corner_grid`), checked
    against ``board`` when that is a Board."""
    if isinstance(board, Board):
        if grid is not None and grid != (board.rows, board.columns):
            hint = (" (rows first: the short side's inner corners, then the long side's)"
                    if grid == (board.columns, board.rows) else "")
            raise InputError(f"{where}: the frames show a chessboard of {grid[0]} x "
                             f"{grid[1]} inner corners, the board given says {board.rows} x "
                             f"{board.columns}{hint}: fix the board's corner count or leave "
                             "it out")
        return board
    if grid is None:
        raise InputError(f"{where}: no chessboard found in the frames (check that the "
                         "whole board is in view and lit)")
    return Board(grid[0], grid[1], float(board))


def _crop(corners: np.ndarray, shape: tuple[int, int], margin: int
          ) -> tuple[int, int, int, int]:
    """The corners' bounding box (u0, v0, u1, v1) with ``margin`` around, inside the
    image [px]."""
    lo = np.floor(corners.min(axis=0)).astype(int) - margin
    hi = np.ceil(corners.max(axis=0)).astype(int) + margin
    return (max(int(lo[0]), 0), max(int(lo[1]), 0), min(int(hi[0]), shape[1]),
            min(int(hi[1]), shape[0]))
