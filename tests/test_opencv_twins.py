"""scanqa's numpy/scipy twins of OpenCV arithmetic against OpenCV itself (the test venv has the
calib extra).

The numpy arithmetic must give OpenCV's numbers so that the base install (without
OpenCV) computes what a calib install computes; the tolerances are float64 rounding of
a few dozen operations on the values' scale.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.calibration.pinhole import (
    project_points,
    rotation_matrix,
    rotation_vector,
    undistort_points,
)

cv2 = pytest.importorskip("cv2")

RNG = np.random.default_rng(46)
K = np.array([[1800.0, 0, 650.3], [0, 1795.0, 510.8], [0, 0, 1]])
DISTORTIONS = [None, np.array([-0.1, 0.05, 0.0, 0.0]),
               np.array([-0.12, 0.08, 0.001, -0.0015, -0.02])]


def test_rotation_vector_and_matrix_equal_rodrigues():
    worst_m = worst_v = 0.0
    for rvec in [np.zeros(3), np.array([0, 0, 3.1]), *RNG.normal(0, 1, (50, 3))]:
        mat = cv2.Rodrigues(rvec.reshape(3, 1))[0]
        worst_m = max(worst_m, np.abs(rotation_matrix(rvec) - mat).max())
        worst_v = max(worst_v, np.abs(rotation_vector(mat) - cv2.Rodrigues(mat)[0].ravel()
                                      ).max())
    assert worst_m < 1e-14 and worst_v < 1e-12, (worst_m, worst_v)
    # below 1e-5 rad OpenCV returns a zero vector; ours keeps the angle
    assert np.abs(rotation_vector(rotation_matrix([1e-9, 0, 0])) - [1e-9, 0, 0]).max() < 1e-15


@pytest.mark.parametrize("dist", DISTORTIONS)
def test_project_points_equals_opencv(dist):
    pts = np.column_stack([RNG.uniform(-80, 80, (200, 2)), RNG.uniform(300, 500, 200)])
    rvec, tvec = np.array([0.1, -0.3, 0.05]), np.array([5.0, -12.0, 20.0])
    ours = project_points(pts, rvec, tvec, K, dist)
    theirs = cv2.projectPoints(pts, rvec, tvec, K, dist)[0].reshape(-1, 2)
    assert np.abs(ours - theirs).max() < 1e-9  # px, on values ~1000 px


@pytest.mark.parametrize("dist", DISTORTIONS)
def test_undistort_points_equals_opencv(dist):
    px = np.column_stack([RNG.uniform(0, 1300, 300), RNG.uniform(0, 1020, 300)])
    ours = undistort_points(px, K, dist)
    theirs = cv2.undistortPoints(px.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
    assert np.abs(ours - theirs).max() < 1e-12  # normalised units (~0.4)


@pytest.mark.parametrize("sigma", [0.7, 1.3])
def test_gaussian_blur_equals_opencv(sigma):
    from scanqa.simulator.boardposes import gaussian_blur

    image = RNG.uniform(0, 255, (60, 80))
    diff = np.abs(gaussian_blur(image, sigma) - cv2.GaussianBlur(image, (0, 0), sigma))
    assert diff.max() < 1e-9  # DN, on values up to 255


@pytest.mark.parametrize("radius", [1, 3, 8, 16])
def test_filter_bank_convolution_equals_filter2d(radius):
    """Direct sums (up to 7 x 7) and FFTs (above) against cv2.filter2D, BORDER_REFLECT."""
    from scanqa.annotation.filterbank import correlate_reflected

    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    kernel = np.exp(-(xx ** 2 + yy ** 2) / (0.5 * radius ** 2)) * (xx ** 2 + yy ** 2 <= radius ** 2)
    image = RNG.uniform(0, 1, (70, 90)).astype(np.float32)
    theirs = cv2.filter2D(image, cv2.CV_32F, kernel.astype(np.float32),
                          borderType=cv2.BORDER_REFLECT)
    diff = np.abs(correlate_reflected(image, kernel) - theirs).max()
    assert diff < 2e-6 * np.abs(theirs).max(), diff  # float32 rounding of a sum of taps


def test_fill_convex_equals_fill_convex_poly():
    """Shrunk, rotated board squares as characterize board labels them."""
    from scanqa.characterization.board import fill_convex

    ours, theirs = np.zeros((120, 160), np.int32), np.zeros((120, 160), np.int32)
    filled = 0
    for k in range(40):
        centre, angle = RNG.uniform([-5, -5], [165, 125]), RNG.uniform(0, np.pi)
        half = RNG.uniform(3, 15, 2)
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        quad = np.round(centre + corners @ rot.T)
        fill_convex(ours, quad, k + 1)
        cv2.fillConvexPoly(theirs, quad.astype(np.int32), k + 1)
        filled += int(np.count_nonzero(theirs == k + 1))
    differ = np.count_nonzero(ours != theirs)
    assert differ <= 0.01 * filled, (differ, filled)  # a pixel here and there on an edge


def test_the_filter_bank_takes_scipy_without_opencv(monkeypatch):
    """With OpenCV the bank uses cv2.filter2D (less CPU); without it scipy, the same sums."""
    import sys

    from scanqa.annotation.filterbank import convolve_reflected, correlate_reflected

    kernel = np.ones((5, 5)) / 25
    image = RNG.uniform(0, 1, (40, 50)).astype(np.float32)
    with_cv2 = convolve_reflected(image, kernel)
    monkeypatch.setitem(sys.modules, "cv2", None)
    without = convolve_reflected(image, kernel)
    np.testing.assert_allclose(without, correlate_reflected(image, kernel), rtol=0, atol=0)
    assert np.abs(without - with_cv2).max() < 1e-6  # float32 rounding of 25 taps of <= 1
