"""A camera calibrated with the board's corner positions released (the method of OpenCV's
``calibrateCameraRO``, Strobl and Hirzinger: every corner's 3-D position fitted with the
lens and the poses), solved with the Jacobian's structure.

OpenCV builds the normal equations of this problem as one dense matrix over all
3 x corners coordinates and needs 15-20 s of CPU for five poses of a 13 x 9 board; the
same model and gauge through :func:`scipy.optimize.least_squares` with the analytic
Jacobian of ``cv2.projectPoints`` reaches the same minimum in about a second
(tests/test_release.py checks RMS, lens and fitted board against OpenCV's own).
"""

from __future__ import annotations

import numpy as np

from scanqa.errors import InputError


def _intrinsic_columns(flags: int, aspect: float) -> list:
    """The intrinsic parameters free under OpenCV's ``flags``, each as the columns of
    ``cv2.projectPoints``'s Jacobian (r t f_x f_y c_x c_y k1 k2 p1 p2 k3: 6-14) it moves,
    with the factor it moves each by; the last column is the parameter itself."""
    import cv2

    known = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_FIX_PRINCIPAL_POINT
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2
             | cv2.CALIB_FIX_K3)
    if flags & ~known:
        raise InputError(f"released-board calibration: OpenCV flags {flags & ~known} are "
                         "not supported (aspect ratio, principal point, tangential, k1-k3)")
    columns = []
    if flags & cv2.CALIB_FIX_ASPECT_RATIO:  # f_x = aspect * f_y, f_y free (OpenCV's)
        columns.append(((6, aspect), (7, 1.0)))
    else:
        columns += [((6, 1.0),), ((7, 1.0),)]
    if not flags & cv2.CALIB_FIX_PRINCIPAL_POINT:
        columns += [((8, 1.0),), ((9, 1.0),)]
    for bit, col in ((cv2.CALIB_FIX_K1, 10), (cv2.CALIB_FIX_K2, 11)):
        if not flags & bit:
            columns.append(((col, 1.0),))
    if not flags & cv2.CALIB_ZERO_TANGENT_DIST:
        columns += [((12, 1.0),), ((13, 1.0),)]
    if not flags & cv2.CALIB_FIX_K3:
        columns.append(((14, 1.0),))
    return columns


def calibrate_released(object_points: list, image_points: list, image_size: tuple[int, int],
                       fixed_point: int, flags: int = 0) -> dict:
    """Calibrate a camera with the board's corners released.

    The gauge is OpenCV's: the first corner and ``fixed_point`` held entirely, the last
    corner's z held; the start is ``cv2.calibrateCamera`` with the same ``flags``.

    Parameters
    ----------
    object_points : list of (n, 3) float32
        The ideal board's corners, the same n in every pose [mm].
    image_points : list of (n, 1, 2) or (n, 2) float32
        The corners seen in each pose [px].
    image_size : (width, height)
        The camera's image [px].
    fixed_point : int
        Index of the second corner held (OpenCV's ``iFixedPoint``; usually the last
        corner of the first row), in [1, n - 2].
    flags : int
        OpenCV calibration flags: aspect ratio, principal point, tangential, k1-k3.

    Returns
    -------
    dict
        ``rms_px`` (the residuals' RMS per corner, OpenCV's definition), ``matrix``
        (3, 3), ``dist`` (5,), ``rvecs`` and ``tvecs`` (poses, 3), ``points`` (n, 3) the
        fitted board [mm], and ``ideal_rms_px``: the start's RMS, the camera calibrated
        on the ideal board (``cv2.calibrateCamera``) [px].
    """
    import cv2
    from scipy.optimize import least_squares

    ref = np.asarray(object_points[0], dtype=float).reshape(-1, 3)
    n, poses = len(ref), len(object_points)
    if not 0 < fixed_point < n - 1:
        raise InputError(f"released-board calibration: fixed point {fixed_point} outside "
                         f"[1, {n - 2}]")
    if any(np.asarray(o).reshape(-1, 3).shape != ref.shape for o in object_points):
        raise InputError("released-board calibration needs every corner in every pose")
    seen = [np.asarray(p, dtype=float).reshape(-1, 2) for p in image_points]
    start_rms, k0, d0, rvecs, tvecs = cv2.calibrateCamera(
        [np.asarray(o, np.float32) for o in object_points],
        [np.asarray(p, np.float32) for p in image_points], tuple(image_size), None, None,
        flags=flags)
    aspect = k0[0, 0] / k0[1, 1]
    intrinsics = np.r_[k0[0, 0], k0[1, 1], k0[0, 2], k0[1, 2], np.zeros(5)]
    intrinsics[4:4 + min(d0.size, 5)] = d0.ravel()[:5]
    columns = _intrinsic_columns(flags, aspect)
    held = [0, 1, 2, 3 * fixed_point, 3 * fixed_point + 1, 3 * fixed_point + 2, 3 * n - 1]
    free = np.setdiff1d(np.arange(3 * n), held)
    corner, axis = np.divmod(free, 3)  # each free coordinate's corner and x/y/z
    columns_free = np.arange(free.size)
    ni = len(columns)

    def unpack(x):
        values = intrinsics.copy()
        for cols, p in zip(columns, x[:ni], strict=True):
            for col, weight in cols:
                values[col - 6] = weight * p
        pts = ref.ravel().copy()
        pts[free] = x[ni + 6 * poses:]
        matrix = np.array([[values[0], 0, values[2]], [0, values[1], values[3]], [0, 0, 1]])
        return matrix, values[4:], x[ni:ni + 6 * poses].reshape(poses, 6), pts.reshape(n, 3)

    def residuals_and_jacobian(x):
        matrix, dist, extrinsic, pts = unpack(x)
        res = np.empty(2 * n * poses)
        jac = np.zeros((2 * n * poses, x.size))
        for p in range(poses):
            pix, j = cv2.projectPoints(pts, extrinsic[p, :3], extrinsic[p, 3:], matrix, dist)
            rows = slice(2 * n * p, 2 * n * (p + 1))
            res[rows] = (pix.reshape(-1, 2) - seen[p]).ravel()
            for k, cols in enumerate(columns):
                jac[rows, k] = sum(weight * j[:, col] for col, weight in cols)
            jac[rows, ni + 6 * p:ni + 6 * p + 6] = j[:, :6]
            d_point = j[:, 3:6].reshape(n, 2, 3) @ cv2.Rodrigues(extrinsic[p, :3])[0]
            for k in (0, 1):  # a coordinate moves its own corner's x and y pixel only
                jac[2 * n * p + 2 * corner + k, ni + 6 * poses + columns_free] = \
                    d_point[corner, k, axis]
        return res, jac

    cache: dict = {}

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = residuals_and_jacobian(x)
        return cache[key]

    start = [intrinsics[cols[-1][0] - 6] for cols in columns]
    x0 = np.concatenate([start, np.concatenate([np.r_[r.ravel(), t.ravel()]
                                                for r, t in zip(rvecs, tvecs, strict=True)]),
                         ref.ravel()[free]])
    fit = least_squares(lambda x: evaluate(x)[0], x0, jac=lambda x: evaluate(x)[1],
                        method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    matrix, dist, extrinsic, pts = unpack(fit.x)
    return {"rms_px": float(np.sqrt(np.sum(fit.fun ** 2) / (n * poses))), "matrix": matrix,
            "dist": dist, "rvecs": extrinsic[:, :3], "tvecs": extrinsic[:, 3:],
            "points": pts, "ideal_rms_px": float(start_rms)}
