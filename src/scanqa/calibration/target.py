"""The marked calibration target: its print, and its detection in a marker frame.

The target is a chessboard larger than the camera's field of view, with three marker
dots in an L around its origin (OpenCV's "radon checkerboard", docs/calibration.rst,
"The marked target"). In one marker frame per stage position (a uniformly lit image,
:ref:`sweep-format`), :func:`detect_chessboard` finds the inner corners with
``cv2.findChessboardCornersSBWithMeta`` (sub-pixel, Duda & Frese 2018) and labels each
with its target coordinates from the dots, so that every position shares one target
frame however much of the board is in view. :mod:`scanqa.calibration.sweep_fit` fits the
camera and the stage to the labelled corners.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from scanqa.errors import InputError

#: Target kinds a sweep manifest may name.
TARGET_KINDS = ("chessboard",)
#: Smallest block of inner corners the detector accepts (columns, rows).
MIN_PATTERN = (5, 4)


@dataclass(frozen=True)
class ChessboardSpec:
    """The marked chessboard: square size, the marker cells and their dot radius.

    Cell (i, j) spans target x in [i, i + 1) and y in [j, j + 1) squares; it is white
    when i + j is even. Inner corner (i, j) lies at (i, j) x ``square_mm``. Each marker
    cell carries a dot of the opposite colour at its centre.

    Attributes
    ----------
    square_mm : float
        Side of a square [mm].
    marker_cells : tuple of (int, int)
        Cells carrying the dots (an L of three: its corner cell fixes the orientation).
    dot_radius : float
        Dot radius as a fraction of the square [-] (OpenCV's generator uses 0.17).
    """

    square_mm: float
    marker_cells: tuple = ((0, 0), (0, 1), (1, 1))
    dot_radius: float = 0.17

    def __post_init__(self) -> None:
        if not (isinstance(self.square_mm, (int, float)) and self.square_mm > 0):
            raise InputError(f"target square_mm must be > 0 mm, got {self.square_mm!r}")
        cells = tuple(tuple(int(v) for v in c) for c in self.marker_cells)
        if len(cells) != 3 or len(set(cells)) != 3:
            raise InputError(f"target marker_cells must be 3 distinct cells, got {cells}")
        object.__setattr__(self, "marker_cells", cells)

    def touches_marker(self, ij: np.ndarray) -> np.ndarray:
        """Whether inner corners (i, j) are corners of a marker cell, (n,) bool.

        Parameters
        ----------
        ij : (n, 2) int or float
            Corner indices (target coordinates / ``square_mm``) [-].
        """
        ij = np.asarray(ij, float).reshape(-1, 2)
        near = [np.all((ij >= np.array(c)) & (ij <= np.array(c) + 1), axis=1)
                for c in self.marker_cells]
        return np.any(near, axis=0)

    @staticmethod
    def is_white(i: int, j: int) -> bool:
        """Whether cell (i, j) is white."""
        return (i + j) % 2 == 0


@dataclass(frozen=True)
class Detection:
    """Labelled corners of one marker frame.

    Attributes
    ----------
    image_points : (n, 2) float
        Sensor coordinates, pixel centres at integers [px].
    target_points : (n, 2) float
        Target-plane coordinates of the same corners [mm].
    source : str
        The image, for messages.
    """

    image_points: np.ndarray
    target_points: np.ndarray
    source: str = ""


def _to_uint8(image: np.ndarray) -> np.ndarray:
    """Stretch an image to 8 bits between its 1st and 99th percentiles."""
    img = np.asarray(image, dtype=float)
    if img.ndim == 3:
        img = img.mean(axis=-1)
    lo, hi = np.percentile(img, [1.0, 99.0])
    scale = 255.0 / max(hi - lo, 1e-9)
    return np.clip((img - lo) * scale, 0, 255).astype(np.uint8)


def detect_chessboard(image: np.ndarray, spec: ChessboardSpec, source: str = ""
                      ) -> Detection:
    """Find and label the inner corners of the marked chessboard in one image.

    The eight corners of the three marker cells are left out: their dots break the point
    symmetry about the corner that the sub-pixel refinement relies on, and they come out
    biased by a large fraction of a pixel (0.4 px RMS on the average of 16 simulated
    frames of the sample camera with 2 mm squares, against 0.016 px for the other
    corners; docs/calibration.rst, "The marked target").

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        A uniformly lit frame of the target [DN].
    spec : ChessboardSpec
        The printed target.
    source : str
        Name of the image for messages.

    Returns
    -------
    Detection

    Raises
    ------
    InputError
        No chessboard found, or its marker dots not found or ambiguous.
    """
    import cv2

    img8 = _to_uint8(image)
    flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_MARKER | cv2.CALIB_CB_EXHAUSTIVE
    ok, corners, meta = cv2.findChessboardCornersSBWithMeta(img8, MIN_PATTERN, flags)
    if not ok or corners is None:
        raise InputError(f"{source or 'image'}: no marked chessboard found (need at least "
                         f"{MIN_PATTERN[0]} x {MIN_PATTERN[1]} inner corners and the three "
                         "marker dots in view, uniformly lit, in focus enough for the "
                         "squares to show)")
    grid = np.asarray(corners, float).reshape(*meta.shape, 2)
    valid = meta > 0
    dots, white = _dot_cells(np.asarray(img8, float), grid, valid)
    mapping = _label(dots, white, grid, valid, spec, source)
    rows, cols = np.nonzero(valid)
    ij = np.array([mapping(c, r) for r, c in zip(rows, cols, strict=True)], float)
    points, ok = refine_corners(image, grid[rows, cols], square_px(grid, valid))
    ok &= ~spec.touches_marker(ij)
    return Detection(points[ok], ij[ok] * spec.square_mm, source)


#: Gaussian pre-smoothing of the corner refinement [px] and its half window [px], at
#: most; both shrink with the board's squares (:data:`REFINE_REACH_PER_SQUARE`).
REFINE_SIGMA_PX, REFINE_HALF_WINDOW_PX = 1.5, 5
#: The smoothing's sigma and the half window as fractions of a square's side in the image
#: [-]: past them the refinement reaches the edges of the neighbouring squares (below).
REFINE_REACH_PER_SQUARE = (0.09, 0.45)


def square_px(grid: np.ndarray, valid: np.ndarray) -> float:
    """Median side of a square in the image: the distance between neighbouring corners
    of the detector's grid [px].

    Parameters
    ----------
    grid : (rows, cols, 2) float
        The detector's corners [px].
    valid : (rows, cols) bool
        Which of them were found.
    """
    steps = [np.linalg.norm(np.diff(grid, axis=a), axis=-1)[
        valid[1:] & valid[:-1] if a == 0 else valid[:, 1:] & valid[:, :-1]] for a in (0, 1)]
    steps = np.concatenate(steps)
    return float(np.median(steps)) if steps.size else math.inf


def refine_window(square: float = math.inf) -> tuple[float, int]:
    """The refinement's smoothing sigma [px] and half window [px] for squares of
    ``square`` px: :data:`REFINE_SIGMA_PX` and :data:`REFINE_HALF_WINDOW_PX`, reduced to
    :data:`REFINE_REACH_PER_SQUARE` of the square.

    Examples
    --------
    >>> refine_window(17.9), refine_window(8.9)
    ((1.5, 5), (0.801, 4))
    """
    sigma_rel, half_rel = REFINE_REACH_PER_SQUARE
    if not math.isfinite(square):
        return REFINE_SIGMA_PX, REFINE_HALF_WINDOW_PX
    return (min(REFINE_SIGMA_PX, round(sigma_rel * square, 3)),
            int(max(2, min(REFINE_HALF_WINDOW_PX, round(half_rel * square)))))


def refine_corners(image: np.ndarray, points: np.ndarray, square: float = math.inf
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel corners by ``cv2.cornerSubPix`` on the image smoothed by a Gaussian.

    The detector's own positions carry a bias that depends on where a corner falls
    within its pixel when the image is sharp (undersampled); smoothing first and refining
    by gradient orthogonality over a window removes most of it (on simulated frames of
    the sample camera, 0.08 -> 0.03 px RMS in focus; see docs/calibration.rst,
    "The marked target"); the fit removes the rest
    (:func:`scanqa.calibration.sweep_fit.pixel_locking`).

    The smoothing and the window are held to a fraction of the square
    (:func:`refine_window`): when they reach the edges of the neighbouring squares, whose
    distances differ on the two sides of a corner wherever perspective and distortion
    change the image's scale, each corner is pulled by the field's scale gradient - a
    smooth error the camera fit takes for focal length and k2 (on noise-free simulated
    frames of the sample camera with 2 mm squares of 8.4-9.5 px, sigma 1.5 px and a half
    window of 5 px gave f -0.029 px and k2 +0.36 for the true 0; docs/calibration.rst,
    "The marker fit's radial bias").

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The marker frame [DN].
    points : (n, 2) float
        Starting corners [px].
    square : float
        Side of a square in the image (:func:`square_px`) [px]; inf: the full window.

    Returns
    -------
    points : (n, 2) float
        Refined corners [px].
    ok : (n,) bool
        False where the refinement moved a corner by more than 1 px (not a corner).
    """
    import cv2
    from scipy.ndimage import gaussian_filter

    img = np.asarray(image, dtype=float)
    img = img.mean(axis=-1) if img.ndim == 3 else img
    sigma, half = refine_window(square)
    smooth = gaussian_filter(img, sigma).astype(np.float32)
    start = np.asarray(points, np.float32).reshape(-1, 1, 2).copy()
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    out = cv2.cornerSubPix(smooth, start.copy(), (half, half), (-1, -1), crit).reshape(-1, 2)
    ok = np.hypot(*(out - start.reshape(-1, 2)).T) < 1.0
    return out.astype(float), ok


def _sample(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of an image at (n, 2) points (u, v) [DN]."""
    import cv2

    m = pts.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(img.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).ravel()


def _dot_cells(img: np.ndarray, grid: np.ndarray, valid: np.ndarray
               ) -> tuple[list[tuple[int, int]], dict]:
    """Cells (col, row of their top-left corner) holding a dot, and each cell's colour."""
    quads = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
    rr, cc = np.nonzero(quads)
    if rr.size == 0:
        return [], {}
    c4 = np.stack([grid[rr, cc], grid[rr + 1, cc], grid[rr, cc + 1], grid[rr + 1, cc + 1]], 1)
    centre = c4.mean(axis=1)
    ring = _sample(img, (centre[:, None] + 0.35 * (c4 - centre[:, None])).reshape(-1, 2))
    level = ring.reshape(-1, 4).mean(axis=1)
    mid = _sample(img, centre)
    span = np.percentile(level, 95) - np.percentile(level, 5)
    is_white = level > 0.5 * (np.percentile(level, 95) + np.percentile(level, 5))
    dot = np.abs(mid - level) > 0.4 * span
    colours = {(int(c), int(r)): bool(w) for r, c, w in zip(rr, cc, is_white, strict=True)}
    return [(int(c), int(r)) for r, c in zip(rr[dot], cc[dot], strict=True)], colours


_ROTATIONS = [np.array(m) for m in itertools.product((-1, 0, 1), repeat=4)]
_ROTATIONS = [m.reshape(2, 2) for m in _ROTATIONS
              if abs(round(np.linalg.det(m.reshape(2, 2)))) == 1
              and (np.abs(m.reshape(2, 2)).sum(axis=0) == 1).all()
              and (np.abs(m.reshape(2, 2)).sum(axis=1) == 1).all()]


def _label(dots, colours, grid, valid, spec: ChessboardSpec, source: str):
    """The map (col, row) of the detector's grid -> target corner (i, j) (module notes)."""
    where = source or "image"
    if len(dots) != 3:
        raise InputError(f"{where}: found {len(dots)} marker dots, the target has 3 (are the "
                         "dots in view and the frame uniformly lit?)")
    want = sorted(spec.marker_cells)
    for m in _ROTATIONS:
        cells = []
        for c, r in dots:  # a cell's target index is the smallest of its mapped corners
            quad = [m @ (c + dc, r + dr) for dc in (0, 1) for dr in (0, 1)]
            cells.append(tuple(np.min(quad, axis=0)))
        off = np.subtract(want[0], sorted(cells)[0])
        if sorted(tuple(np.add(x, off)) for x in cells) != want:
            continue
        mapping = _mapper(m, off)
        if not _consistent(mapping, colours, grid, valid, spec):
            continue
        return mapping
    raise InputError(f"{where}: the three marker dots do not match the target's marker "
                     f"cells {spec.marker_cells} in any orientation")


def _mapper(m: np.ndarray, off: np.ndarray):
    def mapping(c: int, r: int) -> tuple[int, int]:
        i, j = m @ (c, r) + off
        return int(i), int(j)
    return mapping


def _consistent(mapping, colours: dict, grid: np.ndarray, valid: np.ndarray,
                spec: ChessboardSpec) -> bool:
    """A cell's colour matches the target (one cell fixes the parity) and the labelling
    is not mirrored."""
    first = next(iter(colours.items()), None)
    if first is not None:
        (c, r), white = first
        quad = [mapping(c + dc, r + dr) for dc in (0, 1) for dr in (0, 1)]
        i, j = np.min(quad, axis=0)
        if spec.is_white(int(i), int(j)) != white:
            return False
    rows, cols = np.nonzero(valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:])
    r, c = rows[0], cols[0]
    e_c, e_r = grid[r, c + 1] - grid[r, c], grid[r + 1, c] - grid[r, c]
    t_c = np.subtract(mapping(c + 1, r), mapping(c, r))
    t_r = np.subtract(mapping(c, r + 1), mapping(c, r))
    image_det = e_c[0] * e_r[1] - e_c[1] * e_r[0]
    target_det = t_c[0] * t_r[1] - t_c[1] * t_r[0]
    return image_det * target_det > 0  # seen from the front: no mirror
