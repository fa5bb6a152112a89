"""The uncertainty of a parametric calibration, and what it does to a triangulated point.

The 24 parameters (:data:`scanqa.io.opencv.COVARIANCE_PARAMETERS`: both lenses' f_x,
f_y, c_x, c_y, k1 k2 p1 p2 k3, the rotation vector of Rp, Tp) of a board calibration get
a covariance C from the calibrations that left one pose out (the jackknife, Eq. 1):

    C = (n - 1) / n sum_i (theta_i - theta_bar)(theta_i - theta_bar)^T          (1)

With n poses C has rank n - 1 at most. Its effect on a point is propagated along its
principal axes (sigma points, Eq. 2): with C = sum_k lambda_k e_k e_k^T, each axis moves
the parameters by +-sqrt(lambda_k) e_k and the point (same pixel, same phase) from
P_k+ to P_k-; the point's variance along its line of sight r = P / |P| is

    sigma^2 = sum_k ( r . (P_k+ - P_k-) / 2 )^2                                  (2)

which is exact for a point that depends linearly on the parameters. The term is
systematic within a scan: every scan with the same calibration shares the same error.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from scanqa.io.opencv import COVARIANCE_PARAMETERS, OpenCVCalibration

#: Eigenvalues below this fraction of the largest are dropped (numerical rank) [-].
RANK_TOLERANCE = 1e-12


def _rodrigues(rotation: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(rotation, dtype=float))[0].ravel()


def _rotation(vector: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(vector, dtype=float).reshape(3, 1))[0]


def _lens_vector(matrix: np.ndarray, distortion: np.ndarray) -> list[float]:
    return [matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], *distortion[:5]]


def _lens_matrix(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fx, fy, cx, cy = values[:4]
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), np.array(values[4:9])


def pack_opencv(data: OpenCVCalibration) -> np.ndarray:
    """The (24,) parameter vector of an OpenCV calibration (``COVARIANCE_PARAMETERS``)."""
    return np.array([*_lens_vector(data.Kc, data.kc), *_lens_vector(data.Kp, data.kp),
                     *_rodrigues(data.Rp), *np.ravel(data.Tp)], dtype=float)


def pack(cal) -> np.ndarray:
    """The (24,) parameter vector of a :class:`ParametricCalibration`."""
    return np.array([*_lens_vector(cal.camera.matrix, cal.camera.distortion),
                     *_lens_vector(cal.projector.matrix, cal.projector.distortion),
                     *_rodrigues(cal.rotation), *cal.translation], dtype=float)


def unpack(cal, theta: np.ndarray):
    """``cal`` with the parameters ``theta`` (24,) (skew, sizes, range kept; no
    covariance: it belongs to the fitted parameters)."""
    cam_m, cam_k = _lens_matrix(theta[:9])
    proj_m, proj_k = _lens_matrix(theta[9:18])
    cam_m[0, 1], proj_m[0, 1] = cal.camera.matrix[0, 1], cal.projector.matrix[0, 1]
    return replace(cal, camera=replace(cal.camera, matrix=cam_m, distortion=cam_k),
                   projector=replace(cal.projector, matrix=proj_m, distortion=proj_k),
                   rotation=_rotation(theta[18:21]), translation=np.array(theta[21:24]),
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
        plus = unpack(cal, theta + step).apply(u, v, xp, extrapolate=True).xyz
        minus = unpack(cal, theta - step).apply(u, v, xp, extrapolate=True).xyz
        var += (np.sum(ray * (plus - minus), axis=-1) / 2) ** 2
    return np.sqrt(var)
