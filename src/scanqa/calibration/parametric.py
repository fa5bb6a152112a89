"""Parametric camera-projector calibration: two pinholes with Brown-Conrady distortion.

Most scanners are calibrated this way (OpenCV's stereo calibration with the projector as
an inverse camera): camera and projector matrices K, distortion k1 k2 p1 p2 k3 and the
pose X_p = R X_c + T [mm] (:mod:`scanqa.io.opencv` reads the files and states the
conventions). :class:`ParametricCalibration` plugs into annotation and QA wherever the
nonparametric table does (:class:`scanqa.calibration.base.Calibration`).

Triangulation of a decoded pixel (u, v) with projector coordinate x_p (vertical fringes;
y_p for horizontal ones):

1. The camera pixel is undistorted once per calibration (:attr:`image_grid`): a 2-D
   Newton iteration on the distortion with its analytic Jacobian gives the normalised
   ray direction d = (x, y, 1); the point is Q = t d with t = Z_c.
2. Along the ray the undistorted projector coordinates (a, b) = (X_p / Z_p, Y_p / Z_p)
   move on a straight line, the epipolar line through the image of the camera centre
   (T) and of the ray's point at infinity (R d): b = b0 + m a. The projector pixel is
   x_p(a) = K_p[0] . (distort(a, b0 + m a), 1), a smooth function of one unknown, solved
   by Newton's method from the distortion-free solution, vectorised over all points, to
   |x_p(a) - x_p| < :data:`TOLERANCE_PX` (two steps and a check for the distortion of
   common lenses; points that have not converged after :data:`MAX_ITERATIONS` are
   flagged). Points are solved in pieces of :data:`PIECE_POINTS`; no Python loop runs
   per point.
3. t follows in closed form from a: a (t A_z + T_z) = t A_x + T_x with A = R d.

The slope dQ/dx_p = d (dt/da) / (dx_p/da) comes by implicit differentiation of
x_p(a(t)) at the solution (tests compare it with finite differences); s_T = |dQ/dx_p|
is the triangulation scale of the optics model (Eq. 18 of the paper).

In volume: the solution exists and has converged, lies in front of camera (t > 0) and
projector (Z_p > 0), projects inside the projector panel (both coordinates within
[-0.5, size - 0.5]), where neither lens's distortion folds over (positive Jacobian
determinant), and has Z_c inside the configured depth range ``depth_range_mm``.

The calibration's own uncertainty (:attr:`ParametricCalibration.calibration_term`): a
file written by ``scanqa calibrate --board`` holds the covariance of its 24 parameters
(the joint fit's, :mod:`scanqa.calibration.bundle`), propagated to every point along its
line of sight (:meth:`ParametricCalibration.calibration_sigma_mm`); a file from another
tool has none, unless a covariance (``calibration_covariance``) or a stated std
(``calibration_sigma_um``) is added to it (:mod:`scanqa.io.opencv`). Without either the
calibration term is 0 and every output says so (the cloud's ``sigma_source``). Its RMS
reprojection errors (kept in ``provenance``) are not propagated: they are the scatter
of single target detections, not an error of the fitted mapping.
"""

from __future__ import annotations

import functools
import logging
import math
import os
from dataclasses import dataclass, field

import numpy as np

from scanqa.calibration.lookup import TableLookup, check_rows, empty_lookup
from scanqa.calibration.parametric_checks import (  # noqa: F401 (importable from here)
    AXIS_TOLERANCE_DEG,
    ORIENTATIONS,
    POSITION_TOLERANCE_MM,
    calibration_term,
    check_calibration,
    check_config,
    check_scan,
    lens_warnings,
)
from scanqa.calibration.uncertainty import calibration_sigma_mm
from scanqa.chunks import row_bands, run_bands
from scanqa.decoding.phasemap import PhaseMap
from scanqa.errors import InputError
from scanqa.io.opencv import OpenCVCalibration, read_opencv_calibration
from scanqa.model.config import ScannerConfig

log = logging.getLogger(__name__)

#: Convergence of the projector Newton iteration: |x_p(Q) - x_p| [projector px].
TOLERANCE_PX = 1e-9
#: Convergence of the camera undistortion, in normalised coordinates [-] (1e-13 is
#: ~2e-10 camera px for a 2000 px focal length).
TOLERANCE_NORMALISED = 1e-13
#: Newton iterations after which a point that has not converged is out of volume.
MAX_ITERATIONS = 20
#: Points solved at once: the ~20 temporaries of a piece stay in a core's cache (twice
#: as fast on 2448 x 2048 as pieces of a whole band of 16384).
PIECE_POINTS = 8192


@dataclass(frozen=True, eq=False)
class Lens:
    """A pinhole with Brown-Conrady distortion (camera or projector).

    Attributes
    ----------
    matrix : (3, 3) float
        K = [[f_x, s, c_x], [0, f_y, c_y], [0, 0, 1]] [px].
    distortion : (5,) float
        k1 k2 p1 p2 k3 [-].
    width_px, height_px : int
        Image or panel size [px].
    """

    matrix: np.ndarray
    distortion: np.ndarray
    width_px: int
    height_px: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "matrix", np.asarray(self.matrix, dtype=float))
        object.__setattr__(self, "distortion", np.asarray(self.distortion, dtype=float))

    def distort(self, x: np.ndarray, y: np.ndarray, jacobian: bool = False) -> tuple:
        """Distorted normalised coordinates (x', y') of (x, y) [-] (:mod:`scanqa.io.opencv`
        gives the formula); with ``jacobian`` also dx'/dx, dx'/dy (= dy'/dx), dy'/dy."""
        k1, k2, p1, p2, k3 = self.distortion
        x2, y2, xy = x * x, y * y, x * y
        r2 = x2 + y2
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2)
        yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy
        if not jacobian:
            return xd, yd
        dr = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))  # d(radial)/dx = dr x
        jxx = radial + dr * x2 + 2.0 * p1 * y + 6.0 * p2 * x
        jxy = dr * xy + 2.0 * p1 * x + 2.0 * p2 * y
        jyy = radial + dr * y2 + 6.0 * p1 * y + 2.0 * p2 * x
        return xd, yd, jxx, jxy, jyy

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel (u, v) [px] of (..., 3) points in the device's own frame [mm]."""
        q = np.asarray(points, dtype=float)
        with np.errstate(invalid="ignore", divide="ignore"):
            xd, yd = self.distort(q[..., 0] / q[..., 2], q[..., 1] / q[..., 2])
        k = self.matrix
        return k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]

    def undistort(self, u: np.ndarray, v: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Undistorted normalised coordinates (x, y) [-] of pixels (u, v) [px].

        Returns
        -------
        x, y : ndarray
            Ray direction (x, y, 1) in the device frame [-].
        ok : bool ndarray
            Converged where the distortion does not fold over (positive Jacobian and
            radial factor: the branch that holds the principal point).
        """
        k = self.matrix
        u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
        yd = (v - k[1, 2]) / k[1, 1]
        xd = (u - k[0, 2] - k[0, 1] * yd) / k[0, 0]
        x, y = xd.copy(), yd.copy()
        if not np.any(self.distortion):
            return x, y, np.isfinite(x) & np.isfinite(y)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for _ in range(MAX_ITERATIONS):
                fx, fy, a, b, c = self.distort(x, y, jacobian=True)
                rx, ry = fx - xd, fy - yd
                det = a * c - b * b
                x -= (c * rx - b * ry) / det
                y -= (a * ry - b * rx) / det
                if not np.any(np.abs(rx) + np.abs(ry) > TOLERANCE_NORMALISED):
                    break  # NaN compares False: masked pixels do not hold the loop
            # det > 0 alone also passes the far branch, where the radial factor and its
            # derivative are both negative (a point beyond the fold, mirrored through the
            # centre): the ray must keep the side of its pixel
            k1, k2, _, _, k3 = self.distortion
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ok = (np.abs(rx) + np.abs(ry) <= TOLERANCE_NORMALISED) & (det > 0) & (radial > 0)
        return x, y, ok


@dataclass(frozen=True)
class CameraRays:
    """Undistorted ray of every camera pixel, (x, y, 1) [-] (computed once)."""

    x: np.ndarray      # (H, W) float
    y: np.ndarray      # (H, W) float
    valid: np.ndarray  # (H, W) bool: the undistortion converged without fold-over


@dataclass(frozen=True, eq=False)
class ParametricCalibration:
    """Camera and projector models and their pose; triangulates decoded phase (notes).

    Attributes
    ----------
    camera, projector : Lens
        The two devices.
    rotation : (3, 3) float
        R of X_p = R X_c + T [-].
    translation : (3,) float
        T [mm].
    orientation : str
        "vertical" (the scan codes x_p) or "horizontal" (y_p).
    depth_range_mm : (float, float)
        Z_c range that counts as in volume [mm]; default everything in front.
    errors : dict
        Reprojection errors of the calibration [px] (provenance only).
    source : str
        The calibration file.
    covariance : (24, 24) float or None
        Covariance of the parameters (:data:`scanqa.io.opencv.COVARIANCE_PARAMETERS`),
        e.g. from ``scanqa calibrate --board``; None: unknown.
    stated_sigma_mm : float or None
        A stated calibration std of every point along its line of sight, used when
        there is no covariance [mm]; None: unknown.
    term_source : str
        Where ``covariance`` or ``stated_sigma_mm`` came from when not from the
        calibration file itself (a covariance file, ``--calibration-sigma-um``).
    """

    camera: Lens
    projector: Lens
    rotation: np.ndarray
    translation: np.ndarray
    orientation: str = "vertical"
    depth_range_mm: tuple = (0.0, math.inf)
    errors: dict = field(default_factory=dict)
    source: str = ""
    covariance: np.ndarray | None = None
    stated_sigma_mm: float | None = None
    term_source: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=float))
        object.__setattr__(self, "translation",
                           np.asarray(self.translation, dtype=float).ravel())
        object.__setattr__(self, "depth_range_mm", tuple(float(z) for z in
                                                         self.depth_range_mm))
        check_calibration(self)

    # -- the interface of scanqa.calibration.base.Calibration ----------------------------

    @property
    def width_px(self) -> int:
        """Camera image width [px]."""
        return self.camera.width_px

    @property
    def height_px(self) -> int:
        """Camera image height [px]."""
        return self.camera.height_px

    @property
    def weights(self) -> str:
        """How nodes were weighted: a parametric calibration has none."""
        return "none (parametric calibration)"

    @property
    def cell_px(self) -> float:
        """Spacing of smoothed cells: none, the mapping is continuous (NaN) [camera px]."""
        return math.nan

    @property
    def z_range_mm(self) -> tuple[float, float]:
        """The configured depth range [mm]."""
        return (float(self.depth_range_mm[0]), float(self.depth_range_mm[1]))

    @property
    def provenance(self) -> dict:
        """Where the calibration came from, for output metadata."""
        return {"kind": "parametric", "calibration": self.source,
                "reprojection_error_px": dict(self.errors), "orientation": self.orientation,
                "calibration_term": self.calibration_term}

    @property
    def calibration_term(self) -> dict:
        """Where the calibration's own sigma comes from: ``kind`` "covariance", "stated"
        or "none", and ``detail`` in words (:func:`~scanqa.calibration.parametric_checks.
        calibration_term`)."""
        return calibration_term(self)

    @functools.cached_property
    def image_grid(self) -> CameraRays:
        """Undistorted rays of every camera pixel (computed once, in bands of rows)."""
        shape = (self.height_px, self.width_px)
        x, y, ok = np.empty(shape), np.empty(shape), np.empty(shape, dtype=bool)
        u = np.arange(self.width_px, dtype=float)

        def band(r0: int, r1: int) -> None:
            v = np.arange(r0, r1, dtype=float)[:, None]
            x[r0:r1], y[r0:r1], ok[r0:r1] = self.camera.undistort(u[None, :], v)

        run_bands(band, row_bands(*shape, pixels=PIECE_POINTS))
        return CameraRays(x, y, ok)

    def apply_rows(self, xp_rows: np.ndarray, row0: int = 0, select: np.ndarray | None = None,
                   extrapolate: bool = False) -> TableLookup:
        """Triangulate a band of rows of a phase map (as
        :meth:`scanqa.calibration.table.CalibrationTable.apply_rows`).

        Parameters
        ----------
        xp_rows : (n, W) float ndarray
            Rows row0 .. row0 + n - 1 of a phase map [projector px].
        row0 : int
            Image row of the first [camera px].
        select : (k,) int ndarray, optional
            Flat indices into ``xp_rows`` of the pixels to triangulate; default all.
        extrapolate : bool
            Keep points outside the volume (flagged); by default they are NaN.

        Returns
        -------
        TableLookup
            X, Y, Z [mm], slope dQ/dx_p [mm / projector px], sigma_table = 0 [mm] and
            the in-volume flag; shaped (n, W, ...) or, with ``select``, (k, ...).
        """
        xp, x, y, ok = self._band(xp_rows, row0, select)
        out = empty_lookup((xp.size,))
        self._solve(x, y, xp, ok, extrapolate, out)
        return out if select is not None else _reshaped(out, np.shape(xp_rows))

    def in_volume_rows(self, xp_rows: np.ndarray, row0: int = 0) -> np.ndarray:
        """Whether each phase of a band of rows is in volume (notes): (n, W) bool."""
        xp, x, y, ok = self._band(xp_rows, row0, None)
        return self._solve(x, y, xp, ok).reshape(xp_rows.shape)

    def check_scan(self, config: ScannerConfig, phase_map: PhaseMap,
                   source: str = "scan") -> None:
        """Raise unless scan and config describe the calibrated scanner (notes of
        :func:`check_scan`)."""
        check_scan(self, config, phase_map, source)

    # -- points and images ---------------------------------------------------------------

    def apply(self, u: np.ndarray, v: np.ndarray, xp: np.ndarray,
              extrapolate: bool = False) -> TableLookup:
        """Triangulate arbitrary pixels (u, v) [camera px] with phase ``xp`` [projector px]
        (broadcast together); returns a :class:`TableLookup` of their shape."""
        u, v, xp = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (u, v, xp)))
        x, y, ok = self.camera.undistort(u.ravel(), v.ravel())
        out = empty_lookup((xp.size,))
        self._solve(x, y, xp.ravel(), ok, extrapolate, out)
        return _reshaped(out, xp.shape)

    def apply_image(self, xp: np.ndarray, extrapolate: bool = False) -> TableLookup:
        """Triangulate a whole (H, W) phase map, in bands of rows on every core."""
        xp = np.asarray(xp, dtype=float)
        self._check_rows(xp, 0, whole=True)
        out = empty_lookup(xp.shape)
        self.image_grid  # noqa: B018 - computed once, before the threads share it

        def band(r0: int, r1: int) -> None:
            look = self.apply_rows(xp[r0:r1], r0, None, extrapolate)
            for name in ("xyz", "slope", "sigma_table", "in_volume"):
                getattr(out, name)[r0:r1] = getattr(look, name)

        run_bands(band, row_bands(*xp.shape))
        return out

    def calibration_sigma_mm(self, u: np.ndarray, v: np.ndarray, xp: np.ndarray
                             ) -> np.ndarray:
        """Std of the points (u, v, xp) along their line of sight from the calibration's
        own uncertainty [mm] (:func:`scanqa.calibration.uncertainty.calibration_sigma_mm`);
        the stated std where it has none but one is stated; NaN everywhere when it has
        neither."""
        if self.covariance is None:
            shape = np.broadcast_shapes(np.shape(u), np.shape(v), np.shape(xp))
            stated = self.stated_sigma_mm
            return np.full(shape, np.nan if stated is None else float(stated))
        return calibration_sigma_mm(self, self.covariance, u, v, xp)

    @property
    def projector_position_mm(self) -> np.ndarray:
        """The projector's centre in the camera frame, -R^T T, (3,) [mm]."""
        return -self.rotation.T @ self.translation

    @property
    def projector_axis(self) -> np.ndarray:
        """The projector's optical axis in the camera frame, R^T e_z, (3,) [-]."""
        return self.rotation[2] / np.linalg.norm(self.rotation[2])

    # -- internals -----------------------------------------------------------------------

    def _band(self, xp_rows: np.ndarray, row0: int, select: np.ndarray | None) -> tuple:
        """Flat phase, ray and ray-validity arrays of a band (all pixels or ``select``)."""
        xp_rows = np.asarray(xp_rows, dtype=float)
        self._check_rows(xp_rows, row0)
        g = self.image_grid
        rows = slice(row0, row0 + xp_rows.shape[0])
        arrays = (xp_rows, g.x[rows], g.y[rows], g.valid[rows])
        if select is None:
            return tuple(a.ravel() for a in arrays)
        return tuple(np.take(a, select) for a in arrays)

    def _check_rows(self, xp: np.ndarray, row0: int, whole: bool = False) -> None:
        """Raise unless ``xp`` is rows row0.. (``whole``: all rows) of a phase map of the
        calibrated camera (:func:`scanqa.calibration.lookup.check_rows`)."""
        check_rows(xp, row0, self.width_px, self.height_px, whole, "the calibrated camera",
                   f"the calibration {self.source} is for")

    def _solve(self, x: np.ndarray, y: np.ndarray, xp: np.ndarray, ok: np.ndarray,
               extrapolate: bool = False, out: TableLookup | None = None) -> np.ndarray:
        """Triangulate flat arrays (module notes) in pieces of :data:`PIECE_POINTS`; fill
        ``out`` if given; return the in-volume flag."""
        inside = np.empty(xp.shape, dtype=bool)
        for a in range(0, xp.size, PIECE_POINTS):
            part = slice(a, a + PIECE_POINTS)
            piece = None if out is None else TableLookup(
                out.xyz[part], out.slope[part], out.sigma_table[part], out.in_volume[part])
            inside[part] = self._solve_piece(x[part], y[part], xp[part], ok[part],
                                             extrapolate, piece)
        return inside

    def _solve_piece(self, x: np.ndarray, y: np.ndarray, xp: np.ndarray, ok: np.ndarray,
                     extrapolate: bool, out: TableLookup | None) -> np.ndarray:
        """One piece of :meth:`_solve`."""
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            sol = _newton(self, x, y, xp)
            t, dt_dxp, inside = _depth(self, sol, xp, ok)
        if out is not None:
            if not extrapolate:
                t = np.where(inside, t, np.nan)
                dt_dxp = np.where(inside, dt_dxp, np.nan)
            out.xyz[:, 0], out.xyz[:, 1], out.xyz[:, 2] = t * x, t * y, t
            out.slope[:, 0], out.slope[:, 1], out.slope[:, 2] = dt_dxp * x, dt_dxp * y, dt_dxp
            out.sigma_table[:] = np.where(np.isfinite(t), 0.0, np.nan)
            out.in_volume[:] = inside
        return inside


def _reshaped(look: TableLookup, shape: tuple[int, ...]) -> TableLookup:
    """A flat lookup's arrays reshaped to a query of ``shape`` (views)."""
    return TableLookup(look.xyz.reshape(*shape, 3), look.slope.reshape(*shape, 3),
                       look.sigma_table.reshape(shape), look.in_volume.reshape(shape))


@dataclass(frozen=True)
class _Solution:
    """Where the projector Newton iteration ended, per point."""

    w: np.ndarray          # primary undistorted projector coordinate (a or b) [-]
    a: np.ndarray          # projector frame direction of the ray: A = R d, 3 arrays [-]
    dxp_dw: np.ndarray     # d(projector pixel)/dw at the solution [px]
    secondary: np.ndarray  # the other projector pixel coordinate [px]
    converged: np.ndarray  # |residual| <= TOLERANCE_PX and no fold-over
    primary: int           # 0 for x_p (vertical fringes), 1 for y_p


def _newton(cal: ParametricCalibration, x: np.ndarray, y: np.ndarray, xp: np.ndarray
            ) -> _Solution:
    """Solve x_p(w) = xp along each ray's epipolar line (module notes, step 2)."""
    r, t = cal.rotation, cal.translation
    big_a = [r[i, 0] * x + r[i, 1] * y + r[i, 2] for i in range(3)]
    p = 0 if cal.orientation == "vertical" else 1
    q = 1 - p
    # epipolar line l = T x A in homogeneous projector coordinates; secondary = c + m w
    line = [t[1] * big_a[2] - t[2] * big_a[1], t[2] * big_a[0] - t[0] * big_a[2],
            t[0] * big_a[1] - t[1] * big_a[0]]
    m, c = -line[p] / line[q], -line[2] / line[q]
    k = cal.projector.matrix
    kp_, kq_ = float(k[p, p]), float(k[p, q])  # the row of K giving the coded coordinate
    target = xp - k[p, 2]
    w = (target - kq_ * c) / (kp_ + kq_ * m)  # distortion-free start
    for _ in range(MAX_ITERATIONS):
        s = c + m * w
        if kq_ == 0.0:  # no skew: only the coded coordinate's distortion is needed
            dist, deriv = _coded_distortion(cal.projector.distortion, p, w, s, m)
            resid = kp_ * dist - target
            deriv *= kp_
        else:
            resid, deriv = _coded_skewed(cal.projector, p, w, s, m, target)
        if not np.any(np.abs(resid) > TOLERANCE_PX):
            break  # NaN compares False: undecoded pixels do not hold the loop
        w = w - resid / deriv
    s = c + m * w
    ad, bd, jxx, jxy, jyy = cal.projector.distort(*((w, s) if p == 0 else (s, w)), True)
    secondary = k[q, q] * (ad, bd)[q] + k[q, 2] + (k[q, p] * (ad, bd)[p] if k[q, p] else 0.0)
    converged = (np.abs(resid) <= TOLERANCE_PX) & (jxx * jyy - jxy * jxy > 0)
    return _Solution(w, big_a, deriv, secondary, converged, p)


def _coded_distortion(k: np.ndarray, p: int, w: np.ndarray, s: np.ndarray, m: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The distorted coded coordinate (x' for p = 0, y' for p = 1) at undistorted coded
    coordinate w and other coordinate s = c + m w [-], and its derivative along the
    epipolar line, d/dw = d/dw|_s + m d/ds|_w [-]. Terms with a zero coefficient are
    skipped: a lens with k1 alone costs a third of the full distortion."""
    k1, k2, p1, p2, k3 = (float(v) for v in k)
    u_, v_ = (p1, p2) if p == 0 else (p2, p1)  # the tangential terms, seen from w
    w2 = w * w
    r2 = w2 + s * s
    poly = k1 + r2 * (k2 + r2 * k3) if (k2 or k3) else k1
    radial = 1.0 + r2 * poly
    dr = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) if (k2 or k3) else 2.0 * k1
    dist = w * radial
    d_w = radial + dr * w2
    d_s = dr * (w * s)
    if u_ or v_:
        dist = dist + 2.0 * u_ * w * s + v_ * (r2 + 2.0 * w2)
        d_w = d_w + 2.0 * u_ * s + 6.0 * v_ * w
        d_s = d_s + 2.0 * u_ * w + 2.0 * v_ * s
    return dist, d_w + m * d_s


def _coded_skewed(lens: Lens, p: int, w: np.ndarray, s: np.ndarray, m: np.ndarray,
                  target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual and derivative of the coded pixel when K has skew (both coordinates)."""
    k = lens.matrix
    q = 1 - p
    ad, bd, jxx, jxy, jyy = lens.distort(*((w, s) if p == 0 else (s, w)), True)
    dist, jac = (ad, bd), ((jxx, jxy), (jxy, jyy))
    resid = k[p, p] * dist[p] + k[p, q] * dist[q] - target
    deriv = (k[p, p] * (jac[p][p] + jac[p][q] * m)
             + k[p, q] * (jac[q][p] + jac[q][q] * m))
    return resid, deriv


def _depth(cal: ParametricCalibration, sol: _Solution, xp: np.ndarray, ok: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z_c = t, dt/dx_p and the in-volume flag (module notes, step 3)."""
    t_vec, a, p, w = cal.translation, sol.a, sol.primary, sol.w
    denom = w * a[2] - a[p]
    t = (t_vec[p] - w * t_vec[2]) / denom
    dt_dxp = (t_vec[2] * a[p] - t_vec[p] * a[2]) / (denom * denom) / sol.dxp_dw
    z_p = t * a[2] + t_vec[2]
    lo, hi = cal.depth_range_mm
    sizes = (cal.projector.width_px, cal.projector.height_px)
    inside = (ok & sol.converged & (t > 0) & (z_p > 0) & (t >= lo) & (t <= hi)
              & (xp >= -0.5) & (xp <= sizes[p] - 0.5)
              & (sol.secondary >= -0.5) & (sol.secondary <= sizes[1 - p] - 0.5))
    return t, dt_dxp, inside


# --------------------------------------------------------------------------- loading


def from_opencv(data: OpenCVCalibration, orientation: str = "vertical",
                depth_range_mm: tuple = (0.0, math.inf),
                camera_size: tuple[int, int] | None = None,
                projector_size: tuple[int, int] | None = None) -> ParametricCalibration:
    """A :class:`ParametricCalibration` from the contents of an OpenCV file.

    Parameters
    ----------
    data : OpenCVCalibration
        As read by :func:`scanqa.io.opencv.read_opencv_calibration`.
    orientation : str
        "vertical" (scans code x_p) or "horizontal" (y_p).
    depth_range_mm : (float, float)
        Z_c range counted as in volume [mm].
    camera_size, projector_size : (int, int), optional
        (width, height) [px], used when the file has no ``frameWidth``/``frameHeight``
        (``screenResX``/``screenResY``); where it has them they must agree.

    Raises
    ------
    InputError
        A size is neither in the file nor given, or disagrees with the file's.
    """
    cam = _size(data, ("frameWidth", "frameHeight"), camera_size, "camera")
    proj = _size(data, ("screenResX", "screenResY"), projector_size, "projector")
    cal = ParametricCalibration(Lens(data.Kc, data.kc, *cam), Lens(data.Kp, data.kp, *proj),
                                data.Rp, data.Tp, orientation,
                                tuple(float(v) for v in depth_range_mm), dict(data.errors),
                                data.source, data.covariance,
                                None if data.stated_sigma_um is None
                                else 1e-3 * float(data.stated_sigma_um))
    for warning in lens_warnings(cal):
        log.warning(warning)
    return cal


def _size(data: OpenCVCalibration, keys: tuple[str, str], given: tuple[int, int] | None,
          device: str) -> tuple[int, int]:
    """A device's (width, height) from the file and/or the caller (:func:`from_opencv`)."""
    have = [data.sizes.get(k) for k in keys]
    if None not in have:
        if given is not None and tuple(given) != tuple(have):
            raise InputError(f"{data.source}: {keys[0]} x {keys[1]} is {have[0]} x {have[1]} "
                             f"but the {device} is {given[0]} x {given[1]} px in the scanner "
                             "config: use the calibration of this scanner")
        return have[0], have[1]
    if given is None:
        raise InputError(f"{data.source} has no {keys[0]}/{keys[1]}: give the {device} size "
                         f"(the scanner config's {device}.width_px and height_px)")
    return int(given[0]), int(given[1])


def load_opencv_calibration(path: str | os.PathLike, orientation: str = "vertical",
                            depth_range_mm: tuple = (0.0, math.inf),
                            camera_size: tuple[int, int] | None = None,
                            projector_size: tuple[int, int] | None = None
                            ) -> ParametricCalibration:
    """Read an OpenCV camera-projector calibration file (:mod:`scanqa.io.opencv`) into a
    :class:`ParametricCalibration` (parameters as :func:`from_opencv`)."""
    return from_opencv(read_opencv_calibration(path), orientation, depth_range_mm,
                       camera_size, projector_size)
