"""OpenCV's pinhole camera arithmetic in numpy: rotation vectors, projection, undistortion.

OpenCV (the ``calib`` extra) stays the tool for what needs its solvers (corner
detection, ``calibrateCamera``, ``stereoCalibrate``, ``solvePnP``, FileStorage files).
The arithmetic those results feed (a rotation vector to a matrix and back, projecting
points through a camera matrix and its k1 k2 p1 p2 k3 distortion, undistorting pixels)
is a few lines of numpy, so that the base install keeps every path that needs only it.
Each function is checked against its OpenCV counterpart in tests/test_opencv_twins.py (the
tolerances there).

Conventions are OpenCV's: ``K`` = [[fx, s, cx], [0, fy, cy], [0, 0, 1]] [px] (the skew
``s`` ignored, as ``cv2.projectPoints`` ignores it), distortion (k1, k2, p1, p2[, k3])
[-], a rotation vector's direction the axis and its length the angle [rad].
"""

from __future__ import annotations

import numpy as np

from scanqa.errors import InputError

#: Fixed-point iterations of :func:`undistort_points`: OpenCV's default
#: (``cv::undistortPoints`` without criteria iterates 5 times) [-].
UNDISTORT_ITERATIONS = 5


def rotation_matrix(rvec: np.ndarray) -> np.ndarray:
    """The 3 x 3 rotation of a rotation vector (``cv2.Rodrigues(rvec)[0]``).

    Parameters
    ----------
    rvec : (3,) or (3, 1) array_like
        Axis times angle [rad].

    Returns
    -------
    (3, 3) float
        The rotation matrix [-].
    """
    r = np.asarray(rvec, dtype=float).reshape(3)
    theta = float(np.linalg.norm(r))
    if theta < 1e-300:
        return np.eye(3)
    k = r / theta
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return (np.cos(theta) * np.eye(3) + (1 - np.cos(theta)) * np.outer(k, k)
            + np.sin(theta) * cross)


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector of a 3 x 3 rotation (``cv2.Rodrigues(R)[0].ravel()``).

    The matrix is first made orthonormal (its nearest rotation, by SVD, as OpenCV does).

    Parameters
    ----------
    rotation : (3, 3) array_like
        A rotation matrix [-].

    Returns
    -------
    (3,) float
        Axis times angle, the angle in [0, pi] [rad].
    """
    from scipy.spatial.transform import Rotation

    u, _, vt = np.linalg.svd(np.asarray(rotation, dtype=float).reshape(3, 3))
    return Rotation.from_matrix(u @ vt).as_rotvec()


def _distortion(dist) -> np.ndarray:
    """(k1, k2, p1, p2, k3) from OpenCV's 4 or 5 coefficients (None: none) [-]."""
    d = np.zeros(5) if dist is None else np.asarray(dist, dtype=float).ravel()
    if d.size > 5 and np.any(d[5:]):
        raise InputError(f"distortion with {d.size} coefficients: scanqa's numpy camera "
                         "model takes k1 k2 p1 p2 [k3] (the rational and thin-prism terms "
                         "need OpenCV itself)")
    return np.concatenate([d[:5], np.zeros(5 - min(d.size, 5))])


def distort(xy: np.ndarray, dist) -> np.ndarray:
    """Normalised image points through the k1 k2 p1 p2 k3 distortion [-]."""
    k1, k2, p1, p2, k3 = _distortion(dist)
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return np.column_stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y])


def project_points(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                   matrix: np.ndarray, dist=None) -> np.ndarray:
    """Pixels of 3D points (``cv2.projectPoints(...)[0].reshape(-1, 2)``).

    Parameters
    ----------
    points : (n, 3) array_like
        Points in the object frame [mm].
    rvec, tvec : (3,) array_like
        Object-to-camera rotation vector [rad] and translation [mm].
    matrix : (3, 3) array_like
        Camera matrix [px].
    dist : array_like or None
        k1 k2 p1 p2 [k3] [-].

    Returns
    -------
    (n, 2) float
        Pixel coordinates [px].
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    cam = pts @ rotation_matrix(rvec).T + np.asarray(tvec, dtype=float).reshape(3)
    z = np.where(cam[:, 2] != 0, cam[:, 2], 1.0)
    xy = distort(cam[:, :2] / z[:, None], dist)
    k = np.asarray(matrix, dtype=float)
    return np.column_stack([k[0, 0] * xy[:, 0] + k[0, 2], k[1, 1] * xy[:, 1] + k[1, 2]])


def undistort_points(pixels: np.ndarray, matrix: np.ndarray, dist=None) -> np.ndarray:
    """Normalised image points of distorted pixels (``cv2.undistortPoints``, no R, no P).

    OpenCV's own iteration: x <- (x0 - tangential(x)) / radial(x), from the distorted
    point, :data:`UNDISTORT_ITERATIONS` times.

    Parameters
    ----------
    pixels : (n, 2) array_like
        Pixel coordinates [px].
    matrix : (3, 3) array_like
        Camera matrix [px].
    dist : array_like or None
        k1 k2 p1 p2 [k3] [-].

    Returns
    -------
    (n, 2) float
        Normalised coordinates x/z, y/z [-].
    """
    k = np.asarray(matrix, dtype=float)
    px = np.asarray(pixels, dtype=float).reshape(-1, 2)
    x0 = (px[:, 0] - k[0, 2]) / k[0, 0]
    y0 = (px[:, 1] - k[1, 2]) / k[1, 1]
    k1, k2, p1, p2, k3 = _distortion(dist)
    x, y = x0.copy(), y0.copy()
    if not np.any([k1, k2, p1, p2, k3]):
        return np.column_stack([x, y])
    for _ in range(UNDISTORT_ITERATIONS):
        r2 = x * x + y * y
        icdist = 1 / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (x0 - dx) * icdist, (y0 - dy) * icdist
    return np.column_stack([x, y])
