"""The board calibration's covariance (scanqa.calibration.bundle) against simulated truth:
the calibration's own 3-D error at points over the volume, divided by its predicted
sigma (docs/studies/calibration_covariance.py runs the full study: held-out seeds
2000-2011, RMS(error / sigma) 1.06, 2-sigma coverage 0.967). Here four further seeds,
named before they were run; the truth is projected by OpenCV, not by the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.calibration.board_fit import calibrate_board
from scanqa.calibration.parametric import from_opencv
from scanqa.calibration.uncertainty import calibration_sigma_mm
from scanqa.errors import InputError
from scanqa.simulator.boardposes import BOARD, PANEL, simulate, volume_points

#: Named before they were run (the study's tuning seeds are 1000-1009, held out 2000-2011).
SEEDS = (3000, 3001, 3002, 3003)


@pytest.mark.slow
def test_the_predicted_calibration_sigma_covers_the_simulated_error():
    ratios = []
    for seed in SEEDS:
        sim = simulate(seed)
        result = calibrate_board(sim.poses, BOARD, PANEL, "k1")
        cal = from_opencv(result.data)
        u, v, xp, xyz = volume_points(sim.truth, sim.depth_mm)
        ray = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        err = np.sum((cal.apply(u, v, xp, extrapolate=True).xyz - xyz) * ray, axis=1)
        ratios.append(err / calibration_sigma_mm(cal, result.data.covariance, u, v, xp))
        # the joint fit measures each device's corner noise (Eq. 1) and the board's bow
        noise = result.bundle["noise_px"]
        assert abs(noise["camera"] / sim.noise_px[0] - 1) < 0.3, (noise, sim.noise_px)
        bow = [result.bundle["model_terms"][k]["estimate"] for k in ("bow_x", "bow_y")]
        assert np.allclose(np.abs(bow), np.abs(sim.bow[:2]), atol=0.03), (bow, sim.bow)
    z = np.concatenate(ratios)
    # four seeds: each shares one calibration error over its points, so each seed is
    # about one draw of error / sigma and the study's [0.75, 1.33] and [0.90, 0.99] need
    # >= 10 seeds. Here the RMS within wide bounds, and no seed's median |error| / sigma
    # beyond 3 (an honest sigma fails that with ~1 % chance over four seeds; a share
    # within 2 sigma >= 0.8 failed one in ~6: with the release of Eq. 6, seed 3002 sits
    # at 2.4 sigma and the share is 0.79)
    assert 0.5 < np.sqrt(np.mean(z**2)) < 2.0
    assert max(np.median(np.abs(r)) for r in ratios) < 3.0


def test_a_pose_given_twice_is_refused():
    sim = simulate(1000, n_poses=3)
    twice = [sim.poses[0], sim.poses[1], sim.poses[0]]
    with pytest.raises(InputError, match="show the board at the same place"):
        calibrate_board(twice, BOARD, PANEL, "k1")


def test_an_implausible_square_size_is_refused(tmp_path, capsys):
    from scanqa.calibration.board import Board
    from scanqa.cli import main

    with pytest.raises(InputError, match="no chessboard's square"):
        Board(8, 11, 1e9)
    code = main(["calibrate", "--square-mm", "1e9", "--patterns", "c.toml", "r.toml",
                 str(tmp_path), "--out", str(tmp_path / "cal.xml")])
    assert code == 2
    err = capsys.readouterr().err
    assert "no chessboard's square (0.2-500 mm)" in err and "Traceback" not in err


def test_a_baseline_far_from_the_configs_is_refused():
    """A wrong square size scales the calibration's baseline: 15 mm squares stated for
    the simulated 10 mm board put the projector ~50 % farther than the config says."""
    from dataclasses import replace

    from scanqa.calibration.board_fit import check_baseline

    sim = simulate(1000, n_poses=4)
    truth_centre = -sim.truth.Rp.T @ sim.truth.Tp
    result = calibrate_board(sim.poses, BOARD, PANEL, "k1", covariance=False)
    assert abs(check_baseline(result.data, truth_centre, 10.0)) < 0.05
    wrong = calibrate_board(sim.poses, replace(BOARD, square_mm=15.0), PANEL, "k1",
                            covariance=False)
    with pytest.raises(InputError, match=r"\+5\d % off the config.s projector position"):
        check_baseline(wrong.data, truth_centre, 15.0)


def test_the_full_lens_model_gives_a_covariance_too():
    """The "full" model leaves no lens term out (no nuisance of Eq. 3): its joint fit
    ended in a matmul ValueError (the nuisance slice [-0:] took every parameter)."""
    sim = simulate(1000, n_poses=4)
    result = calibrate_board(sim.poses, BOARD, PANEL, "full")
    cov = result.data.covariance
    assert cov.shape == (24, 24) and np.isfinite(cov).all()
    assert np.all(np.diag(cov)[[0, 5, 6, 7, 8]] > 0)  # f_x, k2, p1, p2, k3 of the camera
    assert set(result.bundle["model_terms"]) == {"bow_x", "bow_y", "bow_xy"}


def test_released_lens_terms_remove_the_bias_the_data_show():
    """Corner noise of 0.02 px (what rendered Gray-code poses give) against a camera
    principal point pixels off the image centre: the "k1" fit states that bias as a
    variance (Eq. 3), so the error is about one sigma at every point. With ``release``
    (Eqs. 4-5) the terms the data show are fitted: the principal point lands within
    3 std of the truth and the error at the volume points drops several-fold (seed 5005,
    a tuning seed of docs/studies/calibration_covariance.py sim --noise-px 0.02,0.02)."""
    from scanqa.calibration.board_fit import joint_fit

    sim = simulate(5005, n_poses=5, noise_px=(0.02, 0.02))
    start = calibrate_board(sim.poses, BOARD, PANEL, "k1", covariance=False).data
    u, v, xp, xyz = volume_points(sim.truth, sim.depth_mm)
    ray = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    errors = {}
    for release in (False, True):
        fit = joint_fit(sim.poses, BOARD, start, "k1", release)
        cal = from_opencv(fit.data)
        errors[release] = np.sum((cal.apply(u, v, xp, extrapolate=True).xyz - xyz) * ray, 1)
    terms = fit.model_terms
    assert terms["camera_cx"].get("released") and terms["camera_cy"].get("released")
    for k, name in ((0, "camera_cx"), (1, "camera_cy")):
        assert abs(fit.data.Kc[k, 2] - sim.truth.Kc[k, 2]) < 3 * terms[name]["std"]
    # the corner noise measured after the nuisances is the simulated one
    assert abs(fit.noise_px["camera"] / 0.02 - 1) < 0.15
    assert np.median(np.abs(errors[True])) < np.median(np.abs(errors[False])) / 5


def test_a_term_the_poses_do_not_pin_is_not_released():
    """Eq. 6 of scanqa.calibration.bundle on leave-one-pose-out estimates measured in the
    study: the camera's c_y on SLStudio's real poses (1, 3-6; 17.2 px off at 1.25 px std,
    the five fits scatter by 4.8 px) is refused, on rendered seed 4250 (6.6 px off at
    0.39 px std, scatter 0.09 px) released. The limit, chi-square's 99.9 % point for 4
    degrees of freedom (18.47) over 4, taken from tables, not from scipy."""
    from scanqa.calibration.bundle import identified

    real = [-20.7691, -16.1181, -20.2015, -14.4555, -17.6497]
    rendered = [6.6562, 6.5582, 6.5601, 6.6569, 6.61]
    ok = identified(np.column_stack([real, rendered]), [1.2529, 0.392])
    assert ok.tolist() == [False, True]
    # about the limit (2.1487): a jackknife spread of 2.145 std passes, 2.152 does not
    spread = np.array([-1.0, 1.0, 0.0, 0.0, 0.0])  # jackknife std sqrt(4 / 5 * 2)
    for factor, expected in ((2.145, True), (2.152, False)):
        assert identified(spread[:, None], [np.sqrt(1.6) / factor]).tolist() == [expected]


@pytest.mark.parametrize("model", ["k1", "k1k2", "full"])
def test_the_joint_fits_jacobian_is_the_residuals_derivative(model):
    """The joint fit's analytic Jacobian (OpenCV's projection derivatives chained through
    the projector's pose and the board's bow), against central differences of its
    residuals taken here, by each parameter and each left-out lens term."""
    import cv2

    from scanqa.calibration import bundle
    from scanqa.calibration.board_fit import _fit, _points

    sim = simulate(1000, n_poses=3)
    data = _fit(sim.poses, BOARD, PANEL, model)[0]
    obj, cam, proj = (list(map(np.asarray, a)) for a in _points(sim.poses, BOARD))
    obj = [o.astype(float) for o in obj]
    poses = [cv2.solvePnP(o, c, data.Kc, data.kc)[1:] for o, c in zip(obj, cam, strict=True)]
    problem = bundle._Problem(data, obj, [c.astype(float) for c in cam],
                              [p.astype(float) for p in proj],
                              (bundle.FREE[model], bundle.LEFT_OUT[model]),
                              [r.ravel() for r, _ in poses], [t.ravel() for _, t in poses],
                              BOARD.object_points)
    problem.scale = np.array([0.3, 0.5])
    x = problem.x0.copy()
    x[sum(problem.sizes[:3]):][:3] = (0.05, -0.03, 0.02)  # a bowed board
    eta = np.full(problem.n_nuis, 1e-3)
    res, jac, jn = problem.with_jacobian(x, eta)
    np.testing.assert_array_equal(res, problem.residuals(x, eta))
    for base, analytic, f in ((x, jac, lambda y: problem.residuals(y, eta)),
                              (eta, jn, lambda e: problem.residuals(x, e))):
        # steps: 1e-4 for the large parameters (translations [mm]), else 1e-6
        steps = np.where(np.abs(base) > 10, 1e-4, 1e-6)
        for j, h in enumerate(steps):
            up, down = base.copy(), base.copy()
            up[j] += h
            down[j] -= h
            numeric = (f(up) - f(down)) / (2 * h)
            np.testing.assert_allclose(analytic[:, j], numeric, rtol=0,
                                       atol=1e-5 * np.abs(numeric).max() + 1e-9)
