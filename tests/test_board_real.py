"""The real board poses behind SLStudio's calibration.xml (README of the real-data folder:
six poses calseq1..6 of a chessboard with 10 mm squares and 9 x 13 saddle points, 2 x
3-step phase shift in columns (114 and 1824 px) and rows (71.25 and 1140 px); SLStudio's
dialog used sequences 1 and 3-6). scanqa calibrates from them with its own decoder and
is held against SLStudio's file, which nobody on this project computed.

Measured (lens model "k1", SLStudio's: square pixels, k1, camera principal point at the
centre), poses 1, 3-6: RMS camera 0.295 px (SLStudio 0.282), projector 0.317 px (0.463),
stereo 0.356 px (0.422); focal lengths +0.41 % (camera) and +0.14 % (projector);
rotation 0.42 deg; baseline direction 0.57 deg, length +0.58 %. Each pose left out:
plane RMS 0.157, 0.246, 0.229, 0.296, 0.213 mm (calibration.xml: 0.157, 0.251, 0.235,
0.295, 0.222 mm). skull_2x3 triangulated with both: median |dXYZ| 1.07 mm, calibration
sigma (jackknife over the five poses) 3.0-4.3 mm, median |dXYZ| / sigma 0.32. The
camera's RMS and the baseline direction miss issue 25's bounds because the board is not
flat (test_the_camera_residual_is_the_boards, docs/calibration.rst).

With corner_method="model" (the detector a rule fixed beforehand chose, by its
repeatability between the column and the row frames): camera 0.249 px, projector 0.264,
stereo 0.306; f +0.32 % / +0.11 %; rotation 0.41 deg; baseline 0.62 deg, +0.58 %: the
camera's bound met, the baseline direction still missed (by both detectors). It is the
default since (more accurate by every measure independent of the bounds); the tests on
`poses` ask for OpenCV's corners explicitly.

The baseline direction's miss, looked into (docs/studies/board_direction.py): the row set's
71.25 px period is right (the decoder's drift warning on poses 3-6 is a step in the cue,
not a period), no corner-level or stereo variant passes the rule chosen beforehand
(held-out predicted projector RMS), and calibration.xml predicts our projector corners to
2.6-5.1 px only: the gap lies between SLStudio's correspondences and ours, at the scale of
the direction's own jackknife std (0.44 deg).
"""

from __future__ import annotations

import functools
import json
from dataclasses import replace

import numpy as np
import pytest

from scanqa.calibration.board import Board, decode_pose, find_corners, projector_corners
from scanqa.calibration.board_fit import board_flatness, calibrate_board, compare, hold_out
from scanqa.calibration.corners import refine_corners
from scanqa.calibration.parametric import from_opencv, load_opencv_calibration
from scanqa.cli import main
from scanqa.decoding.decoder import decode_pattern_dir
from scanqa.decoding.parsing import load_patterns
from scanqa.io.opencv import read_opencv_calibration
from scanqa.io.patterns import dumps_patterns
from tests.realdata import (
    SLSTUDIO,
    SLSTUDIO_SHIFTS,
    needs_slstudio,
    slstudio_board_patterns,
)
from tests.shared_runs import share_board_calibration

pytestmark = needs_slstudio

CALIBRATION = SLSTUDIO / "calibration"
BOARD = Board(rows=9, columns=13, square_mm=10.0)
PANEL = (1824, 1140)


@pytest.fixture(scope="module")
def patterns(tmp_path_factory):
    return tuple(str(p) for p in slstudio_board_patterns(
        tmp_path_factory.mktemp("board_patterns")))


@pytest.fixture(scope="module")
def poses(patterns):
    """The six poses, decoded once (about 25 s on two busy cores), the corner grid found
    in the frames (only the square size is given)."""
    cols, rows = (load_patterns(p) for p in patterns)
    return [decode_pose(CALIBRATION / f"calseq{k}", cols, rows, BOARD.square_mm,
                        corner_method="opencv") for k in range(1, 7)]


@pytest.fixture(scope="module")
def slstudio_poses(poses):
    """The calibration of the poses SLStudio used (1, 3-6)."""
    return calibrate_board([poses[k] for k in (0, 2, 3, 4, 5)], BOARD, PANEL)


def test_every_corner_is_found_and_decoded(poses):
    for pose in poses:
        assert pose.board == BOARD  # 9 x 13 found in the frames, as SLStudio's dialog says
        assert pose.camera_px.shape == (117, 2)
        assert np.isfinite(pose.projector_px).all()
        # inside the panel
        assert (pose.projector_px > 0).all() and (pose.projector_px < PANEL).all()


def test_against_slstudio_calibration(slstudio_poses):
    ours = slstudio_poses.data
    ref = read_opencv_calibration(CALIBRATION / "calibration.xml")
    diff = compare(ours, ref)
    assert ours.errors["proj_error"] <= ref.errors["proj_error"]  # 0.317 vs 0.463 px
    assert ours.errors["stereo_error"] <= ref.errors["stereo_error"]  # 0.356 vs 0.422 px
    # the camera's RMS is 5 % above SLStudio's 0.282 px (measured 0.295 px), short of
    # issue 25's bound: the board is not flat (test_the_camera_residual_is_the_boards)
    assert ours.errors["cam_error"] <= 1.1 * ref.errors["cam_error"]
    assert abs(diff["camera_focal_rel"]) < 0.01  # measured +0.41 %
    assert abs(diff["projector_focal_rel"]) < 0.01  # measured +0.14 %
    assert diff["rotation_deg"] < 0.5  # measured 0.42 deg
    # the joint fit (issue 42) moves the baseline from OpenCV's sequential fit (+0.58 %,
    # 0.57 deg from SLStudio's): measured +1.33 %; see test_model_corners_against_slstudio
    assert abs(diff["baseline_rel"]) < 0.02
    assert diff["baseline_deg"] < 2.5
    assert slstudio_poses.flagged == []


@pytest.mark.slow  # ~19 s of CPU: five-pose calibrations with the board released
def test_the_camera_residual_is_the_boards(poses):
    """The camera's 0.295 px is not its lens model nor its corner detector: calibration.xml's
    own camera on our corners gives 0.297 px, the full model k1 k2 p1 p2 k3 with a free
    principal point 0.282 px, corners from other frame averages move by 0.04 px RMS; the
    residuals of a corner agree between similar poses (correlation 0.95 for 3 and 6).
    With the board's corners released the camera fits to 0.158 px, and the board so
    measured by the camera lowers the projector's RMS from 0.317 to 0.252 px: the
    projector sees the same departure from flatness through the phase."""
    shape = board_flatness([poses[k] for k in (0, 2, 3, 4, 5)], BOARD, PANEL)
    assert shape["camera_rms_released_px"] < 0.6 * shape["camera_rms_px"]  # 0.158 / 0.295
    # independent: the projector's corners never saw the board's texture (0.252 / 0.317)
    assert shape["projector_rms_camera_board_px"] < 0.9 * shape["projector_rms_px"]
    assert 0.03 < shape["out_of_plane_mm"] < 0.3  # measured 0.089 mm
    assert shape["in_plane_mm"] < 0.3  # measured 0.086 mm


def test_sequence_2_is_not_off(poses):
    """SLStudio's dialog left sequence 2 out; its residuals are like the others'."""
    result = calibrate_board(poses, BOARD, PANEL, covariance=False)
    assert result.flagged == []
    second = result.poses[1]
    assert second.name == "calseq2"
    cams = [p.camera_rms_px for p in result.poses]
    projs = [p.projector_rms_px for p in result.poses]
    assert min(cams) < second.camera_rms_px < max(cams)  # measured 0.309 (0.249-0.356)
    assert min(projs) < second.projector_rms_px < max(projs)  # 0.355 (0.286-0.370)


def test_each_pose_left_out_is_as_flat_as_with_slstudio(poses):
    reference = load_opencv_calibration(CALIBRATION / "calibration.xml")
    five = [poses[k] for k in (0, 2, 3, 4, 5)]
    rows = hold_out(five, BOARD, PANEL, reference=reference)
    for row in rows:  # issue 25: within 1.2 x of calibration.xml (measured <= 1.002 x)
        assert row["plane_rms_mm"] <= 1.2 * row["reference_plane_rms_mm"], row
        assert row["projector_rms_px"] < 1.5, row  # predicted, measured 0.55-1.19 px


@pytest.fixture(scope="module")
def skull(tmp_path_factory):
    """skull_2x3 decoded (once for both corner detectors): every 7th valid pixel's u, v,
    x_p [px]."""
    folder = tmp_path_factory.mktemp("skull")
    frames = [str(SLSTUDIO / "skull_2x3" / f"frameSeq_{i:02d}.bmp") for i in range(6)]
    (folder / "patterns.toml").write_text(dumps_patterns({
        "format": "scanqa-patterns/2", "projector_width_px": 1824, "set": [
            {"kind": "phase", "name": "p114", "period_px": 114.0, "steps": 3,
             "shifts_rad": SLSTUDIO_SHIFTS, "files": frames[:3]},
            {"kind": "phase", "name": "p1824", "period_px": 1824.0, "steps": 3,
             "shifts_rad": SLSTUDIO_SHIFTS, "files": frames[3:]}]}))
    pm = decode_pattern_dir(folder)
    v, u = (a[::7] for a in np.nonzero(pm.valid))
    return u, v, pm.xp[v, u]


@pytest.mark.parametrize("corners", ["opencv", "model"])
def test_skull_against_slstudio_within_the_calibration_sigma(corners, request, skull):
    """skull_2x3 triangulated with our calibration (either corner detector; "model" is the
    default's) against calibration.xml: within the calibration's own 2 sigma."""
    calibration = request.getfixturevalue(
        "slstudio_poses" if corners == "opencv" else "model_calibration")
    u, v, xp = skull
    ours = from_opencv(calibration.data)
    ref = load_opencv_calibration(CALIBRATION / "calibration.xml")
    diff = np.linalg.norm(ours.apply(u, v, xp).xyz - ref.apply(u, v, xp).xyz, axis=1)
    sigma = ours.calibration_sigma_mm(u, v, xp)
    ok = np.isfinite(diff) & np.isfinite(sigma)
    assert ok.mean() > 0.99
    # measured at ~390 mm, the joint fit's calibrations: opencv corners median 0.80 mm,
    # model corners 0.71 mm (the sequential OpenCV fit's were 1.07 and 0.68 mm)
    assert 0.3 < np.median(diff[ok]) < 1.5
    # issue 42: the joint fit's sigma (median 0.82 mm with model corners, where the
    # jackknife over the five poses said 3.7 mm) predicts the difference from SLStudio's
    # calibration: median |dXYZ| / median sigma in [0.5, 2] (measured 0.87 model, see
    # docs/studies/calibration_covariance.py real)
    assert 0.5 <= np.median(diff[ok]) / np.median(sigma[ok]) <= 2.0
    assert np.mean(diff[ok] <= 2 * sigma[ok]) >= 0.8


@pytest.mark.slow  # ~30 s of CPU: three poses decoded and calibrated through the CLI
def test_cli_writes_a_calibration_every_command_reads(patterns, tmp_path, capsys,
                                                     monkeypatch):
    share_board_calibration(monkeypatch)  # computed once with test_api's
    out = tmp_path / "board.xml"
    poses = [str(CALIBRATION / f"calseq{k}") for k in (1, 3, 6)]
    assert main(["calibrate", "--square-mm", "10", "--patterns",  # grid from the frames
                 *patterns, *poses, "--out", str(out), "-q"]) == 0  # model corners: default
    cal = load_opencv_calibration(out)
    assert cal.covariance is not None and cal.covariance.shape == (24, 24)
    # the same covariance as a covariance file beside it (--calibration-covariance reads it)
    from scanqa.io.covariance import read_covariance

    np.testing.assert_allclose(read_covariance(tmp_path / "board_covariance.json"),
                               cal.covariance, rtol=1e-12, atol=0)
    report = json.loads((tmp_path / "board_report.json").read_text())
    assert [p["pose"] for p in report["poses"]] == ["calseq1", "calseq3", "calseq6"]
    assert report["corner_method"] == "model"
    assert "corners model; lens model k1" in (tmp_path / "board_report.html").read_text()
    assert report["errors_px"]["cam_error"] < 0.4
    # the joint fit's std of f (what the calibration sigma uses) and the jackknife's check
    assert report["parameter_std"]["camera_fx"] > 0
    assert report["parameter_std_jackknife"]["camera_fx"] > 0
    assert report["joint_fit"]["noise_px"]["camera"] < 0.4
    assert "Reprojection RMS per pose" in (tmp_path / "board_report.html").read_text()
    flat = report["board_flatness"]  # three poses: the board's shape shows there too
    assert flat["camera_rms_released_px"] < flat["camera_rms_px"]
    assert "Is the board flat?" in (tmp_path / "board_report.html").read_text()


def test_cli_refuses_a_board_without_its_size(patterns, tmp_path, capsys):
    code = main(["calibrate", "--board", "9x13", str(CALIBRATION / "calseq1"), "--out",
                 str(tmp_path / "x.xml")])
    assert code == 2
    assert "needs --square-mm and --patterns" in capsys.readouterr().err
    code = main(["calibrate", "--board", "9x13", "--square-mm", "10", "--patterns",
                 *patterns, str(CALIBRATION / "calseq1"), "--out", str(tmp_path / "x.npz")])
    assert code == 2
    assert "is an OpenCV file" in capsys.readouterr().err
    code = main(["calibrate", "--board", "9x12", "--square-mm", "10", "--patterns",
                 *patterns, str(CALIBRATION / "calseq1"), "--out", str(tmp_path / "x.xml")])
    assert code == 2  # the check: the frames show 9 x 13
    assert "9 x 13 inner corners, --board says 9 x 12" in capsys.readouterr().err


def _frames(k: int) -> np.ndarray:
    """The 12 frames of pose calseq<k> (README: 00-05 columns, 06-11 rows) [DN]."""
    return _png_frames(k).astype(float)


@functools.lru_cache(maxsize=6)
def _png_frames(k: int) -> np.ndarray:
    """calseq<k>'s 12 PNG files decoded once for the file's tests (poses 1, 4 and 5 are
    read by two or three of them; 27 MB a pose as read) [DN]."""
    import cv2

    frames = np.array([cv2.imread(str(CALIBRATION / f"calseq{k}" / f"frameSeq_{i:02d}.png"),
                                  cv2.IMREAD_GRAYSCALE) for i in range(12)])
    frames.flags.writeable = False
    return frames


@pytest.fixture(scope="module")
def model_poses(poses):
    """The six poses with the corners of ``corner_method="model"`` (found in the mean of all
    12 frames, placed by the blurred-corner model); their projector corners from the
    decoded maps of ``poses`` (decoded pixel by pixel: against decode_pose(...,
    corner_method="model") the camera corners agree to 1e-6 px, the projector corners to
    2e-5 px, the RMS of the calibration below to 1e-6 px)."""
    out = []
    for k, pose in enumerate(poses, start=1):
        camera = find_corners(_frames(k).mean(axis=0), BOARD, "model")
        proj = projector_corners(camera, pose.xp, pose.yp, offset=pose.crop[:2])
        out.append(replace(pose, camera_px=camera, projector_px=proj))
    return out


def test_model_corners_repeat_between_column_and_row_frames():
    """The rule that chose the corner detector (docs/calibration.rst, fixed before any
    candidate was measured): the same corners found in the column frames and in the row
    frames of a pose, two independent captures. Over all six poses: OpenCV's 0.031 px
    (0.043 px in the finest column set alone, today's image), the model's 0.014 px (per
    image, RMS / sqrt 2); here two poses (0.037 and 0.015 px)."""
    spread = {"opencv": [], "model": []}
    for k in (1, 4):
        frames = _frames(k)
        found = []
        for image in (frames[:6].mean(axis=0), frames[6:].mean(axis=0)):
            opencv = find_corners(image, BOARD)
            found.append((opencv, refine_corners(image, opencv, BOARD.rows, BOARD.columns)))
        (col_cv, col_model), (row_cv, row_model) = found
        if np.abs(col_cv - row_cv[::-1]).max() < np.abs(col_cv - row_cv).max():
            row_cv, row_model = row_cv[::-1], row_model[::-1]  # OpenCV's order may flip
        spread["opencv"].append(col_cv - row_cv)
        spread["model"].append(col_model - row_model)
    rms = {key: np.sqrt(np.mean(np.sum(np.concatenate(d) ** 2, axis=1)) / 2)
           for key, d in spread.items()}
    assert rms["model"] < 0.6 * rms["opencv"], rms  # measured 0.014 vs 0.031 px, 6 poses
    assert rms["model"] < 0.025, rms


@pytest.fixture(scope="module")
def model_calibration(model_poses):
    return calibrate_board([model_poses[k] for k in (0, 2, 3, 4, 5)], BOARD, PANEL)


def test_model_corners_against_slstudio(model_calibration):
    """The detector the rule chose, on the poses SLStudio used (1, 3-6). The camera's RMS
    meets issue 25's bound; the baseline direction still does not (0.62 deg, 0.57 with
    OpenCV's corners), missed by both detectors (docs/calibration.rst)."""
    ours = model_calibration.data
    ref = read_opencv_calibration(CALIBRATION / "calibration.xml")
    diff = compare(ours, ref)
    assert ours.errors["cam_error"] <= ref.errors["cam_error"]  # 0.249 vs 0.282 px
    assert ours.errors["proj_error"] <= ref.errors["proj_error"]  # 0.264 vs 0.463 px
    assert ours.errors["stereo_error"] <= ref.errors["stereo_error"]  # 0.306 vs 0.422 px
    assert abs(diff["camera_focal_rel"]) < 0.01  # measured +0.32 %
    assert abs(diff["projector_focal_rel"]) < 0.01  # measured +0.11 %
    assert diff["rotation_deg"] < 0.5  # measured 0.41 deg
    # The joint fit of camera, projector, poses and the board's bow (issue 42; OpenCV's
    # sequential fit gave +0.58 % and 0.62 deg, SLStudio's own procedure is sequential
    # too) lies further from SLStudio's baseline: +1.30 %, 1.79 deg, where its covariance
    # gives 0.16 % and 0.21 deg. It predicts the held-out poses' projector corners better
    # (each of the six left out: mean 0.653 px against 0.704 px), is 4 x closer to the
    # truth in the simulated study (docs/studies/calibration_covariance.py), and its
    # skull_2x3 points lie as close to calibration.xml's (median 0.71 mm against 0.68 mm):
    # the baseline trades against the other parameters.
    assert abs(diff["baseline_rel"]) < 0.02
    assert diff["baseline_deg"] < 2.5
    assert model_calibration.flagged == []


def test_model_corners_each_pose_left_out(model_poses):
    reference = load_opencv_calibration(CALIBRATION / "calibration.xml")
    five = [model_poses[k] for k in (0, 2, 3, 4, 5)]
    for row in hold_out(five, BOARD, PANEL, reference=reference):
        # issue 25: within 1.2 x of calibration.xml (measured 0.96-1.00 x)
        assert row["plane_rms_mm"] <= 1.2 * row["reference_plane_rms_mm"], row
        assert row["projector_rms_px"] < 1.5, row  # predicted, measured 0.50-1.15 px


def _phase(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3-step phase of SLStudio's shifts (0, 2pi/3, 4pi/3 subtracted, README) [rad] and
    amplitude [DN], computed here, not by scanqa's decoder."""
    delta = 2 * np.pi * np.arange(3) / 3
    s, c = np.tensordot(np.sin(delta), stack, 1), np.tensordot(np.cos(delta), stack, 1)
    return np.arctan2(s, c) % (2 * np.pi), np.hypot(s, c) * 2 / 3


def _row_cue_drift(k: int, pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The row set's cue minus its unwrapped fine coordinate on the board [projector px],
    with the fine coordinate [px] and the camera row [px] of each pixel."""
    import cv2

    u0, v0, u1, v1 = pose.crop
    stack = _frames(k)[6:, v0:v1, u0:u1]
    fine, _ = _phase(stack[:3])
    cue, amplitude = _phase(stack[3:])
    y_cue, f = cue / (2 * np.pi) * 1140, fine / (2 * np.pi)
    y = 71.25 * (np.round(y_cue / 71.25 - f) + f)
    inside = np.zeros(y.shape, np.uint8)
    hull = cv2.convexHull((pose.camera_px - (u0, v0)).astype(np.float32))
    cv2.fillConvexPoly(inside, np.round(hull).astype(np.int32), 1)
    ok = inside.astype(bool) & (amplitude > 8)
    rows = np.broadcast_to(np.arange(v0, v1)[:, None], y.shape)
    return ((y_cue - y + 570) % 1140 - 570)[ok], y[ok], rows[ok]


def test_the_row_fringes_have_the_stated_period(model_poses):
    """Decoding the row set (frames 06-11) warns that its cue and fine coordinates drift
    apart by +10..19 px, and suggests a fine period of 72.4-73.8 px where the README says
    71.25 (1140 / 16). The fine period is right; the drift is the cue's:
    (a) the projector fitted with f_x and f_y free (poses 1, 3-6) finds f_y / f_x = 0.9999
    (jackknife std 0.0012), where 72.4-73.8 px would make it 1.017-1.036; the DMD's pixels
    are square in 1824 x 1140 coordinates;
    (b) the near pose calseq1, whose board spans projector rows 113-995, shows no drift
    (slope +0.03 %), where a 73.4 px period would drift by 3 %;
    (c) in a far pose the drift is a step of ~20 px between camera rows 450 and 650, not
    a line, and the decoded fine y_p has no step there (0.02 px)."""
    import cv2

    five = [model_poses[k] for k in (0, 2, 3, 4, 5)]
    flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    matrix = cv2.calibrateCamera([BOARD.object_points] * 5,
                                 [p.projector_px.astype(np.float32) for p in five], PANEL,
                                 None, None, flags=flags)[1]
    assert abs(matrix[1, 1] / matrix[0, 0] - 1) < 0.005  # measured 0.9999
    drift, y, _ = _row_cue_drift(1, model_poses[0])
    assert np.ptp(y) > 800  # the near board spans most of the panel's rows
    assert abs(np.polyfit(y, drift, 1)[0]) < 0.005  # measured +0.03 %
    drift, _, rows = _row_cue_drift(5, model_poses[4])
    step = np.median(drift[rows > 650]) - np.median(drift[rows < 450])
    assert step > 10, step  # measured -3.6 / -1.1 px below, +14.7 / +18.6 px above
    pose = model_poses[4]  # the fine y_p, smooth across the same rows
    u0, v0, u1, v1 = pose.crop
    vv, uu = np.mgrid[v0:v1, u0:u1]
    ok = np.isfinite(pose.yp)
    u, v = (uu[ok] - 843.5) / 800, (vv[ok] - 675.5) / 800
    terms = np.column_stack([u ** i * v ** j for i in range(6) for j in range(6 - i)])
    resid = pose.yp[ok] - terms @ np.linalg.lstsq(terms, pose.yp[ok], rcond=None)[0]
    jump = np.median(resid[(vv[ok] > 650) & (vv[ok] < 750)]) - np.median(
        resid[(vv[ok] > 350) & (vv[ok] < 450)])
    assert abs(jump) < 0.1, jump  # a 1.2 px step would carry the cue's 18 px


def test_the_baseline_gap_is_in_the_correspondences(model_poses):
    """Where the 0.62 deg between our baseline direction and calibration.xml's comes from
    (docs/calibration.rst, *The baseline direction*). calibration.xml, given our camera
    corners, predicts our projector corners to 2.6-5.1 px where our calibration does to
    0.47-0.98 px (and to 0.50-1.15 px each pose held out): it is not consistent with the
    correspondences scanqa measures. With calibration.xml's own intrinsics held, the
    stereo fit on our corners still tilts the baseline across (along camera y) by 0.44 deg
    - the gap's stable part (0.39 deg; jackknife std 0.06 deg) is in the correspondences,
    not in our lens fit or the stereo step. Its other part, in the plane of the baseline
    and the camera's x axis (-0.48 deg), is not pinned by five poses (jackknife std 0.43
    deg, the fit's own noise 0.23 deg)."""
    import cv2

    from scanqa.calibration.board_fit import _points, predicted_projector_rms

    ref = read_opencv_calibration(CALIBRATION / "calibration.xml")
    # the analysis is of OpenCV's sequential fit (the joint fit of issue 42, the default
    # since, tilts across by 0.57 deg: model_calibration.data)
    ours = calibrate_board([model_poses[k] for k in (0, 2, 3, 4, 5)], BOARD, PANEL,
                           covariance=False).data
    for pose in model_poses:
        assert predicted_projector_rms(pose, BOARD, ref) > 2.0  # measured 2.6-5.1 px
        assert predicted_projector_rms(pose, BOARD, ours) < 1.2  # measured 0.47-0.98 px
    five = [model_poses[k] for k in (0, 2, 3, 4, 5)]
    obj, cam, proj = _points(five, BOARD)
    rot, trans = cv2.stereoCalibrate(obj, cam, proj, ref.Kc, ref.kc, ref.Kp, ref.kp,
                                     five[0].camera_size, flags=cv2.CALIB_FIX_INTRINSIC)[5:7]

    def across_deg(r, t):
        """The baseline's angle from calibration.xml's across the camera's x axis [deg]."""
        e = -ref.Rp.T @ np.ravel(ref.Tp)
        e /= np.linalg.norm(e)
        axis = np.cross(e, [1.0, 0.0, 0.0])
        c = -r.T @ np.ravel(t)
        return float(np.degrees(c @ (axis / np.linalg.norm(axis)) / np.linalg.norm(c)))

    assert 0.3 < across_deg(rot, trans) < 0.6  # measured 0.44 deg
    assert 0.3 < across_deg(ours.Rp, ours.Tp) < 0.5  # measured 0.39 deg
