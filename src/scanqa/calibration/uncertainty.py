"""The uncertainty of a calibration, and what it does to a triangulated point and a step.

The 24 parameters (:data:`scanqa.io.opencv.COVARIANCE_PARAMETERS`: both lenses' f_x,
f_y, c_x, c_y, k1 k2 p1 p2 k3, the rotation vector of Rp, Tp) of a board calibration get
their covariance C from the joint fit's Jacobian (:mod:`scanqa.calibration.bundle`); the
calibrations that left one pose out give another, the jackknife (Eq. 1), kept as a check:

    C = (n - 1) / n sum_i (theta_i - theta_bar)(theta_i - theta_bar)^T          (1)

With n poses C has rank n - 1 at most. Its effect on a point is propagated along its
principal axes (sigma points, Eq. 2): with C = sum_k lambda_k e_k e_k^T, each axis moves
the parameters by +-sqrt(lambda_k) e_k and the point (same pixel, same phase) from
P_k+ to P_k-; the point's variance along its line of sight r = P / |P| is

    sigma^2 = sum_k ( r . (P_k+ - P_k-) / 2 )^2                                  (2)

which is exact for a point that depends linearly on the parameters. The term is
systematic within a scan: every scan with the same calibration shares the same error.

The same covariance, carried to a height difference (:func:`step_sigma_mm`), is the
calibration-geometry term of a gauge-block step. A calibration's error in its geometry
moves every point of a scan the same way, so the step between two blocks sees the
calibration's depth-scale error e times the height h, plus its error in the tilt of the
depth axis times the blocks' lateral separation L (and the distortion residual's
difference between the blocks); for parameters theta with covariance C, along C's
principal axes as in Eq. 2,

    u_geom^2 = sum_k ( (d(theta + sqrt(lambda_k) e_k) - d(theta - sqrt(lambda_k) e_k)) / 2 )^2   (3)

with d(theta) the step measured from the blocks' points moved to where the calibration
theta puts the same pixels and phases (:class:`GeometryCovariance`): block a's plane is
refitted, block b's centroid moved. A rigid motion of the whole frame leaves d unchanged
and contributes nothing. For a marker table the parameters are the marker fit's 15
(:class:`~scanqa.calibration.sweep_fit.SweepGeometry`: camera, target tilt, stage axis):
a point's pixel is its projection and its stage reading the target plane that holds it;
for a parametric calibration its 24 (:data:`COVARIANCE_PARAMETERS`): pixel and phase are
its projections into camera and projector.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from scanqa.calibration.pinhole import rotation_matrix, rotation_vector
from scanqa.errors import InputError
from scanqa.io.opencv import COVARIANCE_PARAMETERS, OpenCVCalibration

#: Eigenvalues below this fraction of the largest are dropped (numerical rank) [-].
RANK_TOLERANCE = 1e-12


def _lens_vector(matrix: np.ndarray, distortion: np.ndarray) -> list[float]:
    return [matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], *distortion[:5]]


def _lens_matrix(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fx, fy, cx, cy = values[:4]
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), np.array(values[4:9])


def pack_opencv(data: OpenCVCalibration) -> np.ndarray:
    """The (24,) parameter vector of an OpenCV calibration (``COVARIANCE_PARAMETERS``)."""
    return np.array([*_lens_vector(data.Kc, data.kc), *_lens_vector(data.Kp, data.kp),
                     *rotation_vector(data.Rp), *np.ravel(data.Tp)], dtype=float)


def pack(cal) -> np.ndarray:
    """The (24,) parameter vector of a :class:`ParametricCalibration`."""
    return np.array([*_lens_vector(cal.camera.matrix, cal.camera.distortion),
                     *_lens_vector(cal.projector.matrix, cal.projector.distortion),
                     *rotation_vector(cal.rotation), *cal.translation], dtype=float)


def unpack(cal, theta: np.ndarray):
    """``cal`` with the parameters ``theta`` (24,) (skew, sizes, range kept; no
    covariance: it belongs to the fitted parameters)."""
    cam_m, cam_k = _lens_matrix(theta[:9])
    proj_m, proj_k = _lens_matrix(theta[9:18])
    cam_m[0, 1], proj_m[0, 1] = cal.camera.matrix[0, 1], cal.projector.matrix[0, 1]
    return replace(cal, camera=replace(cal.camera, matrix=cam_m, distortion=cam_k),
                   projector=replace(cal.projector, matrix=proj_m, distortion=proj_k),
                   rotation=rotation_matrix(theta[18:21]), translation=np.array(theta[21:24]),
                   covariance=None)


def jackknife_covariance(thetas: np.ndarray) -> np.ndarray:
    """Eq. 1: the covariance of the full fit from its leave-one-out refits.

    Parameters
    ----------
    thetas : (n, p) float
        Parameters of the n fits that each left one observation out (n >= 2).

    Returns
    -------
    (p, p) float64

    Examples
    --------
    >>> float(jackknife_covariance(np.array([[1.0], [2.0], [3.0]]))[0, 0])
    1.3333333333333333
    """
    thetas = np.asarray(thetas, dtype=float)
    n = len(thetas)
    dev = thetas - thetas.mean(axis=0)
    return (n - 1) / n * dev.T @ dev


def calibration_sigma_mm(cal, covariance: np.ndarray, u: np.ndarray, v: np.ndarray,
                         xp: np.ndarray) -> np.ndarray:
    """Eq. 2: std of triangulated points along their line of sight due to the
    calibration's own uncertainty.

    Parameters
    ----------
    cal : ParametricCalibration
        The calibration.
    covariance : (24, 24) float
        Covariance of its parameters (``COVARIANCE_PARAMETERS`` order).
    u, v : array
        Camera pixels [camera px].
    xp : array
        Decoded phase, broadcast with u and v [projector px].

    Returns
    -------
    array of the broadcast shape
        sigma [mm]; NaN where the point does not triangulate.
    """
    cov = np.asarray(covariance, dtype=float)
    if cov.shape != (len(COVARIANCE_PARAMETERS),) * 2:
        raise ValueError(f"covariance must be {len(COVARIANCE_PARAMETERS)} x "
                         f"{len(COVARIANCE_PARAMETERS)}, got {cov.shape}")
    lam, axes = np.linalg.eigh((cov + cov.T) / 2)
    keep = lam > RANK_TOLERANCE * max(lam.max(), 0.0)
    point = cal.apply(u, v, xp, extrapolate=True).xyz
    ray = point / np.linalg.norm(point, axis=-1, keepdims=True)
    theta = pack(cal)
    var = np.zeros(point.shape[:-1])
    for value, axis in zip(lam[keep], axes.T[keep], strict=True):
        step = np.sqrt(value) * axis
        try:
            plus, minus = unpack(cal, theta + step), unpack(cal, theta - step)
        except InputError as err:
            raise InputError(f"{cal.source}: calibration_covariance: one std along a "
                             f"principal axis (variance {value:.3g}) moves the calibration "
                             f"to an impossible one ({str(err).split(': ', 1)[-1]}): the "
                             "covariance is not this calibration's") from None
        plus = plus.apply(u, v, xp, extrapolate=True).xyz
        minus = minus.apply(u, v, xp, extrapolate=True).xyz
        var += (np.sum(ray * (plus - minus), axis=-1) / 2) ** 2
    return np.sqrt(var)


#: Points of each block the step term moves (a random subset beyond) [-].
STEP_POINTS = 400


@dataclass(frozen=True)
class GeometryCovariance:
    """A calibration's geometric parameters, their covariance, and how a point moves.

    Attributes
    ----------
    name : str
        What the parameters are, for the budget line's source.
    parameters : (p,) float
        The calibration's parameter vector (its own units).
    covariance : (p, p) float
        Their covariance (zero rows for held parameters).
    move : callable
        ``move(points, theta)``: (n, 3) points of a scan in this calibration's frame [mm]
        -> where the calibration ``theta`` puts the same pixels and phases, (n, 3) [mm].
    dof : float
        Degrees of freedom of the covariance (observations - parameters) [-].
    """

    name: str
    parameters: np.ndarray
    covariance: np.ndarray
    move: Callable[[np.ndarray, np.ndarray], np.ndarray]
    dof: float = np.inf

    def axes(self) -> list[np.ndarray]:
        """sqrt(lambda_k) e_k of the covariance's principal axes (numerical rank); none
        for an empty covariance."""
        cov = np.asarray(self.covariance, dtype=float)
        if cov.size == 0:
            return []
        lam, vec = np.linalg.eigh((cov + cov.T) / 2)
        keep = lam > RANK_TOLERANCE * max(lam.max(), 0.0)
        return [np.sqrt(value) * axis for value, axis in zip(lam[keep], vec.T[keep],
                                                                strict=True)]

    def step_sigma_mm(self, points_a: np.ndarray, points_b: np.ndarray) -> float:
        """:func:`step_sigma_mm` of this covariance (what a step's budget calls) [mm]."""
        return step_sigma_mm(self, points_a, points_b)


def marker_covariance(geometry) -> GeometryCovariance:
    """The marker fit's 15 parameters and covariance (:mod:`~scanqa.calibration.sweep_fit`)
    as a :class:`GeometryCovariance`: a point keeps its pixel (its projection) and its
    stage reading (the target plane through it)."""

    def move(points: np.ndarray, theta: np.ndarray) -> np.ndarray:
        u, v = geometry.camera.project(points)
        return geometry.with_parameters(theta).ray_points(u, v, geometry.stage_reading(points))

    return GeometryCovariance("marker fit (camera, target tilt, stage axis; 15 parameters)",
                              np.asarray(geometry.parameters, float),
                              np.asarray(geometry.covariance, float), move)


def parametric_covariance(cal, covariance: np.ndarray) -> GeometryCovariance:
    """A parametric calibration's 24 parameters (:func:`pack`) and their covariance as a
    :class:`GeometryCovariance`: a point keeps its camera pixel and its phase (its
    projections)."""
    axis = 0 if cal.orientation == "vertical" else 1

    def move(points: np.ndarray, theta: np.ndarray) -> np.ndarray:
        u, v = cal.camera.project(points)
        xp = cal.projector.project(points @ np.asarray(cal.rotation).T + cal.translation)[axis]
        return unpack(cal, theta).apply(u, v, xp, extrapolate=True).xyz

    return GeometryCovariance("parametric calibration (24 parameters)", pack(cal),
                              np.asarray(covariance, float), move)


def _step(points_a: np.ndarray, points_b: np.ndarray) -> float:
    """d = n_a . (c_a - c_b), n_a block a's plane normal towards the camera [mm]."""
    ca, cb = points_a.mean(axis=0), points_b.mean(axis=0)
    normal = np.linalg.svd(points_a - ca, full_matrices=False)[2][2]
    normal = -normal if normal @ ca > 0 else normal
    return float(normal @ (ca - cb))


def _subset(points: np.ndarray, n: int = STEP_POINTS) -> np.ndarray:
    points = np.asarray(points, float)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) <= n:
        return points
    return points[np.random.default_rng(0).choice(len(points), n, replace=False)]


def step_sigma_mm(term: GeometryCovariance, points_a: np.ndarray, points_b: np.ndarray
                  ) -> float:
    """Eq. 3: std of the step from block a's plane to block b's centroid due to the
    calibration's geometric uncertainty.

    Parameters
    ----------
    term : GeometryCovariance
        The calibration's parameters, covariance and point mapping.
    points_a, points_b : (n, 3) float
        The blocks' points in the calibration's frame [mm] (up to :data:`STEP_POINTS`
        of each are used).

    Returns
    -------
    float
        u_geom [mm]; NaN when a block has fewer than 3 points that move, or the
        covariance is not finite (a singular fit).
    """
    if not np.isfinite(term.covariance).all():
        return float("nan")
    a, b = _subset(points_a), _subset(points_b)
    var = 0.0
    for step in term.axes():
        plus = (term.move(a, term.parameters + step), term.move(b, term.parameters + step))
        minus = (term.move(a, term.parameters - step), term.move(b, term.parameters - step))
        ok_a = np.isfinite(plus[0]).all(1) & np.isfinite(minus[0]).all(1)
        ok_b = np.isfinite(plus[1]).all(1) & np.isfinite(minus[1]).all(1)
        if ok_a.sum() < 3 or ok_b.sum() < 1:
            return float("nan")
        var += ((_step(plus[0][ok_a], plus[1][ok_b])
                 - _step(minus[0][ok_a], minus[1][ok_b])) / 2) ** 2
    return float(np.sqrt(var))



#: Marker-fit parameters of the target's rotation (its rotation vector) [-].
ROTATION_PARAMETERS = (7, 8, 9)


def _rigid_residual(points: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(n, 3) displacement ``field`` at ``points`` less its best rigid motion
    (translation + small rotation about the centroid, least squares) [mm]."""
    r = points - points.mean(axis=0)
    basis = []
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        basis += [np.tile(e, (len(r), 1)).ravel(), np.cross(e, r).ravel()]
    a = np.array(basis).T
    coef = np.linalg.lstsq(a, field.ravel(), rcond=None)[0]
    return (field.ravel() - a @ coef).reshape(-1, 3)


def registered_error_spread(geometry, stage_mm, parameters=None, step_px: int = 8
                            ) -> np.ndarray:
    """Eq. 4: how a marker table's plane points scatter, after one rigid registration,
    from the marker fit's uncertainty in some of its parameters.

    The table is built with the points where each pixel's ray meets the target plane at
    every stage reading (:meth:`SweepGeometry.plane_points`). Along each principal axis
    k of the covariance of the selected parameters (the others held), the points move
    by d_k = (P(theta + sqrt(lambda_k) e_k) - P(theta - sqrt(lambda_k) e_k)) / 2; a rigid
    motion of the whole frame is removed (the registration that any use of the table in
    the world's frame makes), leaving r_k. For points linear in the parameters the RMS
    error e over pixels i (a grid of ``step_px``) at every reading is

        e^2 = z^T A z,   A_kl = mean_i r_k,i . r_l,i,   z ~ N(0, I)                  (4)

    so e^2 is distributed as sum_j mu_j chi^2_1 with mu_j the eigenvalues of A.

    Parameters
    ----------
    geometry : SweepGeometry
        The marker fit, with its parameter vector and covariance.
    stage_mm : sequence of float
        The sweep's stage readings [mm].
    parameters : sequence of int, optional
        Indices into the 15-vector (default all; :data:`ROTATION_PARAMETERS` gives the
        target's rotation alone).
    step_px : int
        Pixel grid spacing [px].

    Returns
    -------
    (m,) float
        mu_j, largest first [mm^2]; NaN (one) without a finite covariance.
    """
    cov = np.asarray(geometry.covariance, dtype=float)
    if cov.shape != (15, 15) or not np.isfinite(cov).all():
        return np.array([np.nan])
    sel = np.zeros(15, bool)
    sel[list(range(15)) if parameters is None else list(parameters)] = True
    cov = np.where(np.outer(sel, sel), cov, 0.0)
    cam = geometry.camera
    v, u = np.mgrid[0:cam.height_px:step_px, 0:cam.width_px:step_px].astype(float)
    u, v = np.tile(u.ravel(), len(stage_mm)), np.tile(v.ravel(), len(stage_mm))
    s = np.repeat(np.asarray(stage_mm, float), u.size // len(stage_mm))
    base = geometry.ray_points(u, v, s)
    theta = np.asarray(geometry.parameters, float)
    moved = []
    for step in GeometryCovariance("", theta, cov, lambda p, t: p).axes():
        moved.append((geometry.with_parameters(theta + step).ray_points(u, v, s)
                      - geometry.with_parameters(theta - step).ray_points(u, v, s)) / 2)
    if not moved:
        return np.zeros(1)
    good = np.isfinite(base).all(axis=1) & np.all([np.isfinite(m).all(axis=1)
                                                   for m in moved], axis=0)
    r = np.array([_rigid_residual(base[good], m[good]).ravel() for m in moved])
    return np.sort(np.clip(np.linalg.eigvalsh(r @ r.T / good.sum()), 0.0, None))[::-1]


def registered_error_mm(spread: np.ndarray, quantile: float | None = None,
                        scale: float = 1.0) -> float:
    """The registered error of Eq. 4 from its ``spread`` (:func:`registered_error_spread`):
    its RMS expectation sqrt(sum mu_j), or with ``quantile`` that quantile of e (by 20000
    draws of a fixed stream), for the spread times ``scale`` (e.g. 1 / N for N times
    the corners' information) [mm].

    Examples
    --------
    >>> round(registered_error_mm(np.array([4.0])), 6), round(registered_error_mm(
    ...     np.array([4.0]), 0.95), 1)
    (2.0, 3.9)
    """
    mu = np.asarray(spread, dtype=float) * scale
    if quantile is None:
        return float(np.sqrt(mu.sum()))
    z = np.random.default_rng(0).standard_normal((20000, mu.size))
    return float(np.quantile(np.sqrt(z**2 @ mu), quantile))


#: The share of sweeps whose registered error the marker design must keep within the
#: bound (the 95 % quantile of Eq. 4: 9 of 10 sweeps within it with probability 0.91).
MARKER_QUANTILE = 0.95


def marker_error_summary(geometry, stage_mm, frames: int, bound_mm: float) -> dict:
    """What the marker fit's uncertainty implies for the table (Eq. 4), for reports.

    Parameters
    ----------
    geometry : SweepGeometry
        The marker fit (with its covariance).
    stage_mm : sequence of float
        The sweep's stage readings [mm].
    frames : int
        Marker frames averaged per position [-].
    bound_mm : float
        The error the table must stay within [mm].

    Returns
    -------
    dict
        The target rotation's std toward x / y [deg] and the registered error it implies
        alone, the whole fit's (RMS expectation and :data:`MARKER_QUANTILE` quantile)
        [um], the bound [um], ``exceeds_bound`` (the whole fit's quantile past it) and
        ``frames_needed``: the fewest frames per position whose quantile is within the
        bound, the fit's information scaling with the frames (None past 100).
    """
    whole = registered_error_spread(geometry, stage_mm)
    rotation = registered_error_spread(geometry, stage_mm, ROTATION_PARAMETERS)
    q = MARKER_QUANTILE
    quantile = registered_error_mm(whole, q)
    needed = next((n for n in range(1, 101)
                   if registered_error_mm(whole, q, frames / n) <= bound_mm), None)
    std = geometry.std
    return {"marker_frames": int(frames), "bound_um": 1e3 * bound_mm, "quantile": q,
            "rotation_std_deg": [std.get("target_normal_x_deg"),
                                 std.get("target_normal_y_deg")],
            "rotation_error_um": 1e3 * registered_error_mm(rotation),
            "rotation_error_quantile_um": 1e3 * registered_error_mm(rotation, q),
            "fit_error_um": 1e3 * registered_error_mm(whole),
            "fit_error_quantile_um": 1e3 * quantile,
            "exceeds_bound": bool(quantile > bound_mm), "frames_needed": needed}
