"""Orthogonal least-squares planes (the fit every QA quantity on a flat face rests on)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanqa.errors import InputError


@dataclass(frozen=True)
class PlaneFit:
    """Orthogonal least-squares plane: centroid [mm], unit normal (towards the camera)."""

    centroid: np.ndarray
    normal: np.ndarray
    residuals: np.ndarray  # signed orthogonal distances [mm]
    axes: np.ndarray       # (2, 3) in-plane unit vectors


def fit_plane(points: np.ndarray, where: str = "points") -> PlaneFit:
    """Fit a plane by orthogonal least squares (SVD of the centred points).

    Parameters
    ----------
    points : (n, 3) float
        Points [mm], n >= 3 and not collinear.
    where : str
        Name used in error messages.

    Returns
    -------
    PlaneFit
        Normal oriented towards the camera (the scanner origin).

    Notes
    -----
    The orthogonal (total) least-squares plane, the least-squares reference plane (LSPL) of
    ISO 12781-1:2011: centroid c = mean(p_i); normal n = the right singular vector of the
    centred points with the smallest singular value; residuals r_i = (p_i - c) . n.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise InputError(f"{where}: a plane needs at least 3 points, got {pts.shape[0]}")
    if not np.isfinite(pts).all():
        raise InputError(f"{where}: points with NaN or infinite coordinates")
    c = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - c, full_matrices=False)
    if s[1] <= 1e-9 * max(s[0], 1e-300):
        raise InputError(f"{where}: the points are collinear, no plane is defined")
    n = vt[2]
    if np.dot(n, -c) < 0:  # towards the camera at the origin
        n = -n
    return PlaneFit(c, n, (pts - c) @ n, vt[:2])


def plane_design(points: np.ndarray, fit: PlaneFit) -> np.ndarray:
    """The design of a plane's (offset, slope_1, slope_2) parameters at the points.

    Parameters
    ----------
    points : (n, 3) float
        Points [mm].
    fit : PlaneFit
        The plane.

    Returns
    -------
    (n, 3) float
        Columns 1, s_1, s_2: in-plane coordinates about the centroid along ``fit.axes``
        [-], [mm], [mm].

    Notes
    -----
    The plane as offset plus two slopes, h(s_1, s_2) = h_0 + a_1 s_1 + a_2 s_2 with
    s_k = (p - c) . e_k: the design matrix J of that linear model, whose covariance
    (J^T J)^-1 J^T Sigma J (J^T J)^-1 the QA propagates (GUM 5.2.2, Eq. 13, to first order).
    """
    d = np.asarray(points, dtype=float) - fit.centroid
    return np.column_stack([np.ones(len(d)), d @ fit.axes[0], d @ fit.axes[1]])
