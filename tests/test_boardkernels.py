"""The board renderers' compiled loops (scanqa.simulator.boardkernels) against their
numpy twins (the numpy and scipy expressions they replaced) and against geometry written
out here: the rays meet the bowed board, the squares' reflectance at chosen points.

Compiled and numpy code may round differently on another CPU, so floats are compared
within the rounding their operations allow (tests/cpu_targets.py), 8-bit frames exactly
except where a value lies within that bound of a rounding step.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.calibration.pinhole import rotation_matrix
from scanqa.simulator import boardkernels as bk
from scanqa.simulator.boardposes import ALBEDO, BOARD, sag_mm

from .cpu_targets import op_bound


def _blur_bound(image, w):
    """Two passes of 2R + 1 products and sums on values up to max |image| [units]."""
    return op_bound(2 * (2 * (w.shape[0] - 1) + 1) * 2, np.abs(image).max())


@pytest.mark.compiled_vs_numpy
@pytest.mark.parametrize("sigma", [0.0, 0.7, 1.3, 2.5])
def test_blur_agrees_with_scipys_correlate1d(sigma):
    rng = np.random.default_rng(21)
    w = bk.gaussian_weights(sigma)
    assert w.shape[0] == 1 + (0 if sigma == 0 else (int(np.rint(sigma * 8 + 1)) | 1) // 2)
    assert np.isclose(w[0] + 2 * w[1:].sum(), 1.0)
    for shape in ((64, 80), (5, 7), (2, 3), (1, 9), (9, 1), (1, 1)):
        image = rng.uniform(0, 240, shape)
        got, want = bk.blur(image, w), bk.blur_numpy(image, w)
        assert got.shape == shape
        assert np.all(np.abs(got - want) <= _blur_bound(image, w)), (sigma, shape)
    flat = np.full((6, 5), 37.0)  # a constant image stays constant (weights sum to 1)
    np.testing.assert_allclose(bk.blur(flat, w), 37.0, rtol=1e-14)


def _frames_agree(got, want_level):
    """8-bit frames from the compiled loop against the numpy pre-rounding level: equal,
    but for levels within their bound of a rounding step (x.5), where 1 DN apart."""
    want = np.clip(np.round(want_level), 0, 255).astype(np.uint8)
    tol = op_bound(40, np.abs(want_level) + 255.0)
    near = np.abs(want_level - np.floor(want_level) - 0.5) <= tol
    diff = np.abs(got.astype(int) - want.astype(int))
    assert np.all(diff[~near] == 0) and np.all(diff <= 1)


@pytest.mark.compiled_vs_numpy
def test_shots_agree_with_their_numpy_twins():
    rng = np.random.default_rng(22)
    shape = (48, 61)
    gain = 230.0 * rng.choice(list(ALBEDO.values()), shape)
    lit = rng.random(shape) < 0.8
    light = (rng.random(shape) < 0.5).astype(float)
    noise = rng.standard_normal(shape)
    w = bk.gaussian_weights(0.7)
    # a Gray-code frame: light where lit, constant noise of 2 DN (variance 4, no shot)
    got = bk.fringe_shot(8.0, gain, np.where(lit, light, 0.0), w, noise, 4.0, 0.0)
    assert got.shape == shape and got.dtype == np.uint8
    level = bk.blur_numpy(8.0 + gain * np.where(lit, light, 0.0), w) + 2.0 * noise
    _frames_agree(got, level)
    _frames_agree(bk.fringe_shot_numpy(8.0, gain, np.where(lit, light, 0.0), w, noise, 4.0,
                                       0.0), level)

    shown = rng.uniform(0, 1, shape) * lit
    noise *= 30.0  # both clips reached
    got = bk.fringe_shot(8.0, gain, shown, w, noise, 1.0, 0.05)
    blurred = bk.blur_numpy(8.0 + gain * shown, w)
    level = blurred + np.sqrt(1.0 + 0.05 * np.maximum(blurred, 0.0)) * noise
    _frames_agree(got, level)
    _frames_agree(bk.fringe_shot_numpy(8.0, gain, shown, w, noise, 1.0, 0.05), level)
    assert got.min() == 0 and got.max() == 255


def _pose():
    """A tilted board 400 mm away, bowed by 0.4 mm, and rays over its corner grid."""
    rot = rotation_matrix(np.array([0.3, -0.25, 0.1]))
    origin = np.array([-40.0, -30.0, 400.0])
    obj = BOARD.object_points.astype(float)
    centre = (obj.max(axis=0) + obj.min(axis=0)) / 2
    half = (obj.max(axis=0) - obj.min(axis=0)) / 2
    bow = np.array([0.4, -0.3, 0.2])
    rng = np.random.default_rng(23)
    nx, ny = rng.uniform(-0.2, 0.2, 4000), rng.uniform(-0.15, 0.15, 4000)
    return rot, origin, centre, half, bow, nx, ny


@pytest.mark.compiled_vs_numpy
def test_board_points_meet_the_bowed_board():
    rot, origin, centre, half, bow, nx, ny = _pose()
    normal = rot[:, 2]
    args = (nx, ny, normal, origin, rot, float(normal @ origin), bow, centre[:2], half[:2], 2)
    pts, local = bk.board_points(*args)
    ref_pts, ref_local = bk.board_points_numpy(*args)
    # ~40 operations (three steps of the ray, the rotation, the sag) on coordinates of
    # 500 mm, each step's depth amplified by 1 / cos of the ray's incidence (< 2 here)
    tol = op_bound(40, 1000.0)
    assert np.abs(pts - ref_pts).max() <= tol and np.abs(local - ref_local).max() <= tol
    # on its ray, and on the board's surface: local Z is the sag at local X, Y, each
    # fixed-point step closer (two leave < 1e-3 mm of a sag of a millimetre, tilted 0.4)
    np.testing.assert_allclose(pts[:, 0] / pts[:, 2], nx, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(pts[:, 1] / pts[:, 2], ny, rtol=1e-12, atol=1e-15)
    off = np.abs(local[:, 2] - sag_mm(BOARD, bow, local[:, :2]))
    one = bk.board_points(*args[:-1], 1)[1]
    assert off.max() < 1e-3 and off.max() < 0.1 * np.abs(one[:, 2] - sag_mm(
        BOARD, bow, one[:, :2])).max()
    back = local @ rot.T + origin  # board frame to camera frame
    np.testing.assert_allclose(back, pts, atol=1e-9)
    flat_pts, flat_local = bk.board_points(*args[:-4], np.zeros(3), centre[:2], half[:2], 0)
    np.testing.assert_allclose(flat_local[:, 2], 0.0, atol=1e-9)  # the plane alone
    np.testing.assert_allclose(flat_pts @ normal, normal @ origin, rtol=1e-13)


@pytest.mark.compiled_vs_numpy
def test_board_reflectance_of_squares_margin_and_beyond():
    s, white, black, beyond = 10.0, ALBEDO["white"], ALBEDO["black"], ALBEDO["beyond"]
    # board corners at 0 .. 10 s x 0 .. 7 s (columns 11, rows 8 of inner corners: the
    # squares run from -s to 11 s and -s to 8 s); a white margin of one square beyond
    points = {(5.0, 5.0): black, (15.0, 5.0): white, (-5.0, -5.0): black,
              (-15.0, 5.0): white, (-25.0, 5.0): beyond, (115.0, 85.0): white,
              (95.0, 75.0): black, (105.0, 75.0): white, (125.0, 5.0): beyond, (5.0, 95.0): beyond,
              (np.nan, 5.0): beyond, (1e300, 5.0): beyond, (-np.inf, 0.0): beyond}
    local = np.array([[x, y, 0.0] for x, y in points])
    want = np.array(list(points.values()))
    args = (s, BOARD.columns, BOARD.rows, white, black, beyond)
    np.testing.assert_array_equal(bk.board_reflectance(local, *args), want)
    np.testing.assert_array_equal(bk.board_reflectance_numpy(local, *args), want)
    rng = np.random.default_rng(24)
    many = np.column_stack([rng.uniform(-40, 150, (20000, 2)), np.zeros(20000)])
    # exact away from the squares' edges (a comparison, not a rounding, decides)
    edge = np.any(np.abs(many[:, :2] / s - np.rint(many[:, :2] / s)) < 1e-9, axis=1)
    np.testing.assert_array_equal(bk.board_reflectance(many, *args)[~edge],
                                  bk.board_reflectance_numpy(many, *args)[~edge])
