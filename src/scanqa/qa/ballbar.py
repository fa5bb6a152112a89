"""Ball bars: two spheres and the distance between their centres.

The centre distance L = |c_a - c_b| has, to first order (GUM), the variance

    u(L)^2 = g^T (Cov(c_a) + Cov(c_b)) g,   g = (c_a - c_b) / L,

with the two spheres' centre covariances from their own points (:mod:`scanqa.qa.sphere`,
noise-correlation factor included). The spheres are fitted independently, so their
covariances add; errors shared by both (a calibration table's scale error over the bar's
length) are not in u(L) and belong to the uncertainty budget of the caller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scanqa.errors import InputError
from scanqa.qa.ransac import find_spheres
from scanqa.qa.sphere import MIN_COVERAGE, Correlation, SphereFit, fit_sphere


@dataclass(frozen=True)
class BallBarFit:
    """Two fitted spheres and their centre distance.

    Attributes
    ----------
    sphere_a, sphere_b : SphereFit
        The two spheres (a: the one whose centre has the smaller x) [mm].
    distance : float
        Centre distance |c_a - c_b| [mm].
    u_distance : float
        Its standard uncertainty [mm] (module notes).
    """

    sphere_a: SphereFit
    sphere_b: SphereFit
    distance: float
    u_distance: float

    @property
    def direction(self) -> np.ndarray:
        """Unit vector from sphere a's centre to sphere b's [-]."""
        return (self.sphere_b.centre - self.sphere_a.centre) / self.distance


def centre_distance(a: SphereFit, b: SphereFit) -> tuple[float, float]:
    """Distance between two sphere centres and its standard uncertainty.

    Parameters
    ----------
    a, b : SphereFit
        Independently fitted spheres [mm].

    Returns
    -------
    distance : float
        [mm]
    u : float
        First-order standard uncertainty from both centre covariances [mm].

    Notes
    -----
    L = |c_a - c_b|; u(L)^2 = g^T (Cov(c_a) + Cov(c_b)) g with g = (c_a - c_b) / L, the
    first-order law of propagation of GUM 5.1.2 (Eq. 10) for the two independently fitted
    centres.
    """
    d = a.centre - b.centre
    length = float(np.linalg.norm(d))
    if length == 0:
        raise InputError("ball bar: the two spheres have the same centre (the same sphere "
                         "found twice?)")
    g = d / length
    var = g @ (a.covariance[:3, :3] + b.covariance[:3, :3]) @ g
    return length, float(math.sqrt(var))


def fit_ball_bar(points_a, points_b, sigma_a=None, sigma_b=None,
                 correlation: Correlation | None = None,
                 min_coverage: float = MIN_COVERAGE) -> BallBarFit:
    """Fit both spheres of a ball bar and their centre distance.

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        Points of each sphere [mm].
    sigma_a, sigma_b : (n,) float, optional
        Per-point standard deviations along the radial direction [mm].
    correlation : float, (4,) float or callable, optional
        Noise-correlation factor, as in :func:`scanqa.qa.sphere.fit_sphere` [-].
    min_coverage : float
        Least cap coverage of each sphere, fraction of a hemisphere [-].

    Returns
    -------
    BallBarFit

    Notes
    -----
    Two least-squares spheres (:func:`scanqa.qa.sphere.fit_sphere`) and their centre
    distance L = |c_a - c_b| with u(L) from :func:`centre_distance` (GUM 5.1.2, Eq. 10):
    the quantities of the sphere-spacing error SD of VDI/VDE 2634-2.
    """
    fits = [fit_sphere(p, s, correlation, min_coverage=min_coverage, where=f"ball bar sphere {w}")
            for p, s, w in ((points_a, sigma_a, "a"), (points_b, sigma_b, "b"))]
    fits.sort(key=lambda f: f.centre[0])
    return BallBarFit(fits[0], fits[1], *centre_distance(fits[0], fits[1]))


def find_ball_bar(points, diameter_mm: float, distance_mm: float | None = None,
                  distance_tol_mm: float | None = None, threshold_mm: float = 0.1,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Find the two spheres of a ball bar in a cloud (RANSAC with a radius prior).

    Parameters
    ----------
    points : (n, 3) float
        Cloud [mm].
    diameter_mm : float
        Nominal ball diameter [mm].
    distance_mm : float, optional
        Nominal centre distance [mm]; when given, the two spheres found must be that far
        apart within ``distance_tol_mm`` (default 2 % of it).
    distance_tol_mm : float, optional
        Accepted |distance - distance_mm| [mm].
    threshold_mm : float
        RANSAC inlier distance [mm].
    seed : int
        Random seed [-].

    Returns
    -------
    idx_a, idx_b : (m,) int
        Indices of each sphere's inliers, a the sphere with the smaller centre x [-].

    Raises
    ------
    InputError
        Fewer than two spheres found, or two spheres at the wrong distance.

    Notes
    -----
    RANSAC with a radius prior (:func:`scanqa.qa.ransac.find_spheres`; M. A. Fischler and
    R. C. Bolles (1981), Comm. ACM 24(6), 381-395); the two spheres found must lie
    |L - L_nominal| <= tol apart, tol = 2 % of L_nominal by default (scanqa's check,
    docs/artefacts.rst).
    """
    if not (math.isfinite(diameter_mm) and diameter_mm > 0):
        raise InputError(f"ball bar: the ball diameter must be > 0 mm, got {diameter_mm!r}")
    for name, value in (("nominal distance", distance_mm), ("distance tolerance",
                                                            distance_tol_mm)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"ball bar: the {name} must be finite and > 0 mm, got {value!r}")
    found = find_spheres(points, 2, diameter_mm / 2, what="ball bar",
                         threshold_mm=threshold_mm, seed=seed)
    found.sort(key=lambda s: s.centre[0])
    if distance_mm is not None:
        tol = 0.02 * distance_mm if distance_tol_mm is None else distance_tol_mm
        got = float(np.linalg.norm(found[0].centre - found[1].centre))
        if abs(got - distance_mm) > tol:
            raise InputError(
                f"ball bar: the two spheres found are {got:.2f} mm apart, the bar's nominal "
                f"distance is {distance_mm:g} mm (tolerance {tol:g} mm): one of them is not "
                "a ball of the bar; crop the scan to the bar or check the distance given")
    return found[0].inliers, found[1].inliers
