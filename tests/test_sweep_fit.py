"""The sweep geometry fit beyond the plain least squares (issue 15): a decentred principal
point found (or held, when the data cannot pin it) and the pixel-locking correction.

Truth comes from the simulator's ray geometry (``tests/test_target.py``'s corner truth and
:func:`scanqa.simulator.devices.camera_principal_point`), never from the fit.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.calibration.sweep_fit import fit_sweep_geometry, pixel_locking
from scanqa.calibration.target import Detection
from scanqa.model.config import load_config
from scanqa.simulator import devices

from .test_target import REALISM as BASE
from .test_target import SAMPLE, _corner_truth

REALISM = {**BASE, "target_square_mm": 2.0, "camera_cx_offset_px": 5.0,
           "camera_cy_offset_px": -3.0}
GRID = np.array([[i, j] for i in range(-24, 25) for j in range(-20, 21)], float) * 2.0


@pytest.fixture(scope="module")
def cfg():
    return load_config(SAMPLE, profile="sample").replace_simulator(**REALISM)


def _sweep(cfg, noise_px: float, zs) -> list[Detection]:
    """Exact corners of the printed target inside the sensor at each reading, plus white
    noise [px]."""
    rng = np.random.default_rng(5)
    out = []
    for z in zs:
        uv = _corner_truth(cfg, z, GRID)
        inside = (uv[:, 0] > 2) & (uv[:, 0] < 303) & (uv[:, 1] > 2) & (uv[:, 1] < 253)
        out.append(Detection(uv[inside] + rng.normal(0, noise_px, uv[inside].shape),
                             GRID[inside]))
    return out


def test_decentred_principal_point_found(cfg):
    """A sweep of 14 planes with 2 mm squares and 0.02 px corner noise: the fit finds the
    simulator's principal point, 5 px right of and 3 px above the sensor centre, within
    three of its standard deviations, and calls it fitted; the stage and target tilts
    come out as simulated. (Held at the centre, the fit would be 5.8 px off.)"""
    zs = [float(z) for z in np.arange(424.0, 477.0, 4.0)]
    geo = fit_sweep_geometry(_sweep(cfg, 0.02, zs), zs, cfg, 306, 256)
    truth = devices.camera_principal_point(cfg)
    assert truth == (157.5, 124.5)  # the sensor centre (152.5, 127.5) + (5, -3)
    found, std = geo.camera.matrix[:2, 2], np.array([geo.std["cx_px"], geo.std["cy_px"]])
    print(f"\n[sweep_fit] principal point {found} (true {truth}), std {std} px")
    assert geo.principal_point_fitted
    assert np.all(np.abs(found - truth) < 3 * std) and np.all(std < 0.5)
    # the stage axis trades with the principal point (0.45 px here moves it 0.016 deg)
    assert geo.stage_tilt_deg == pytest.approx(1.0, abs=0.03)
    assert geo.target_tilt_deg == pytest.approx(2.0, abs=0.02)


def test_principal_point_held_when_the_data_cannot_pin_it(cfg):
    """Three planes and coarse corner noise (0.3 px) do not pin the principal point: it
    is held at the sensor centre and reported as not fitted."""
    zs = [426.0, 450.0, 474.0]
    geo = fit_sweep_geometry(_sweep(cfg, 0.3, zs), zs, cfg, 306, 256)
    assert not geo.principal_point_fitted
    assert tuple(geo.camera.matrix[:2, 2]) == (152.5, 127.5)
    assert geo.std["cx_px"] == 0.0


@pytest.mark.parametrize("p1", [0.0, 3e-3])
def test_decentring_kept_only_when_the_corners_need_it(cfg, p1):
    """Without tangential distortion in the simulated lens the likelihood-ratio test
    drops p1, p2 (they would trade against the principal point); with p1 = 3e-3 (10
    times what the sweep resolves) it keeps them and the corners fit to their noise.
    The split between decentring, principal point and stage axis is then not pinned
    (docs/calibration.rst): the point is reported as not fitted."""
    lens = cfg.replace_simulator(camera_p1=p1)
    zs = [float(z) for z in np.arange(424.0, 477.0, 4.0)]
    geo = fit_sweep_geometry(_sweep(lens, 0.02, zs), zs, lens, 306, 256)
    assert geo.decentring_fitted == (p1 > 0)
    assert geo.rms_px == pytest.approx(0.02 * np.sqrt(2), rel=0.1)
    if p1 > 0:
        assert not geo.principal_point_fitted
    else:
        assert geo.camera.distortion[2] == 0.0 and geo.std["p1"] == 0.0


def test_pixel_locking_recovers_a_grid_periodic_error():
    """Misfit = a locking term periodic in the pixel grid + a smooth trend + noise: the
    estimate returns the periodic part (to 0.002 px RMS) and leaves the trend alone."""
    rng = np.random.default_rng(2)
    uv = rng.uniform(0, 300, (3000, 2))
    frac = uv - np.round(uv)
    lock = np.column_stack([0.013 * np.sin(2 * np.pi * frac[:, 0]),
                            0.011 * np.sin(2 * np.pi * frac[:, 1]) + 0.004 * np.cos(
                                4 * np.pi * frac[:, 1])])
    trend = 1e-4 * (uv - 150.0)
    misfit = lock + trend + rng.normal(0, 0.01, uv.shape)
    groups = np.repeat([0, 1, 2], 1000)
    est = pixel_locking(misfit, uv, groups)
    assert np.sqrt(np.mean((est - lock) ** 2)) < 0.002
    assert abs(np.corrcoef(est[:, 0] - lock[:, 0], trend[:, 0])[0, 1]) < 0.1
    few = pixel_locking(misfit[:10], uv[:10], np.zeros(10, int))
    assert not few.any()  # 10 corners cannot tell locking from noise: no correction


@pytest.mark.slow  # ~29 s of CPU (measured 2026-11-27)
def test_calibration_report_shows_the_marker_geometry(cfg, tmp_path, capsys):
    """scanqa calibrate on a simulated marked sweep: the report (JSON and HTML) carries
    the fitted camera and stage and says what the sweep could not pin."""
    import json

    from scanqa.cli import main
    from scanqa.simulator.experiments import run_experiment

    small = cfg.replace_simulator(target_square_mm=4.0)
    out = run_experiment("calibration-sweep", small, tmp_path / "s",
                         positions=[430.0, 440.0, 450.0, 460.0, 470.0], repeats=1,
                         marker_frames=2)
    # two marker frames per position, each its own noise, both listed in the manifest
    from scanqa.io.sweep import load_sweep

    frames = load_sweep(out.parent).positions[0].marker_frames
    assert len(frames) == 2
    from scanqa.io.images import read_image

    assert (read_image(frames[0]) != read_image(frames[1])).any()
    assert main(["calibrate", str(out.parent), "--config", f"{SAMPLE}#sample", "--out",
                 str(tmp_path / "t.npz")]) == 0
    info = json.loads((tmp_path / "t_report.json").read_text())
    geo = info["target_geometry"]
    # simulated truth 1 deg. Five positions: one noise draw can move it. Measured over the
    # simulator's seeds 0, 1, 2: 0.996, 0.996, 1.001 with the previous renderer, 1.091,
    # 0.996, 1.000 with the float32 frequency-domain one (same light to 3e-6; only the
    # sensor's random stream differs) - seed 0 is an outlier draw, not a bias
    assert geo["stage_tilt_deg"] == pytest.approx(1.0, abs=0.1)
    assert isinstance(geo["principal_point_fitted"], bool)
    assert isinstance(geo["decentring_fitted"], bool)
    html = (tmp_path / "t_report.html").read_text()
    assert "Camera and stage from the marked target" in html
    assert f"stage tilt {geo['stage_tilt_deg']:.4f} deg" in html
    # both of the target normal's directions, each with its std (the tilt alone is blind
    # to a turn about the other axis)
    assert f"toward azimuth {geo['target_tilt_azimuth_deg']:.2f} deg" in html
    assert f"{geo['std']['target_normal_y_deg']:.4f} deg toward x / y" in html
    # the error the marker fit implies, against the model's bound: stated, with the
    # frames it would take (a 4 mm board at 5 positions is far from the bound)
    err = geo["marker_error"]
    assert err["marker_frames"] == 2
    assert err["rotation_std_deg"] == [geo["std"]["target_normal_x_deg"],
                                       geo["std"]["target_normal_y_deg"]]
    assert f"{err['fit_error_quantile_um']:.2f} um in 95 % of sweeps" in html
    assert err["exceeds_bound"] == ("Warning: the marker fit" in html)
    assert err["exceeds_bound"] == (err["frames_needed"] is None or err["frames_needed"] > 2)


def test_target_normal_in_both_directions_with_its_std(cfg):
    """The simulator turns the flat 2 deg about the camera's X axis, so its normal leans
    toward +-y (azimuth +-90 deg) and not toward x; the fit finds both directions within
    three of the standard deviations it reports for them, and those stds are the ones
    of the rotation vector's covariance (at a 2 deg tilt the normal turns toward x with
    the rotation about y and toward y with the rotation about x, to within a few %)."""
    zs = [float(z) for z in np.arange(424.0, 477.0, 4.0)]
    geo = fit_sweep_geometry(_sweep(cfg, 0.02, zs), zs, cfg, 306, 256)
    sx, sy = geo.std["target_normal_x_deg"], geo.std["target_normal_y_deg"]
    cov = geo.covariance
    print(f"\n[sweep_fit] tilt {geo.target_tilt_deg:.5f} deg toward "
          f"{geo.target_tilt_azimuth_deg:.3f} deg; normal std x / y {sx:.5f} / {sy:.5f} deg; "
          f"rotation-vector std {np.degrees(np.sqrt(np.diag(cov)[7:10]))} deg")
    assert 0 < sx < 0.05 and 0 < sy < 0.05
    lean_x = geo.target_tilt_deg * np.cos(np.radians(geo.target_tilt_azimuth_deg))
    lean_y = geo.target_tilt_deg * abs(np.sin(np.radians(geo.target_tilt_azimuth_deg)))
    assert abs(lean_x) < 3 * sx
    assert abs(lean_y - 2.0) < 3 * sy
    rot_std = np.degrees(np.sqrt(np.diag(cov)[7:10]))
    assert sx == pytest.approx(rot_std[1], rel=0.05)
    assert sy == pytest.approx(rot_std[0], rel=0.05)
