"""Sub-pixel chessboard corners from a model of the corner.

A chessboard's inner corner, seen by a camera, is two straight edges crossing at the
saddle point, the four quadrants alternately dark and bright, blurred by the lens. Around
a corner at (u0, v0), with the edges at angles theta_1, theta_2 and a Gaussian blur of
width s, the image is modelled as

    I(u, v) = m + a erf(d_1 / (sqrt(2) s)) erf(d_2 / (sqrt(2) s)),
    d_i = -(u - u0) sin(theta_i) + (v - v0) cos(theta_i),

(a Gaussian-blurred step across each edge; the product gives the chessboard's alternating
quadrants; m is the mean level and a the half contrast [DN]). The seven parameters are
fitted to the pixels within ``half_width_px`` of the corner by least squares (the corner's
position is where the two fitted edges cross, using every pixel along both edges, not the
image's gradient at a few pixels). Starting values: OpenCV's corner, the edge directions
from the neighbouring corners of the grid, s = 1.5 px.

The model holds where the edges are straight within the window (lens distortion and the
board's bow bend them by far less than a pixel over 25 px) and the print's squares meet
at a point.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erf

#: Half-width of the window fitted around each corner [camera px].
HALF_WIDTH_PX = 12
#: Starting blur width [camera px].
START_BLUR_PX = 1.5
#: A fitted corner further than this from its start is not trusted: the start is kept
#: [camera px].
MAX_SHIFT_PX = 2.0


def edge_directions(corners: np.ndarray, rows: int, columns: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Angles of the grid's two edge families at each corner, from its neighbours.

    Parameters
    ----------
    corners : (rows * columns, 2) float
        Corners row by row [camera px].
    rows, columns : int
        The grid [-].

    Returns
    -------
    (n,) float, (n,) float
        Angle of the edge along a row and along a column at each corner [rad].
    """
    grid = np.asarray(corners, dtype=float).reshape(rows, columns, 2)
    along_row = np.gradient(grid, axis=1).reshape(-1, 2)
    along_column = np.gradient(grid, axis=0).reshape(-1, 2)
    return (np.arctan2(along_row[:, 1], along_row[:, 0]),
            np.arctan2(along_column[:, 1], along_column[:, 0]))


def _model(p: np.ndarray, u: np.ndarray, v: np.ndarray, jacobian: bool = False):
    """The blurred corner (module notes) at pixels (u, v), and its Jacobian (n, 7)."""
    u0, v0, t1, t2, s, m, a = p
    du, dv = u - u0, v - v0
    sin1, cos1, sin2, cos2 = math.sin(t1), math.cos(t1), math.sin(t2), math.cos(t2)
    d1, d2 = -du * sin1 + dv * cos1, -du * sin2 + dv * cos2
    scale = math.sqrt(2.0) * s
    e1, e2 = erf(d1 / scale), erf(d2 / scale)
    if not jacobian:
        return m + a * e1 * e2
    g1 = 2 / math.sqrt(math.pi) * np.exp(-(d1 / scale) ** 2) / scale  # d e1 / d d1
    g2 = 2 / math.sqrt(math.pi) * np.exp(-(d2 / scale) ** 2) / scale
    jac = np.column_stack([
        a * (g1 * sin1 * e2 + e1 * g2 * sin2),
        -a * (g1 * cos1 * e2 + e1 * g2 * cos2),
        -a * g1 * (du * cos1 + dv * sin1) * e2,
        -a * e1 * g2 * (du * cos2 + dv * sin2),
        -a * (g1 * d1 * e2 + e1 * g2 * d2) / s,
        np.ones_like(du),
        e1 * e2])
    return jac


def fit_corner(image: np.ndarray, start: tuple[float, float], angles: tuple[float, float],
               half_width_px: int = HALF_WIDTH_PX) -> tuple[np.ndarray, float] | None:
    """One corner's position from the blurred-corner model (module notes).

    Parameters
    ----------
    image : (H, W) float
        The board under uniform light [DN].
    start : (float, float)
        A first position (u, v) of the corner [camera px].
    angles : (float, float)
        Directions of the two edges through it [rad].
    half_width_px : int
        Half-width of the fitted window [camera px].

    Returns
    -------
    ((2,) float64, float) or None
        The corner (u0, v0) [camera px] and the fitted blur width s [camera px]; None
        when the window leaves the image or the fit does not converge near the start.
    """
    from scipy.optimize import least_squares

    height, width = image.shape
    (iu, iv), h = (int(np.rint(x)) for x in start[:2]), half_width_px
    if iu - h < 0 or iv - h < 0 or iu + h >= width or iv + h >= height:
        return None
    v, u = (a.ravel().astype(float) for a in np.mgrid[iv - h:iv + h + 1, iu - h:iu + h + 1])
    values = np.asarray(image, dtype=float)[iv - h:iv + h + 1, iu - h:iu + h + 1].ravel()
    half = (values.max() - values.min()) / 2
    p0 = np.array([start[0], start[1], angles[0], angles[1], START_BLUR_PX, values.mean(),
                   half])
    flipped = p0.copy()
    flipped[6] = -half
    if np.sum((_model(flipped, u, v) - values) ** 2) < np.sum((_model(p0, u, v) - values) ** 2):
        p0 = flipped  # which quadrants are bright
    fit = least_squares(lambda p: _model(p, u, v) - values, p0, method="lm",
                        jac=lambda p: _model(p, u, v, jacobian=True),
                        x_scale=[1, 1, 0.1, 0.1, 1, 10, 10])
    shift = math.hypot(fit.x[0] - start[0], fit.x[1] - start[1])
    if not fit.success or shift > MAX_SHIFT_PX or not np.isfinite(fit.x).all():
        return None
    return fit.x[:2].copy(), float(abs(fit.x[4]))


def refine_corners(image: np.ndarray, corners: np.ndarray, rows: int, columns: int,
                   half_width_px: int = HALF_WIDTH_PX) -> np.ndarray:
    """A chessboard's corners placed by the blurred-corner model (module notes).

    Parameters
    ----------
    image : (H, W) float
        The board under uniform light [DN].
    corners : (rows * columns, 2) float
        The corners as first found (e.g. by OpenCV), row by row [camera px].
    rows, columns : int
        The grid of inner corners [-].
    half_width_px : int
        Half-width of each fitted window [camera px].

    Returns
    -------
    (rows * columns, 2) float64
        The refined corners [camera px]; a corner whose fit fails keeps its start.
    """
    corners = np.asarray(corners, dtype=float)
    out = corners.copy()
    first, second = edge_directions(corners, rows, columns)
    for n, start in enumerate(corners):
        fitted = fit_corner(image, start, (first[n], second[n]), half_width_px)
        if fitted is not None:
            out[n] = fitted[0]
    return out
