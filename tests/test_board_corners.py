"""The blurred-corner model (scanqa.calibration.corners) against chessboards rendered with
known corners: an area-sampled board seen through a homography, blurred and noisy, the
truth the homography's image of the board's corners (computed here, not by the code
under test)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.calibration.corners import edge_directions, fit_corner, refine_corners

ROWS, COLUMNS, SQUARE_PX = 4, 5, 40.0


def _render(hom: np.ndarray, shape=(260, 320), blur_px=1.0, noise_dn=0.0, seed=0):
    """A chessboard (squares of SQUARE_PX board units) through ``hom`` (board -> image),
    4 x 4 supersampled per pixel, Gaussian blur, noise [DN]; and its inner corners."""
    from scipy.ndimage import gaussian_filter

    sub = 4
    v, u = np.mgrid[0:shape[0] * sub, 0:shape[1] * sub]
    pix = np.stack([(u + 0.5) / sub - 0.5, (v + 0.5) / sub - 0.5, np.ones(u.shape)], -1)
    board = pix @ np.linalg.inv(hom).T
    x, y = board[..., 0] / board[..., 2], board[..., 1] / board[..., 2]
    white = (np.floor(x / SQUARE_PX) + np.floor(y / SQUARE_PX)) % 2
    image = 40 + 160 * white.reshape(shape[0], sub, shape[1], sub).mean(axis=(1, 3))
    image = gaussian_filter(image, blur_px)
    image += np.random.default_rng(seed).normal(0, noise_dn, image.shape) if noise_dn else 0
    j, i = np.meshgrid(np.arange(1, COLUMNS + 1), np.arange(1, ROWS + 1))
    pts = np.column_stack([j.ravel() * SQUARE_PX, i.ravel() * SQUARE_PX, np.ones(j.size)])
    img = pts @ hom.T
    return image, img[:, :2] / img[:, 2:]


HOM = np.array([[0.95, 0.12, 21.3], [-0.08, 0.9, 27.7], [2e-4, -1.5e-4, 1.0]])


def test_a_corner_is_found_where_it_was_drawn():
    image, truth = _render(HOM, blur_px=1.2)
    angles = edge_directions(truth, ROWS, COLUMNS)
    for n in (0, 7, 19):
        start = truth[n] + [0.6, -0.4]  # a start half a pixel off
        corner, blur = fit_corner(image, start, (angles[0][n], angles[1][n]))
        # noise-free: within 0.01 px (measured <= 0.008 px; area sampling vs the model's point
        # sampling)
        np.testing.assert_allclose(corner, truth[n], atol=0.01)
        assert 1.0 < blur < 1.6  # 1.2 px Gaussian plus the pixel's width


def test_noisy_board_refined_within_a_few_hundredths():
    image, truth = _render(HOM, blur_px=0.8, noise_dn=2.0, seed=3)
    start = truth + np.random.default_rng(1).uniform(-0.5, 0.5, truth.shape)
    refined = refine_corners(image, start, ROWS, COLUMNS)
    err = np.sqrt(np.mean(np.sum((refined - truth) ** 2, axis=1)))
    assert err < 0.03  # 2 DN noise on a 160 DN step: measured 0.010 px RMS
    # (cv2.cornerSubPix 5 px from the same starts: 0.042 px)


def test_a_corner_too_near_the_edge_keeps_its_start():
    image, _ = _render(HOM)
    start = np.array([[5.0, 5.0]])
    assert fit_corner(image, start[0], (0.0, math.pi / 2)) is None
    with pytest.raises(ValueError):  # not a grid of 4 x 5
        refine_corners(image, start, ROWS, COLUMNS)
