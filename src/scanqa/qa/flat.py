"""Flatness of a flat: least-squares and minimum-zone planes.

Least-squares flatness is the range (max - min) of the signed orthogonal distances from
the least-squares plane (:func:`scanqa.qa.planes.fit_plane`). Minimum-zone flatness is
the smallest distance between two parallel planes enclosing all points, so it never
exceeds the least-squares range.

The minimum zone is found exactly for a fixed frame and iterated over the frame: in the
frame of the current normal n (in-plane axes e1, e2, points (x, y, z)), the thinnest slab
of the form z = a x + b y + t measured along n is a linear program,

    min t_up - t_lo   subject to   t_lo <= z_i - a x_i - b y_i <= t_up,

solved with HiGHS by constraint generation (a few extreme points first, then the points
the solution violates, until none does: the LP optimum over all points). The normal is
then tilted to (-a, -b, 1) in that frame and the LP repeated until the tilt vanishes;
at that fixed point the orthogonal width has no descent direction. Starting from the
least-squares normal, this is the minimum zone of a flat patch whose extent is large
against its form deviation (the test compares it with the exact convex-hull search).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from scanqa.errors import InputError
from scanqa.qa.planes import fit_plane
from scanqa.qa.sphere import check_points

#: Points of each side that start the constraint generation [-].
_SEED = 64


@dataclass(frozen=True)
class ZonePlane:
    """Minimum-zone plane pair.

    Attributes
    ----------
    normal : (3,) float
        Common unit normal, oriented as the least-squares plane's (towards the camera) [-].
    lower, upper : float
        Offsets n . p of the two enclosing planes [mm].
    iterations : int
        Frames (outer iterations) used [-].
    """

    normal: np.ndarray
    lower: float
    upper: float
    iterations: int

    @property
    def width(self) -> float:
        """Minimum-zone flatness upper - lower [mm]."""
        return self.upper - self.lower


def _frame(normal: np.ndarray) -> np.ndarray:
    """Rows e1, e2, n: an orthonormal frame whose third axis is ``normal``."""
    e1 = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(normal, e1), normal])


def _slab_lp(xyz: np.ndarray, tol: float) -> tuple[float, float]:
    """Slopes (a, b) of the thinnest slab z = a x + b y + t over all local points xyz,
    by constraint generation."""
    x, y, z = xyz.T
    order = np.argsort(z)
    active = np.unique(np.concatenate([order[:_SEED], order[-_SEED:]]))
    for _ in range(100):
        xa, ya, za = x[active], y[active], z[active]
        one, zero = np.ones(active.size), np.zeros(active.size)
        a_ub = np.vstack([np.column_stack([-xa, -ya, -one, zero]),
                          np.column_stack([xa, ya, zero, one])])
        sol = linprog([0, 0, 1.0, -1.0], A_ub=a_ub, b_ub=np.concatenate([-za, za]),
                      bounds=[(-1, 1), (-1, 1), (None, None), (None, None)], method="highs")
        if sol.status != 0:
            raise InputError(f"flat: the minimum-zone linear program failed ({sol.message})")
        a, b = sol.x[:2]
        v = z - a * x - b * y
        up, lo = v[active].max(), v[active].min()  # the slab of these slopes, exactly
        over = np.flatnonzero((v > up + tol) | (v < lo - tol))
        if over.size == 0:
            return float(a), float(b)
        worst = over[np.argsort(-np.maximum(v[over] - up, lo - v[over]))][:4 * _SEED]
        active = np.union1d(active, worst)
    raise InputError("flat: the minimum-zone search did not converge")


def minimum_zone_plane(points, where: str = "flat", max_iter: int = 50) -> ZonePlane:
    """Minimum-zone plane pair: the thinnest slab of parallel planes enclosing the points.

    Parameters
    ----------
    points : (n, 3) float
        Points on a flat [mm], n >= 4.
    where : str
        Name used in messages.
    max_iter : int
        Most frames tried [-].

    Returns
    -------
    ZonePlane
        Its ``width`` is the minimum-zone flatness [mm].

    Notes
    -----
    The minimum-zone reference plane (MZPL) of ISO 12781-1:2011: the pair of parallel
    planes of least separation enclosing every point, min over n of (max_i p_i . n -
    min_i p_i . n); solved as a sequence of linear programs (module notes).
    """
    pts = check_points(points, where, 4)
    ls = fit_plane(pts, where)
    q = pts - ls.centroid
    normal = ls.normal
    tol = 1e-12 * max(float(np.abs(q).max()), 1.0)
    it, tilt = 0, math.inf
    while it < max_iter and tilt > 1e-13:
        it += 1
        frame = _frame(normal)
        a, b = _slab_lp(q @ frame.T, tol)
        normal = frame.T @ np.array([-a, -b, 1.0])
        normal /= np.linalg.norm(normal)
        tilt = max(abs(a), abs(b))
    h = pts @ normal
    return ZonePlane(normal, float(h.min()), float(h.max()), it)


def flatness(points, method: str = "least_squares", where: str = "flat") -> float:
    """Flatness of a set of points: range of distances to a plane [mm].

    Parameters
    ----------
    points : (n, 3) float
        Points [mm].
    method : {"least_squares", "minimum_zone"}
        Range of the signed orthogonal distances from the least-squares plane, or the
        width of the minimum zone.
    where : str
        Name used in messages.

    Returns
    -------
    float
        Flatness [mm].

    Notes
    -----
    Flatness as ISO 12781-1:2011 defines it: "least_squares" is max_i r_i - min_i r_i of
    the residuals from the least-squares plane (LSPL, the F of VDI/VDE 2634-2);
    "minimum_zone" is the width of the minimum-zone planes (MZPL), never larger.
    """
    if method == "least_squares":
        return float(np.ptp(fit_plane(check_points(points, where, 4), where).residuals))
    if method == "minimum_zone":
        return minimum_zone_plane(points, where).width
    raise InputError(f"{where}: method must be 'least_squares' or 'minimum_zone', "
                     f"got {method!r}")
