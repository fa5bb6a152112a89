"""The released-board camera calibration (scanqa.calibration.release) against OpenCV's
own ``calibrateCameraRO`` on the same corners, and against the simulated board's truth.

OpenCV's result is computed here by OpenCV, independently of the code under test; the
truth is the bent board the corners were projected from.
"""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from scanqa.calibration.release import calibrate_released  # noqa: E402
from scanqa.errors import InputError  # noqa: E402

COLS, ROWS, SQUARE = 8, 6, 10.0
#: OpenCV flags of the lens models scanqa calibrates: k1 (square pixels, the principal
#: point held, k1 only) and full (k1 k2 p1 p2 k3, everything free)
FLAGS = {"k1": (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2
                | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_PRINCIPAL_POINT),
         "full": 0}
SIZE = (1280, 960)
K = np.array([[1500.0, 0, 652.0], [0, 1500.0, 470.0], [0, 0, 1]])
DIST = np.array([-0.08, 0.05, 0.0, 0.0, 0.0])


def _board(bow_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The ideal grid and the bent board the camera sees (a bow of ``bow_mm`` at the
    centre, zero at the corners' rim)."""
    gx, gy = np.meshgrid(np.arange(COLS) * SQUARE, np.arange(ROWS) * SQUARE)
    ideal = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    u = (ideal[:, 0] / ideal[:, 0].max() - 0.5) * 2
    v = (ideal[:, 1] / ideal[:, 1].max() - 0.5) * 2
    true = ideal.copy()
    true[:, 2] = bow_mm * (1 - u ** 2) * (1 - v ** 2)
    return ideal, true


def _views(true: np.ndarray, noise_px: float, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    views = []
    for k in range(5):
        rvec = np.array([0.25 * np.cos(k), 0.25 * np.sin(k), 0.05 * k])
        tvec = np.array([-35.0 + 3 * k, -25.0, 260.0 + 15 * k])
        pix = cv2.projectPoints(true, rvec, tvec, K, DIST)[0].reshape(-1, 2)
        views.append((pix + rng.normal(0, noise_px, pix.shape)).astype(np.float32))
    return views


@pytest.mark.parametrize("model", ["k1", "full"])
def test_released_board_is_opencvs(model):
    ideal, true = _board(0.4)
    views = _views(true, 0.05, seed=11)
    obj = [ideal.astype(np.float32)] * len(views)
    flags = FLAGS[model]
    ours = calibrate_released(obj, views, SIZE, COLS - 1, flags)
    rms, matrix, dist, _, _, points = cv2.calibrateCameraRO(
        obj, views, SIZE, COLS - 1, None, None, flags=flags)[:6]
    assert ours["rms_px"] == pytest.approx(rms, rel=1e-6)
    assert np.allclose(ours["matrix"], matrix, atol=1e-2)  # px, of f ~ 1500 px
    assert np.allclose(ours["dist"][:5], np.ravel(dist)[:5], atol=1e-4)
    assert np.abs(ours["points"] - points.reshape(-1, 3)).max() < 1e-3  # mm


def test_released_board_finds_the_bow():
    """The fitted board's height against the bent board's truth: the bow of 0.4 mm is
    recovered to within 0.05 mm RMS (the gauge holds three corners; heights compared
    after removing the best plane, which the gauge leaves free up to the corners')."""
    ideal, true = _board(0.4)
    views = _views(true, 0.03, seed=12)
    fit = calibrate_released([ideal.astype(np.float32)] * len(views), views, SIZE,
                             COLS - 1, FLAGS["full"])
    a = np.column_stack([ideal[:, :2], np.ones(len(ideal))])
    dz = fit["points"][:, 2] - true[:, 2]
    dz -= a @ np.linalg.lstsq(a, dz, rcond=None)[0]
    assert np.sqrt(np.mean(dz ** 2)) < 0.05
    assert fit["rms_px"] < 0.04  # the released board explains the bow: noise is 0.03 px
    flat = cv2.calibrateCamera([ideal.astype(np.float32)] * len(views), views, SIZE, None,
                               None, flags=FLAGS["full"])[0]
    assert flat > 1.5 * fit["rms_px"]  # the ideal flat grid cannot


def test_released_board_refuses_a_bad_gauge():
    ideal, true = _board(0.0)
    views = _views(true, 0.05, seed=13)
    with pytest.raises(InputError, match="fixed point"):
        calibrate_released([ideal.astype(np.float32)] * len(views), views, SIZE, 0)
    with pytest.raises(InputError, match="every corner"):
        calibrate_released([*[ideal.astype(np.float32)] * 4, ideal[:-1].astype(np.float32)],
                           [*views[:4], views[4][:-1]], SIZE, COLS - 1)
