"""Board calibration (scanqa.calibration.board, board_fit, uncertainty) in closed loops
with a known camera-projector pair: corners are projected by OpenCV's ``projectPoints``
from the known truth (not by the code under test), the fit must give the truth back.
The real board poses are in tests/test_board_real.py."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose

from scanqa.calibration.board import (
    Board,
    BoardPose,
    corner_grid,
    find_corners,
    projector_corners,
)
from scanqa.calibration.board_fit import calibrate_board, compare
from scanqa.calibration.parametric import from_opencv
from scanqa.calibration.uncertainty import jackknife_covariance, pack, unpack
from scanqa.errors import InputError
from scanqa.io.opencv import (
    COVARIANCE_PARAMETERS,
    OpenCVCalibration,
    read_opencv_calibration,
    write_opencv_calibration,
)

BOARD = Board(rows=6, columns=8, square_mm=10.0)
CAMERA = (1280, 1024)
PANEL = (912, 570)
#: The truth: square pixels, radial k1 only, camera principal point at the centre
#: (lens model "k1") [px, -, mm].
TRUTH = OpenCVCalibration(
    Kc=np.array([[1800.0, 0.0, 639.5], [0.0, 1800.0, 511.5], [0.0, 0.0, 1.0]]),
    kc=np.array([-0.06, 0.0, 0.0, 0.0, 0.0]),
    Kp=np.array([[1300.0, 0.0, 450.0], [0.0, 1300.0, 400.0], [0.0, 0.0, 1.0]]),
    kp=np.array([-0.03, 0.0, 0.0, 0.0, 0.0]),
    Rp=cv2.Rodrigues(np.array([0.05, 0.25, 0.02]))[0],
    Tp=np.array([-120.0, -10.0, 30.0]),
    sizes={"frameWidth": CAMERA[0], "frameHeight": CAMERA[1], "screenResX": PANEL[0],
           "screenResY": PANEL[1]})
#: Board poses (rotation vector [rad], translation [mm]) in the camera frame.
POSES = [((0.2, 0.1, 0.05), (-35.0, -25.0, 400.0)), ((-0.25, 0.2, -0.1), (-40.0, -20.0, 380.0)),
         ((0.1, -0.3, 0.2), (-30.0, -30.0, 420.0)), ((0.35, 0.05, -0.05), (-45.0, -15.0, 390.0)),
         ((-0.1, -0.2, 0.3), (-25.0, -35.0, 410.0)), ((0.0, 0.35, 0.0), (-35.0, -20.0, 370.0))]


def synthetic_pose(k: int, noise_px: float = 0.0, seed: int = 0) -> BoardPose:
    """Pose k of POSES seen by TRUTH, with Gaussian corner noise [px]."""
    rvec, tvec = (np.array(a, dtype=float) for a in POSES[k])
    obj = BOARD.object_points.astype(float)
    cam = cv2.projectPoints(obj, rvec, tvec, TRUTH.Kc, TRUTH.kc)[0].reshape(-1, 2)
    rot = TRUTH.Rp @ cv2.Rodrigues(rvec)[0]
    proj = cv2.projectPoints(obj, cv2.Rodrigues(rot)[0], TRUTH.Rp @ tvec + TRUTH.Tp,
                             TRUTH.Kp, TRUTH.kp)[0].reshape(-1, 2)
    rng = np.random.default_rng(seed + k)
    cam, proj = (p + noise_px * rng.standard_normal(p.shape) for p in (cam, proj))
    empty = np.full((1, 1), np.nan)
    return BoardPose(f"pose{k}", cam, proj, (0, 0, 1, 1), empty, empty, CAMERA)


def test_noise_free_corners_give_the_truth_back():
    result = calibrate_board([synthetic_pose(k) for k in range(6)], BOARD, PANEL)
    data = result.data
    assert_allclose(data.Kc, TRUTH.Kc, rtol=1e-6, atol=1e-6)  # exact data: solver precision
    assert_allclose(data.Kp, TRUTH.Kp, rtol=1e-6, atol=1e-4)
    assert_allclose(data.kc, TRUTH.kc, atol=1e-5)  # measured 1.6e-6
    assert_allclose(data.kp, TRUTH.kp, atol=1e-5)
    assert_allclose(data.Rp, TRUTH.Rp, atol=1e-6)  # measured 3e-7
    assert_allclose(data.Tp, TRUTH.Tp, atol=1e-3)
    assert all(v < 1e-4 for v in data.errors.values())
    diff = compare(data, TRUTH)
    assert abs(diff["camera_focal_rel"]) < 1e-6 and diff["rotation_deg"] < 1e-4
    assert data.covariance.shape == (24, 24)
    # every subset gives the truth to solver precision: f within 1e-3 px (std, measured 8e-4)
    assert np.abs(data.covariance).max() < 1e-6


def test_noisy_corners_land_near_the_truth_and_the_spread_covers_the_error():
    result = calibrate_board([synthetic_pose(k, 0.2) for k in range(6)], BOARD, PANEL)
    data, cov = result.data, result.data.covariance
    # 0.2 px of corner noise: each pose's RMS is sqrt(2) x 0.2 px in expectation
    for pose in result.poses:
        assert 0.15 < pose.camera_rms_px < 0.35 and not pose.flagged
    err = pack_truth_difference(data)
    std = np.sqrt(np.diag(cov))
    free = std > 0
    # k1 model: f_x = f_y, k1 (+ c_x, c_y of the projector), R, T; the left-out lens
    # terms (camera c_x, c_y, k2; projector k2) enter only where the data show them
    assert 14 <= free.sum() <= 18
    # the joint fit's std: every error within 3.5 of them (a 1-in-2000 miss per parameter)
    assert np.all(np.abs(err[free]) <= 3.5 * std[free]), (err[free], std[free])
    # the jackknife (the check) is of the same order on the parameters both let move
    jack = np.sqrt(np.diag(result.jackknife))
    both = free & (jack > 0)
    assert both.sum() >= 14
    assert np.all((jack[both] > 0.2 * std[both]) & (jack[both] < 5 * std[both]))


def pack_truth_difference(data: OpenCVCalibration) -> np.ndarray:
    """Fitted minus true parameters, in COVARIANCE_PARAMETERS order (computed here)."""
    def vec(d):
        return np.array([d.Kc[0, 0], d.Kc[1, 1], d.Kc[0, 2], d.Kc[1, 2], *d.kc,
                         d.Kp[0, 0], d.Kp[1, 1], d.Kp[0, 2], d.Kp[1, 2], *d.kp,
                         *cv2.Rodrigues(d.Rp)[0].ravel(), *d.Tp])
    return vec(data) - vec(TRUTH)


def test_a_pose_that_is_off_is_flagged():
    poses = [synthetic_pose(k, 0.1) for k in range(5)] + [synthetic_pose(5, 1.0)]
    result = calibrate_board(poses, BOARD, PANEL, covariance=False)
    assert result.flagged == ["pose5"]
    assert result.data.covariance is None


def test_the_written_file_is_read_back_and_triangulates(tmp_path):
    result = calibrate_board([synthetic_pose(k, 0.1) for k in range(6)], BOARD, PANEL)
    path = write_opencv_calibration(tmp_path / "cal.xml", result.data)
    back = read_opencv_calibration(path)
    for key in ("Kc", "kc", "Kp", "kp", "Rp", "Tp", "covariance"):
        assert_allclose(getattr(back, key), getattr(result.data, key), rtol=1e-15)
    assert back.sizes == result.data.sizes and back.errors == result.data.errors
    cal = from_opencv(back)
    assert cal.covariance is not None
    # a board corner seen by the true camera and projector triangulates to itself
    rvec, tvec = (np.array(a, dtype=float) for a in POSES[0])
    point = cv2.Rodrigues(rvec)[0] @ BOARD.object_points[10] + tvec
    exact = from_opencv(TRUTH)
    u, v = cv2.projectPoints(point[None], np.zeros(3), np.zeros(3), TRUTH.Kc,
                             TRUTH.kc)[0].ravel()
    xp = cv2.projectPoints(point[None], cv2.Rodrigues(TRUTH.Rp)[0], TRUTH.Tp, TRUTH.Kp,
                           TRUTH.kp)[0].ravel()[0]
    assert_allclose(exact.apply(u, v, xp).xyz, point, atol=1e-6)
    assert_allclose(cal.apply(u, v, xp).xyz, point, atol=0.5)  # 0.1 px of noise


def test_write_refuses_a_suffix_opencv_does_not_read(tmp_path):
    with pytest.raises(InputError, match="must end in"):
        write_opencv_calibration(tmp_path / "cal.txt", TRUTH)


def test_projector_corners_of_an_exact_homography():
    hom = np.array([[1.1, 0.05, 30.0], [-0.02, 0.95, 12.0], [1e-4, -5e-5, 1.0]])
    rows, cols = np.mgrid[0:200, 0:240].astype(float)
    w = hom[2, 0] * cols + hom[2, 1] * rows + hom[2, 2]
    xp = (hom[0, 0] * cols + hom[0, 1] * rows + hom[0, 2]) / w
    yp = (hom[1, 0] * cols + hom[1, 1] * rows + hom[1, 2]) / w
    xp[90:110, 60:70] = np.nan  # masked pixels do not matter
    corners = np.array([[60.3, 100.7], [150.25, 40.5], [3.0, 3.0]])
    got = projector_corners(corners + np.array([500, 300]), xp, yp, offset=(500, 300))
    for (u, v), (x, y) in zip(corners, got, strict=True):
        den = hom[2, 0] * u + hom[2, 1] * v + hom[2, 2]
        assert_allclose([x, y], [(hom[0, 0] * u + hom[0, 1] * v + hom[0, 2]) / den,
                                 (hom[1, 0] * u + hom[1, 1] * v + hom[1, 2]) / den],
                        atol=1e-6)
    none = projector_corners(np.array([[100.0, 100.0]]), np.full((200, 240), np.nan), yp)
    assert np.isnan(none).all()


def test_corners_of_a_rendered_board():
    """A chessboard drawn at 8 px per mm and warped by a known homography."""
    scale, margin = 8, 40
    squares = np.indices((BOARD.rows + 1, BOARD.columns + 1)).sum(axis=0) % 2
    flat = np.kron(squares, np.ones((10 * scale, 10 * scale)))
    flat = np.pad(flat, margin, constant_values=1.0) * 160 + 30
    hom = np.array([[0.9, 0.1, 80.0], [-0.05, 0.85, 60.0], [1e-5, 5e-5, 1.0]])
    image = cv2.warpPerspective(flat, hom, (1000, 800), flags=cv2.INTER_AREA,
                                borderValue=20.0)
    image = cv2.GaussianBlur(image, (0, 0), 1.0)
    found = find_corners(image, BOARD)
    grid = BOARD.object_points[:, :2] * scale + margin + 10 * scale - 0.5
    truth = cv2.perspectiveTransform(grid[None].astype(float), hom)[0]
    if np.linalg.norm(found[0] - truth[0]) > np.linalg.norm(found[0] - truth[-1]):
        found = found[::-1]  # the board is symmetric under a half turn
    assert_allclose(found, truth, atol=0.1)  # sub-pixel on a clean rendering
    model = find_corners(image, BOARD, "model")
    if np.linalg.norm(model[0] - truth[0]) > np.linalg.norm(model[0] - truth[-1]):
        model = model[::-1]
    assert_allclose(model, truth, atol=0.05)  # measured <= 0.027 px (OpenCV's 0.040 px)
    rms = [np.sqrt(np.mean(np.sum((c - truth) ** 2, axis=1))) for c in (model, found)]
    assert rms[0] < rms[1]  # measured 0.017 vs 0.024 px
    with pytest.raises(InputError, match="corner method must be one of"):
        find_corners(image, BOARD, "saddle")
    assert find_corners(np.full((400, 500), 100.0), BOARD) is None
    # the grid drawn, found with no size given (short side first), either way round
    assert corner_grid(image) == (BOARD.rows, BOARD.columns)
    assert corner_grid(image.T) == (BOARD.rows, BOARD.columns)
    assert corner_grid(np.full((400, 500), 100.0)) is None


def test_jackknife_covariance_by_hand():
    # two parameters, three fits: mean (2, 1); deviations (-1, 0), (0, 1), (1, -1);
    # (n - 1) / n = 2/3 times the sum of outer products [[2, -1], [-1, 2]]
    thetas = np.array([[1.0, 1.0], [2.0, 2.0], [3.0, 0.0]])
    assert_allclose(jackknife_covariance(thetas), [[4 / 3, -2 / 3], [-2 / 3, 4 / 3]])


def test_pack_and_unpack_are_inverse():
    cal = from_opencv(TRUTH)
    theta = pack(cal)
    assert len(theta) == len(COVARIANCE_PARAMETERS)
    moved = unpack(cal, theta + 0.01)
    assert_allclose(pack(moved), theta + 0.01, atol=1e-12)
    assert_allclose(unpack(cal, theta).rotation, cal.rotation, atol=1e-14)


def test_calibration_sigma_of_one_uncertain_parameter():
    """Only T_z uncertain (std 2 mm): sigma is the move of the point along its ray when
    Tp changes by +-2 mm, triangulated here with calibrations built from the file data."""
    cov = np.zeros((24, 24))
    cov[23, 23] = 4.0
    cal = from_opencv(OpenCVCalibration(**{**TRUTH.__dict__, "covariance": cov}))
    rvec, tvec = (np.array(a, dtype=float) for a in POSES[1])
    points = (cv2.Rodrigues(rvec)[0] @ BOARD.object_points[[0, 20, 47]].T).T + tvec
    u, v = cv2.projectPoints(points, np.zeros(3), np.zeros(3), TRUTH.Kc,
                             TRUTH.kc)[0].reshape(-1, 2).T
    xp = cv2.projectPoints(points, cv2.Rodrigues(TRUTH.Rp)[0], TRUTH.Tp, TRUTH.Kp,
                           TRUTH.kp)[0].reshape(-1, 2)[:, 0]
    moved = [from_opencv(OpenCVCalibration(**{**TRUTH.__dict__,
                                              "Tp": TRUTH.Tp + np.array([0.0, 0.0, s])}))
             for s in (2.0, -2.0)]
    p0 = cal.apply(u, v, xp).xyz
    ray = p0 / np.linalg.norm(p0, axis=1, keepdims=True)
    expected = np.abs(np.sum(ray * (moved[0].apply(u, v, xp).xyz
                                    - moved[1].apply(u, v, xp).xyz), axis=1)) / 2
    assert_allclose(cal.calibration_sigma_mm(u, v, xp), expected, rtol=1e-9)
    assert expected.max() > 0.5  # T_z moves points by up to ~1 mm here
    nan = cal.calibration_sigma_mm(np.array([400.0]), np.array([300.0]), np.array([np.nan]))
    assert np.isnan(nan).all()
    assert np.isnan(from_opencv(TRUTH).calibration_sigma_mm(u, v, xp)).all()  # no covariance


def test_bad_boards_and_models_are_refused():
    with pytest.raises(InputError, match="rows must be a whole number >= 2"):
        Board(1, 8, 10.0)
    with pytest.raises(InputError, match="square_mm must be > 0"):
        Board(6, 8, 0.0)
    with pytest.raises(InputError, match="lens model must be one of"):
        calibrate_board([synthetic_pose(0)] * 2, BOARD, PANEL, model="fisheye")
    with pytest.raises(InputError, match="at least 2 poses"):
        calibrate_board([synthetic_pose(0)], BOARD, PANEL)


def test_report_renders_poses_flags_and_the_comparison():
    from dataclasses import replace

    from scanqa.report import board as report_board

    poses = [synthetic_pose(k, 0.1) for k in range(5)] + [synthetic_pose(5, 1.0)]
    result = calibrate_board(poses, BOARD, PANEL)
    result = replace(result, comparison=compare(result.data, TRUTH))
    info = report_board.summary(result)
    assert info["flagged_poses"] == ["pose5"]
    assert set(info["parameter_std"]) == set(COVARIANCE_PARAMETERS)
    assert info["parameter_std_fit"]["camera_fx"] > 0
    html = report_board.render(result)
    assert "Flagged (pose RMS &gt; 2 x the median of the other poses): pose5" in html
    assert "cam_error [px]: ours / reference" in html
