"""The sweep's geometry from the marked target: camera and rigid stage.

:func:`fit_sweep_geometry` fits, to the labelled corners of every marker frame of a sweep
(:func:`scanqa.calibration.target.detect_chessboard`), one camera (focal length,
principal point, Brown-Conrady k1 k2 p1 p2; square pixels, no skew) and the target's pose
at every position, constrained to a rigid stage: one rotation (the target's tilt) and a
translation that moves along one straight axis by the stage readings. The stage axis and
the target's tilt are estimated, not assumed.

Two steps beyond a plain least-squares fit, each from the sweep's own data:

* the principal point is fitted starting from the fit that holds it at the sensor
  centre, and kept when a profile-likelihood test says the data pin it to
  +-:data:`PRINCIPAL_POINT_LIMIT_PX` (else it is held at the centre, and the result says
  so: ``principal_point_fitted``);
* the corners' pixel locking (an error periodic in the pixel grid, which the smooth
  camera model cannot produce) is estimated from the fit's misfit and removed
  (:func:`pixel_locking`), then the fit is repeated.

:meth:`SweepGeometry.plane_points` gives, per pixel, the 3-D point of the target plane it
sees at a stage reading (pose + distortion): the lateral X, Y, Z that the calibration
table is built with (:mod:`scanqa.calibration.sweep`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from scanqa.calibration.parametric import Lens
from scanqa.calibration.pinhole import rotation_matrix
from scanqa.calibration.target import Detection
from scanqa.errors import InputError
from scanqa.model.config import ScannerConfig

#: Half-width of the 95 % profile interval within which the sweep must pin the principal
#: point for it to count as fitted [px] (else it is held at the sensor centre).
PRINCIPAL_POINT_LIMIT_PX = 1.0


def _rodrigues(rvec: np.ndarray) -> np.ndarray:
    return rotation_matrix(rvec)


def plane_to_camera(xy: np.ndarray, rotation: np.ndarray, translation: np.ndarray
                    ) -> np.ndarray:
    """(n, 2) target-plane points -> (n, 3) camera-frame points [mm]; ``translation`` is
    the target origin, (3,) or one per point (n, 3)."""
    xy = np.asarray(xy, float)
    return xy[:, :1] * rotation[:, 0] + xy[:, 1:2] * rotation[:, 1] + translation


def _direction(a: float, b: float) -> np.ndarray:
    """Unit vector from two small angles about the camera axis [-]."""
    v = np.array([math.tan(a), math.tan(b), 1.0])
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class SweepGeometry:
    """Camera and rigid-stage geometry fitted to a marked sweep (module notes).

    Attributes
    ----------
    camera : Lens
        Camera matrix and distortion (k1 k2 p1 p2 0) [px], [-].
    rotation : (3, 3) float
        Target -> camera rotation; its third column is the target's normal [-].
    origin_mm : (3,) float
        Target origin in the camera frame at stage reading ``stage_ref_mm`` [mm].
    axis : (3,) float
        Stage direction in the camera frame (unit, + with the readings) [-].
    stage_ref_mm : float
        The reading at which ``origin_mm`` holds [mm].
    rms_px : float
        RMS reprojection error of all corners [px].
    plane_rms_px : dict
        RMS reprojection error per stage reading [px].
    principal_point_fitted : bool
        Whether the sweep identified the principal point (else: the sensor centre).
    std : dict
        Standard deviations of the main parameters from the fit's covariance.
    locking_px : float
        RMS of the pixel-locking correction applied to the corners [px].
    decentring_fitted : bool
        Whether the corners needed the tangential distortion p1, p2 (else held at 0).
    parameters : (15,) float
        The fitted vector (f, c_x, c_y, k1, k2, p1, p2, rotation vector, origin, the
        axis' two angles) [px], [-], [rad], [mm], [rad]; empty when not known.
    covariance : (15, 15) float
        Its covariance from the fit's Jacobian and residual variance (zero rows and
        columns for held parameters); empty when not known.
    """

    camera: Lens
    rotation: np.ndarray
    origin_mm: np.ndarray
    axis: np.ndarray
    stage_ref_mm: float
    rms_px: float
    plane_rms_px: dict = field(default_factory=dict)
    principal_point_fitted: bool = True
    std: dict = field(default_factory=dict)
    locking_px: float = 0.0
    decentring_fitted: bool = True
    parameters: np.ndarray = field(default_factory=lambda: np.zeros(0))
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def translation(self, stage_mm: float) -> np.ndarray:
        """Target origin in the camera frame at a stage reading [mm]."""
        return self.origin_mm + (float(stage_mm) - self.stage_ref_mm) * self.axis

    @property
    def stage_tilt_deg(self) -> float:
        """Angle between the stage axis and the camera axis [deg]."""
        return math.degrees(math.acos(min(1.0, abs(float(self.axis[2])))))

    @property
    def target_tilt_deg(self) -> float:
        """Angle between the target's normal and the camera axis [deg]."""
        return math.degrees(math.acos(min(1.0, abs(float(self.rotation[2, 2])))))

    @property
    def target_tilt_azimuth_deg(self) -> float:
        """Direction in the sensor plane toward which the target's normal leans, from
        the camera's x axis toward its y axis [deg]; with the tilt it gives both of the
        normal's directions (the tilt alone is blind, to first order, to a turn about an
        axis at right angles to the one it is tilted about)."""
        n = self.rotation[:, 2] * math.copysign(1.0, float(self.rotation[2, 2]))
        return math.degrees(math.atan2(float(n[1]), float(n[0])))

    def project(self, target_xy: np.ndarray, stage_mm: float) -> np.ndarray:
        """Sensor coordinates of target-plane points at a stage reading: (n, 2) [px]."""
        pts = plane_to_camera(target_xy, self.rotation, self.translation(stage_mm))
        return np.stack(self.camera.project(pts), -1)

    def with_parameters(self, parameters: np.ndarray) -> SweepGeometry:
        """The same geometry with another (15,) parameter vector (``parameters``'
        order); the fit's statistics are kept, the covariance dropped."""
        k, dist, rot, t0, axis = _unpack(np.asarray(parameters, dtype=float))
        cam = self.camera
        return replace(self, camera=Lens(k, dist, cam.width_px, cam.height_px), rotation=rot,
                       origin_mm=np.asarray(t0, float), axis=axis,
                       parameters=np.asarray(parameters, dtype=float),
                       covariance=np.zeros((0, 0)))

    def stage_reading(self, points: np.ndarray) -> np.ndarray:
        """The stage reading whose target plane holds each of (n, 3) points [mm]."""
        n = self.rotation[:, 2]
        return self.stage_ref_mm + (np.asarray(points, float) @ n - n @ self.origin_mm) / (
            n @ self.axis)

    def ray_points(self, u: np.ndarray, v: np.ndarray, stage_mm: np.ndarray) -> np.ndarray:
        """(n, 3) points where the rays of pixels (u, v) [px] meet the target plane at
        stage readings ``stage_mm`` [mm]; NaN where the undistortion fails."""
        x, y, ok = self.camera.undistort(u, v)
        n = self.rotation[:, 2]
        depth = (np.asarray(stage_mm, float) - self.stage_ref_mm) * (n @ self.axis) + (
            n @ self.origin_mm)
        lam = np.where(ok, depth / (n[0] * x + n[1] * y + n[2]), np.nan)
        return np.stack([lam * x, lam * y, lam], -1)

    def plane_points(self, stage_mm: float, width: int, height: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """X, Y, Z maps [mm] of the target plane seen by every pixel at a stage reading.

        Each pixel's ray (undistorted) meets the plane of the target's pose; NaN where
        the undistortion fails.
        """
        v, u = np.mgrid[0:height, 0:width].astype(float)
        x, y, ok = self.camera.undistort(u, v)
        n = self.rotation[:, 2]
        lam = (n @ self.translation(stage_mm)) / (n[0] * x + n[1] * y + n[2])
        lam = np.where(ok, lam, np.nan)
        return lam * x, lam * y, lam

    def summary(self) -> dict:
        """Plain numbers for reports."""
        k = self.camera.matrix
        return {"focal_px": float(k[0, 0]), "principal_point_px": [float(k[0, 2]),
                                                                   float(k[1, 2])],
                "principal_point_fitted": self.principal_point_fitted,
                "decentring_fitted": self.decentring_fitted,
                "distortion_k1_k2_p1_p2": [float(v) for v in self.camera.distortion[:4]],
                "stage_axis": [float(v) for v in self.axis],
                "stage_tilt_deg": self.stage_tilt_deg,
                "target_tilt_deg": self.target_tilt_deg,
                "target_tilt_azimuth_deg": self.target_tilt_azimuth_deg, "rms_px": self.rms_px,
                "locking_px": self.locking_px, "std": dict(self.std),
                "stage_ref_mm": self.stage_ref_mm,
                "image_size_px": [self.camera.width_px, self.camera.height_px],
                "parameters": [float(v) for v in self.parameters],
                "covariance": [[float(v) for v in row] for row in self.covariance]}


def geometry_from_summary(summary: dict) -> SweepGeometry:
    """The :class:`SweepGeometry` of a :meth:`SweepGeometry.summary` (a table's
    ``target_geometry`` provenance) with its parameters and covariance.

    Raises
    ------
    InputError
        The summary predates the parameter vector (a table built before it was kept).
    """
    if len(summary.get("parameters", [])) != 15:
        raise InputError("the table's target_geometry holds no parameter vector (a table "
                         "built by an older scanqa): calibrate it again to carry the "
                         "marker fit's covariance")
    width, height = summary["image_size_px"]
    theta = np.asarray(summary["parameters"], float)
    k, dist, rot, t0, axis = _unpack(theta)
    return SweepGeometry(Lens(k, dist, int(width), int(height)), rot, np.asarray(t0, float),
                         axis, float(summary["stage_ref_mm"]), float(summary["rms_px"]),
                         principal_point_fitted=bool(summary["principal_point_fitted"]),
                         decentring_fitted=bool(summary["decentring_fitted"]),
                         std=dict(summary.get("std", {})),
                         locking_px=float(summary.get("locking_px", 0.0)),
                         parameters=theta, covariance=np.asarray(summary["covariance"], float))


def _unpack(p: np.ndarray):
    """Parameters (f, cx, cy, k1, k2, p1, p2, rotation, origin, axis) -> (K, dist, R, t0,
    axis)."""
    f, cx, cy = p[:3]
    k = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    dist = np.array([*p[3:7], 0.0])
    return k, dist, _rodrigues(p[7:10]), p[10:13], _direction(p[13], p[14])


def _residuals(p, xy, stage, uv, size):
    """Model - observed corners, u then v [px]."""
    k, dist, rot, t0, axis = _unpack(p)
    pts = plane_to_camera(xy, rot, t0 + stage[:, None] * axis)
    u, v = Lens(k, dist, *size).project(pts)
    return np.concatenate([u - uv[:, 0], v - uv[:, 1]])


def fit_sweep_geometry(detections: list[Detection], stage_mm: list[float],
                       config: ScannerConfig, width: int, height: int) -> SweepGeometry:
    """Fit the camera and the rigid stage to the labelled corners of a sweep.

    In order (module notes): a fit with the principal point at the sensor centre; from
    it, the fit with the point free; the corners' pixel locking estimated from its misfit
    and removed (:func:`pixel_locking`), refitting after each pass; the tangential
    distortion p1, p2 dropped unless a likelihood-ratio test says the corners need it;
    the principal point held at the sensor centre unless the sweep pins it
    (:func:`_principal_point_identified`).

    Parameters
    ----------
    detections : list of Detection
        One per stage position.
    stage_mm : list of float
        The stage reading of each [mm].
    config : ScannerConfig
        Starting values (focal length, pixel size) only.
    width, height : int
        Image size [px].

    Returns
    -------
    SweepGeometry

    Raises
    ------
    InputError
        Fewer than 3 positions, or a fit that does not converge to sub-pixel residuals.
    """
    if len(detections) < 3:
        raise InputError(f"the marked target was found at {len(detections)} positions; the "
                         "sweep's geometry needs at least 3")
    ref = 0.5 * (min(stage_mm) + max(stage_mm))
    xy = np.concatenate([d.target_points for d in detections])
    uv = np.concatenate([d.image_points for d in detections])
    counts = [len(d.target_points) for d in detections]
    stage = np.repeat(np.asarray(stage_mm, float) - ref, counts)
    groups = np.repeat(np.arange(len(detections)), counts)
    p0 = _start(detections, stage_mm, ref, config, width, height)
    args = (xy, stage, uv, (width, height))
    fit = _solve(_solve(p0, ~_PP, args).p, _ALL, args)
    corrected = uv
    for _ in range(LOCKING_PASSES):
        model = corrected + fit.fun.reshape(2, -1).T  # the residuals are model - corners
        locking = pixel_locking(uv - model, uv, groups)
        corrected = uv - locking
        args = (xy, stage, corrected, (width, height))
        fit = _solve(fit.p, _ALL, args)
    plain = _solve(np.where(_DECENTRING, 0.0, fit.p), ~_DECENTRING, args)
    if plain.ssr - fit.ssr < _CHI2_95_2DOF * fit.variance:
        fit = plain
    if not _principal_point_identified(fit, args):
        fit = _solve(np.where(_PP, p0, fit.p), fit.free & ~_PP, args)
    lock_rms = float(np.sqrt(np.mean(np.sum(locking**2, axis=1))))
    return _geometry(fit, detections, stage_mm, ref, width, height, lock_rms)


#: Parameter masks of the 15-vector (f, cx, cy, k1, k2, p1, p2, rotation, origin, axis).
_ALL = np.ones(15, bool)
_PP = np.isin(np.arange(15), (1, 2))
_DECENTRING = np.isin(np.arange(15), (5, 6))
#: 95 % quantiles of chi-square with 1 and 2 degrees of freedom [-].
_CHI2_95_1DOF, _CHI2_95_2DOF = 3.841, 5.991


@dataclass(frozen=True)
class _Fit:
    """A least-squares fit of the free entries of the parameter vector."""

    p: np.ndarray
    free: np.ndarray
    fun: np.ndarray
    jac: np.ndarray

    @property
    def ssr(self) -> float:
        """Residual sum of squares [px^2]."""
        return float(self.fun @ self.fun)

    @property
    def variance(self) -> float:
        """Residual variance per coordinate [px^2]."""
        return self.ssr / max(self.fun.size - int(self.free.sum()), 1)

    def covariance(self) -> np.ndarray:
        """(15, 15) covariance of the parameters (zero where held) from the Jacobian
        and the residual variance; inf on the diagonal when the Jacobian is singular."""
        out = np.zeros((self.p.size, self.p.size))
        free = np.flatnonzero(self.free)
        try:
            cov = np.linalg.inv(self.jac.T @ self.jac) * self.variance
        except np.linalg.LinAlgError:
            out[free, free] = np.inf
            return out
        out[np.ix_(free, free)] = cov
        return out

    def std(self) -> np.ndarray:
        """Standard deviations of all 15 parameters (0 where held) from the Jacobian."""
        return np.sqrt(np.abs(np.diag(self.covariance())))


def _solve(p: np.ndarray, free: np.ndarray, args) -> _Fit:
    """Fit the ``free`` parameters of ``p`` (the others held) to the corners."""
    from scipy.optimize import least_squares

    def residuals(x):
        q = p.copy()
        q[free] = x
        return _residuals(q, *args)

    res = least_squares(residuals, p[free], x_scale="jac", method="lm")
    q = p.copy()
    q[free] = res.x
    return _Fit(q, free.copy(), res.fun, res.jac)


#: Harmonics of the pixel-locking model and the passes of its estimate (module notes).
LOCKING_HARMONICS, LOCKING_PASSES = 2, 2


def pixel_locking(misfit: np.ndarray, uv: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """The corners' pixel-locking error, estimated from the fit's misfit, (n, 2) [px].

    A sub-pixel corner is pulled towards (or away from) pixel centres by an amount that
    depends on where it falls within its pixel. Per position (``groups``) and
    coordinate, the misfit (observed - model) is regressed on sines and cosines of
    2 pi h f, h = 1 .. :data:`LOCKING_HARMONICS`, f = u - round(u) (resp. v): that
    part is periodic in the pixel grid, which the smooth camera model cannot produce,
    so it is the detector's and is removed from the corners.

    Parameters
    ----------
    misfit : (n, 2) float
        Observed minus modelled corners [px].
    uv : (n, 2) float
        Observed corners [px].
    groups : (n,) int
        Position of each corner.
    """
    out = np.zeros_like(uv)
    h = np.arange(1, LOCKING_HARMONICS + 1)
    for g in np.unique(groups):
        m = groups == g
        for a in range(2):
            t = 2 * np.pi * np.outer(uv[m, a] - np.round(uv[m, a]), h)
            basis = np.column_stack([np.sin(t), np.cos(t)])
            if len(basis) <= 4 * basis.shape[1]:
                continue  # too few corners to tell locking from noise
            coef = np.linalg.lstsq(basis, misfit[m, a], rcond=None)[0]
            out[m, a] = basis @ coef
    return out


def _principal_point_identified(fit: _Fit, args) -> bool:
    """Whether the sweep pins the principal point to +-:data:`PRINCIPAL_POINT_LIMIT_PX`.

    Profile likelihood, not the Jacobian's standard deviation: the principal point, the
    tangential distortion and the stage axis trade along a curved valley in a narrow
    field of view, where the linearised std can say 0.3 px while the valley runs 13 px
    (simulated, docs/calibration.rst). The point is held at each of ``pp +- limit``
    along u and along v, the rest refitted; it is identified when every one of the four
    raises the residual sum of squares by more than the 95 % quantile of chi-square(1)
    times the residual variance.
    """
    for k in np.nonzero(_PP)[0]:
        for sign in (-1.0, 1.0):
            p = fit.p.copy()
            p[k] += sign * PRINCIPAL_POINT_LIMIT_PX
            if _solve(p, fit.free & ~_PP, args).ssr - fit.ssr < _CHI2_95_1DOF * fit.variance:
                return False
    return True


def _start(detections, stage_mm, ref, config, width, height) -> np.ndarray:
    """Starting parameters: the config's pinhole and two PnP poses."""
    import cv2

    f = config.camera.principal_distance_px
    k = np.array([[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1.0]])
    poses = []
    for d in (detections[0], detections[-1]):
        obj = np.column_stack([d.target_points, np.zeros(len(d.target_points))])
        ok, rvec, tvec = cv2.solvePnP(obj, d.image_points, k, None)
        if not ok:
            raise InputError(f"{d.source}: cannot estimate the target's pose")
        poses.append((rvec.ravel(), tvec.ravel()))
    s0, s1 = stage_mm[0], stage_mm[-1]
    axis = (poses[1][1] - poses[0][1]) / (s1 - s0)
    t_ref = poses[0][1] + (ref - s0) * axis
    axis = axis / np.linalg.norm(axis)
    angles = [math.atan2(axis[0], axis[2]), math.atan2(axis[1], axis[2])]
    return np.array([f, k[0, 2], k[1, 2], 0, 0, 0, 0, *poses[0][0], *t_ref, *angles])


def _geometry(fit: _Fit, detections, stage_mm, ref, width, height,
              locking_px: float) -> SweepGeometry:
    k, dist, rot, t0, axis = _unpack(fit.p)
    res = fit.fun.reshape(2, -1)
    err = np.hypot(res[0], res[1])
    rms = float(np.sqrt(np.mean(err**2)))
    if not rms < 1.0:
        raise InputError(f"the marked sweep does not fit one camera on a straight stage "
                         f"(RMS reprojection error {rms:.2f} px): check the stage readings "
                         "and that the target did not move on the stage")
    per, start = {}, 0
    for d, s in zip(detections, stage_mm, strict=True):
        n = len(d.target_points)
        per[float(s)] = float(np.sqrt(np.mean(err[start:start + n] ** 2)))
        start += n
    names = ("focal_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2")
    std = {n: float(v) for n, v in zip(names, fit.std(), strict=False)}
    std.update(_normal_std(fit.p, fit.covariance()))
    return SweepGeometry(Lens(k, dist, width, height), rot, np.asarray(t0, float), axis,
                         float(ref), rms, per, bool(fit.free[1]), std,
                         locking_px, bool(fit.free[5]), np.array(fit.p, float),
                         fit.covariance())


def _normal_std(p: np.ndarray, covariance: np.ndarray) -> dict[str, float]:
    """Standard deviations of the target normal's direction toward the camera's x and y
    axes [deg], propagated from the covariance of the rotation vector (parameters 7-9)
    through the normal's Jacobian (central differences): the small turns of the target
    about the camera's y and x axes, which the tilt angle alone does not show."""
    cov = np.asarray(covariance, dtype=float)
    if cov.shape[0] < 10:
        return {}
    rvec, h = np.asarray(p[7:10], dtype=float), 1e-7
    jac = np.empty((3, 3))
    for i in range(3):
        step = np.zeros(3)
        step[i] = h
        jac[:, i] = (_rodrigues(rvec + step)[:, 2] - _rodrigues(rvec - step)[:, 2]) / (2 * h)
    var = np.diag(jac @ cov[7:10, 7:10] @ jac.T)
    return {"target_normal_x_deg": math.degrees(math.sqrt(abs(float(var[0])))),
            "target_normal_y_deg": math.degrees(math.sqrt(abs(float(var[1]))))}
