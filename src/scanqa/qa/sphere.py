"""Spheres: least-squares fit with GUM covariance, cap coverage and minimum-zone form.

The least-squares (Gaussian) sphere minimises the sum of squared orthogonal distances
r_i = |p_i - c| - R. It starts from the algebraic fit (|p|^2 = 2 c.p + R^2 - |c|^2, linear
in c and R^2 - |c|^2) and is refined by Gauss-Newton on the orthogonal distances. The fit
is unweighted, as VDI/VDE 2634-2 evaluates spheres; the per-point sigmas enter only its
covariance (first order, GUM):

    Cov(c, R) = B J^T diag(sigma_i^2) J B,   B = (J^T J)^-1,   J_i = (-u_i^T, -1),

with u_i the unit radial direction of point i and sigma_i its standard deviation along
u_i. Without sigmas, s^2 B with s^2 = sum r_i^2 / (n - 4). Neighbouring points of a scan
share noise (blur spreads one noise event over several pixels), which the formula above
ignores; a noise-correlation factor kappa >= 1 per parameter (or one for all) scales the
variances, given as a number or computed by a callable on the fit (see :func:`fit_sphere`).

Cap coverage. A scanner sees one side of a sphere: at most the hemisphere facing it
(less the rim, lost at grazing incidence). A small cap leaves the radius and the centre
along the view direction poorly separated (for a cap of half-opening theta covered
evenly, sigma_R grows as 1 / (1 - cos theta)). The check measures the solid angle the
points cover, seen from the fitted centre, as a fraction of a hemisphere's 2 pi sr: the
sphere around the cap axis (the mean direction of the points) is cut into equal-area
cells (rings equal in cos of the polar angle, sectors equal in azimuth; finer when there
are more points) and the occupied cells are counted. The fraction is 1 for a hemisphere
seen whole, 0.5 for a cap of half-opening 60 deg, 0.13 for 30 deg; it also catches a
stripe or an arc, whose half-opening may be wide while its solid angle is small.
``min_coverage`` (default 0.5) is the least accepted: half of the hemisphere a single
view could see at best.

Noise along the line of sight. A scanner's noise moves each point along its line of
sight, so it has a tangential part that the orthogonal residual ignores to first order
but that turns the radial directions u_i with the radial noise: the fit's normal
equations sum r_i u_i, and E[r_i u_i] != 0. The least-squares centre and radius are then
biased by b = -(J^T J)^-1 sum_i E[r_i g_i], g_i = (-u_i^T, -1), with

    E[r_i g_i] = sigma_i^2 / R (-(c_i l_perp,i + s_i^2 n_i / 2)^T, -s_i^2 / 2),

for a point with unit normal n_i, unit line of sight l_i, c_i = n_i . l_i, s_i^2 =
1 - c_i^2, l_perp,i = l_i - c_i n_i and line-of-sight sigma_i (second order in sigma; the
neglected terms shrink as 1/n). The bias does not shrink with the number of points: on a
cap seen from one side (radius and centre along the view direction nearly confounded) it
is about -0.3 um on R for sigma = 25 um and R = 12.7 mm (simulated), against a standard
uncertainty of 3 um at 400 points and 0.3 um at 40 000. :func:`sight_noise_bias` predicts
it; the fit does not correct it (the guideline's estimator is the least-squares sphere).

Minimum-zone (Chebyshev) form: the smallest radial width of two concentric spheres that
enclose all points, min over c of (max_i |p_i - c| - min_i |p_i - c|). Solved by
sequential linear programming with a trust region from the least-squares centre (each
step an exact LP on the linearised distances, by constraint generation, accepted only
when the true width drops), so the result is never wider than the least-squares range.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from scanqa.errors import InputError

#: Fewest points accepted for a sphere fit [-].
MIN_POINTS = 20
#: Least accepted cap coverage, as a fraction of a hemisphere's solid angle [-].
MIN_COVERAGE = 0.5

#: Points of each side that start the minimum-zone LP's constraint generation [-].
_ZONE_SEED = 64

#: A noise-correlation factor: a number, one per parameter (cx, cy, cz, R), or a callable
#: ``f(points, jacobian, residuals)`` returning either.
Correlation = float | np.ndarray | Callable[[np.ndarray, np.ndarray, np.ndarray], object]


@dataclass(frozen=True)
class SphereFit:
    """Least-squares sphere with its covariance.

    Attributes
    ----------
    centre : (3,) float
        Centre [mm].
    radius : float
        Radius [mm].
    residuals : (n,) float
        Signed orthogonal distances |p_i - c| - R, positive outside [mm].
    covariance : (4, 4) float
        Covariance of (cx, cy, cz, R) [mm^2], correlation factor included.
    sigma_source : str
        "points" (from the per-point sigmas) or "residuals" (from their scatter).
    correlation : (4,) float
        Noise-correlation factor applied to each parameter's variance [-].
    coverage : float
        Solid angle covered, as a fraction of a hemisphere [-] (module notes).
    half_angle_deg : float
        Half-opening of the cap around its axis (99th percentile) [deg].
    axis : (3,) float
        Cap axis: unit mean direction from the centre to the points [-].
    iterations : int
        Gauss-Newton iterations [-].
    """

    centre: np.ndarray
    radius: float
    residuals: np.ndarray
    covariance: np.ndarray
    sigma_source: str
    correlation: np.ndarray
    coverage: float
    half_angle_deg: float
    axis: np.ndarray
    iterations: int

    @property
    def n_points(self) -> int:
        """Number of points fitted [-]."""
        return int(self.residuals.size)

    @property
    def diameter(self) -> float:
        """Diameter 2 R [mm]."""
        return 2.0 * self.radius

    @property
    def u_radius(self) -> float:
        """Standard uncertainty of the radius [mm]."""
        return float(math.sqrt(self.covariance[3, 3]))

    @property
    def u_centre(self) -> np.ndarray:
        """Standard uncertainties of the centre's coordinates [mm]."""
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def rms(self) -> float:
        """Root mean square of the residuals [mm]."""
        return float(np.sqrt(np.mean(self.residuals**2)))


@dataclass(frozen=True)
class MinimumZoneSphere:
    """Minimum-zone (Chebyshev) sphere: the thinnest concentric shell holding the points.

    Attributes
    ----------
    centre : (3,) float
        Common centre of the two spheres [mm].
    r_inner, r_outer : float
        Radii of the inscribed and circumscribed spheres [mm].
    iterations : int
        Linear programs solved [-].
    """

    centre: np.ndarray
    r_inner: float
    r_outer: float
    iterations: int

    @property
    def width(self) -> float:
        """Minimum-zone form deviation r_outer - r_inner [mm]."""
        return self.r_outer - self.r_inner


def check_points(points, where: str, min_points: int) -> np.ndarray:
    """Points as an (n, 3) float array, or one clear error.

    Parameters
    ----------
    points : (n, 3) float
        Points [mm].
    where : str
        What they are, for messages.
    min_points : int
        Fewest accepted [-].
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{where}: points must be an (n, 3) array [mm], got shape {pts.shape}")
    bad = int(np.sum(~np.isfinite(pts).all(axis=1)))
    if bad:
        raise InputError(f"{where}: {bad} of {len(pts)} points are not finite (NaN or inf); "
                         "drop them before the fit")
    if len(pts) < min_points:
        raise InputError(f"{where}: {len(pts)} points, a fit needs at least {min_points}: "
                         "check the selection (region, radius prior) or the scan")
    return pts


def algebraic_sphere(points) -> tuple[np.ndarray, float]:
    """Algebraic sphere fit, the start of the geometric fit.

    Solves |p|^2 = 2 c.p + d in least squares (linear in c and d = R^2 - |c|^2), on
    coordinates centred on the points' mean for conditioning.

    Parameters
    ----------
    points : (n, 3) float
        Points [mm], n >= 4, not coplanar.

    Returns
    -------
    centre : (3,) float
        [mm]
    radius : float
        [mm]

    Raises
    ------
    InputError
        Fewer than 4 points, a NaN or infinite point, or points on no sphere.

    Notes
    -----
    The algebraic (Kasa) fit: |q_i|^2 = 2 c . q_i + d in least squares, q_i = p_i - mean(p),
    R = sqrt(d + |c|^2) (I. Kasa (1976), IEEE Trans. Instrum. Meas. 25, 8-14). It minimises
    the algebraic, not the orthogonal, distance; :func:`fit_sphere` starts from it.
    """
    pts = check_points(points, "sphere", 4)
    m = pts.mean(axis=0)
    q = pts - m
    a = np.column_stack([2.0 * q, np.ones(len(q))])
    sol, *_ = np.linalg.lstsq(a, np.sum(q**2, axis=1), rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    if not np.isfinite(r2) or r2 <= 0:
        raise InputError("sphere: the points do not define a sphere (algebraic fit failed); "
                         "are they coplanar?")
    return c + m, float(math.sqrt(r2))


def _gauss_newton(pts: np.ndarray, c: np.ndarray, r: float, where: str,
                  max_iter: int = 50) -> tuple[np.ndarray, float, int]:
    """Orthogonal-distance refinement; pts centred on their mean [mm]."""
    for it in range(1, max_iter + 1):
        d = pts - c
        dist = np.linalg.norm(d, axis=1)
        jac = np.column_stack([-d / dist[:, None], -np.ones(len(d))])
        step, *_ = np.linalg.lstsq(jac, -(dist - r), rcond=None)
        c, r = c + step[:3], r + step[3]
        if not (np.all(np.isfinite(step)) and r > 0):
            break
        if np.max(np.abs(step)) <= 1e-12 * max(r, 1.0):
            return c, float(r), it
    if not (np.all(np.isfinite(c)) and np.isfinite(r) and r > 0):
        raise InputError(f"{where}: the sphere fit diverged; the points are not on a sphere")
    return c, float(r), max_iter


def cap_coverage(points, centre) -> tuple[float, float, np.ndarray]:
    """Solid angle covered by the points seen from a centre, as a fraction of a hemisphere.

    Parameters
    ----------
    points : (n, 3) float
        Points [mm].
    centre : (3,) float
        Sphere centre [mm].

    Returns
    -------
    coverage : float
        Occupied equal-area cells x their solid angle / (2 pi) [-] (module notes).
    half_angle_deg : float
        99th percentile of the polar angle around the cap axis [deg].
    axis : (3,) float
        Cap axis (unit mean direction) [-].

    Raises
    ------
    InputError
        No points, or a NaN or infinite point or centre.

    Notes
    -----
    coverage = (occupied cells) / cells^2: the unit directions u_i = (p_i - c) / |p_i - c|
    binned into ``cells`` rings equal in cos theta and ``cells`` sectors in azimuth around
    the cap axis, each cell 2 pi / cells^2 sr; a hemisphere holds cells^2 of them. scanqa's
    own check (module notes, docs/artefacts.rst); for an evenly covered cap of half-opening
    theta it tends to 1 - cos theta.
    """
    centre = np.asarray(centre, dtype=float)
    if centre.shape != (3,) or not np.isfinite(centre).all():
        raise InputError(f"sphere: the centre must be 3 finite coordinates [mm], got {centre}")
    u = check_points(points, "sphere", 1) - centre
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    mean = u.mean(axis=0)
    axis = mean / np.linalg.norm(mean) if np.linalg.norm(mean) > 0 else np.array([0, 0, 1.0])
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.clip(u @ axis, -1.0, 1.0)
    cells = int(np.clip(math.isqrt(len(u) // 4), 2, 16))  # rings (and sectors) per hemisphere
    ring = np.minimum(((1.0 - t) * cells).astype(int), 2 * cells - 1)
    sector = ((np.arctan2(u @ e2, u @ e1) + np.pi) / (2 * np.pi) * cells).astype(int) % cells
    occupied = np.unique(ring * cells + sector).size
    half = float(np.degrees(np.arccos(np.quantile(t, 0.01))))
    return occupied / cells**2, half, axis


def _correlation_factor(correlation, pts, jac, res) -> np.ndarray:
    value = correlation(pts, jac, res) if callable(correlation) else correlation
    kappa = np.broadcast_to(np.asarray(1.0 if value is None else value, dtype=float), (4,))
    if not np.all(np.isfinite(kappa) & (kappa > 0)):
        raise InputError(f"sphere: the noise-correlation factor must be finite and > 0, "
                         f"got {kappa}")
    return kappa.copy()


def _covariance(jac: np.ndarray, res: np.ndarray, sigma) -> tuple[np.ndarray, str]:
    bread = np.linalg.inv(jac.T @ jac)
    if sigma is None:
        s2 = float(res @ res) / max(len(res) - 4, 1)
        return s2 * bread, "residuals"
    return bread @ (jac.T * sigma**2) @ jac @ bread, "points"


def _sigma(sigma, n: int, where: str) -> np.ndarray | None:
    if sigma is None:
        return None
    s = np.broadcast_to(np.asarray(sigma, dtype=float), (n,))
    if not np.all(np.isfinite(s) & (s >= 0)):
        raise InputError(f"{where}: sigma must be finite and >= 0 [mm] for every point "
                         "(replace missing values, e.g. by the measured std)")
    if n and not np.any(s > 0):
        raise InputError(f"{where}: every sigma is 0 [mm], which would give the fit no "
                         "uncertainty; give the points' predicted sigma, or none to take "
                         "the residuals' scatter")
    return s


def fit_sphere(points, sigma=None, correlation: Correlation | None = None,
               min_points: int = MIN_POINTS, min_coverage: float = MIN_COVERAGE,
               where: str = "sphere") -> SphereFit:
    """Least-squares sphere (orthogonal distances) with its GUM covariance.

    Parameters
    ----------
    points : (n, 3) float
        Points on one sphere [mm].
    sigma : (n,) float or float, optional
        Standard deviation of each point along the radial direction [mm]; None: the
        covariance comes from the residuals' scatter.
    correlation : float, (4,) float or callable, optional
        Noise-correlation factor kappa >= 1 multiplying the variances of (cx, cy, cz, R)
        [-], or ``f(points, jacobian, residuals)`` returning it (jacobian (n, 4) of the
        residuals with respect to (cx, cy, cz, R)). None: 1 (independent points).
    min_points : int
        Fewest points accepted [-].
    min_coverage : float
        Least cap coverage accepted, fraction of a hemisphere [-] (module notes).
    where : str
        Name used in messages.

    Returns
    -------
    SphereFit

    Raises
    ------
    InputError
        Too few or non-finite points, a fit that diverges, or a cap covering less than
        ``min_coverage`` of a hemisphere.

    Notes
    -----
    The least-squares (Gaussian) sphere of ISO 10360-6 and VDI/VDE 2634-2: min over (c, R)
    of sum_i (|p_i - c| - R)^2, Gauss-Newton from :func:`algebraic_sphere`. Its
    covariance Cov(c, R) = B J^T diag(sigma_i^2) J B, B = (J^T J)^-1, J_i = (-u_i^T, -1),
    the law of propagation of GUM 5.2.2 (Eq. 13) applied to the estimator linearised at the
    solution; without sigmas s^2 B, s^2 = sum r_i^2 / (n - 4). Each variance is multiplied
    by the noise-correlation factor kappa (module notes).
    """
    pts = check_points(points, where, max(min_points, 5))
    sig = _sigma(sigma, len(pts), where)
    m = pts.mean(axis=0)
    c0, r0 = algebraic_sphere(pts)
    c, r, it = _gauss_newton(pts - m, c0 - m, r0, where)
    coverage, half, axis = cap_coverage(pts - m, c)
    if coverage < min_coverage:
        need = math.degrees(math.acos(1.0 - min_coverage)) if min_coverage <= 2 else 180.0
        raise InputError(
            f"{where}: the points cover {coverage:.0%} of a hemisphere (a cap of half-opening "
            f"{half:.0f} deg seen from the fitted centre); a sphere fit needs at least "
            f"{min_coverage:.0%} (an evenly covered cap of half-opening {need:.0f} deg): scan "
            "the sphere so that more of the face towards the scanner is seen")
    d = pts - m - c
    dist = np.linalg.norm(d, axis=1)
    res = dist - r
    jac = np.column_stack([-d / dist[:, None], -np.ones(len(d))])
    cov, source = _covariance(jac, res, sig)
    kappa = _correlation_factor(correlation, pts, jac, res)
    cov = cov * np.sqrt(np.outer(kappa, kappa))
    return SphereFit(c + m, r, res, cov, source, kappa, coverage, half, axis, it)


def sight_noise_bias(points, centre, radius: float, sigma, view_origin=(0.0, 0.0, 0.0)
                     ) -> np.ndarray:
    """Predicted bias of the least-squares (cx, cy, cz, R) from noise along the lines of
    sight (module notes).

    Parameters
    ----------
    points : (n, 3) float
        Points fitted [mm].
    centre : (3,) float
        Fitted centre [mm].
    radius : float
        Fitted radius [mm].
    sigma : (n,) float or float
        Standard deviation of each point along its line of sight [mm].
    view_origin : (3,) float
        Where the lines of sight start (the camera) [mm].

    Returns
    -------
    (4,) float
        Expected estimate minus truth of (cx, cy, cz, R) [mm], second order in sigma;
        0 for sigma = 0; NaN when a sigma is NaN or infinite (a bias that cannot be
        predicted, never a number).

    Raises
    ------
    InputError
        Fewer than 4 points, a NaN or infinite point or centre, or a radius that is not
        finite and > 0.

    Notes
    -----
    b = -(J^T J)^-1 sum_i E[r_i g_i], g_i = (-u_i^T, -1),
    E[r_i g_i] = sigma_i^2 / R (-(c_i l_perp,i + s_i^2 n_i / 2)^T, -s_i^2 / 2): the
    second-order bias of the least-squares estimator under noise along the lines of sight,
    derived in the module notes (scanqa's own, docs/artefacts.rst), checked by Monte Carlo
    in the tests.
    """
    pts = check_points(points, "sphere", 4)
    if not (math.isfinite(radius) and radius > 0):
        raise InputError(f"sphere: the radius must be finite and > 0 mm, got {radius!r}")
    centre = np.asarray(centre, dtype=float)
    if not np.isfinite(centre).all():
        raise InputError(f"sphere: the centre must be finite [mm], got {centre}")
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (len(pts),))
    if not np.isfinite(sig).all():
        return np.full(4, np.nan)
    n = pts - np.asarray(centre, dtype=float)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    sight = pts - np.asarray(view_origin, dtype=float)
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    c = np.sum(n * sight, axis=1)
    s2 = 1.0 - c**2
    perp = sight - c[:, None] * n
    w = sig**2 / radius
    force = np.append(-np.sum(w[:, None] * (c[:, None] * perp + 0.5 * s2[:, None] * n), axis=0),
                      -0.5 * np.sum(w * s2))
    jac = np.column_stack([-n, -np.ones(len(n))])
    return -np.linalg.solve(jac.T @ jac, force)


def _zone_step(d: np.ndarray, u: np.ndarray, delta: float) -> tuple[np.ndarray, float]:
    """Exact LP on the linearised distances d_i - u_i.s within |s|_inf <= delta: the step s
    and the predicted width. Constraint generation: the LP starts with the most extreme
    points and takes in the points its solution violates until none does."""
    order = np.argsort(d)
    outer, inner = order[-_ZONE_SEED:], order[:_ZONE_SEED]
    bounds = [(-delta, delta)] * 3 + [(None, None)] * 2
    for _ in range(100):
        a_ub = np.vstack([np.column_stack([-u[outer], -np.ones(outer.size),
                                           np.zeros(outer.size)]),
                          np.column_stack([u[inner], np.zeros(inner.size),
                                           np.ones(inner.size)])])
        sol = linprog([0, 0, 0, 1.0, -1.0], A_ub=a_ub,
                      b_ub=np.concatenate([-d[outer], d[inner]]), bounds=bounds,
                      method="highs")
        if sol.status != 0:
            return np.zeros(3), float(np.ptp(d))
        step = sol.x[:3]
        lin = d - u @ step
        hi, lo = lin[outer].max(), lin[inner].min()
        tol = 1e-12 * max(float(d.max()), 1.0)
        over, under = np.flatnonzero(lin > hi + tol), np.flatnonzero(lin < lo - tol)
        if over.size == 0 and under.size == 0:
            return step, float(hi - lo)
        outer = np.union1d(outer, over[np.argsort(-lin[over])][:4 * _ZONE_SEED])
        inner = np.union1d(inner, under[np.argsort(lin[under])][:4 * _ZONE_SEED])
    return np.zeros(3), float(np.ptp(d))


def minimum_zone_sphere(points, start=None, where: str = "sphere",
                        max_iter: int = 200) -> MinimumZoneSphere:
    """Minimum-zone (Chebyshev) sphere: the thinnest concentric shell enclosing the points.

    Parameters
    ----------
    points : (n, 3) float
        Points [mm].
    start : (3,) float, optional
        Starting centre [mm]; default the least-squares centre.
    where : str
        Name used in messages.
    max_iter : int
        Most linear programs solved [-].

    Returns
    -------
    MinimumZoneSphere

    Notes
    -----
    Sequential linear programming with a trust region (module notes). The problem is not
    convex in general; from the least-squares centre it finds the local minimum that
    belongs to that sphere, which for points on a sphere with form errors small against
    the radius is the minimum zone. The width is never larger than the least-squares
    range, from which it starts. The criterion is the minimum-zone (Chebyshev) one that
    ISO 12781-1:2011 gives for flatness (MZPL), here for two concentric spheres:
    min over c of (max_i |p_i - c| - min_i |p_i - c|).
    """
    pts = check_points(points, where, 5)
    m = pts.mean(axis=0)
    q = pts - m
    c = (algebraic_sphere(pts)[0] if start is None else np.asarray(start, float)) - m
    if start is None:
        c, _, _ = _gauss_newton(q, c, float(np.mean(np.linalg.norm(q - c, axis=1))), where)
    d = np.linalg.norm(q - c, axis=1)
    width, scale = float(np.ptp(d)), float(d.mean())
    delta = max(width, 1e-9 * scale)
    it = 0
    while it < max_iter and delta > 1e-13 * scale:
        it += 1
        step, predicted = _zone_step(d, (q - c) / d[:, None], delta)
        if width - predicted <= 1e-14 * scale:
            break
        d_new = np.linalg.norm(q - c - step, axis=1)
        ratio = (width - float(np.ptp(d_new))) / (width - predicted)
        if ratio > 0.1:
            c, d, width = c + step, d_new, float(np.ptp(d_new))
            if ratio > 0.75 and np.max(np.abs(step)) > 0.99 * delta:
                delta *= 2.0
        else:
            delta *= 0.25
    return MinimumZoneSphere(c + m, float(d.min()), float(d.max()), it)
