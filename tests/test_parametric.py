"""Parametric calibration (scanqa.calibration.parametric): closed loops through OpenCV's
projection (an independent implementation of the same camera model), the slope against
finite differences, the in-volume rules, the common Calibration interface, every size
and pose mismatch, and annotation + gauge QA of a synthetic scene through it."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from scanqa.annotation.points import annotate
from scanqa.calibration.base import Calibration, load_calibration
from scanqa.calibration.build import build_table
from scanqa.calibration.parametric import (
    Lens,
    ParametricCalibration,
    from_opencv,
    load_opencv_calibration,
)
from scanqa.errors import InputError
from scanqa.io.opencv import OpenCVCalibration
from scanqa.model import optics
from scanqa.qa.blocks import run_qa
from scanqa.qa.layout import load_layout
from tests.conftest import ROOT
from tests.realdata import SLSTUDIO, needs_slstudio
from tests.synth_parametric import (
    camera_pixels,
    camera_rays,
    layout_scene,
    phase_map,
    projector_pixels,
    small_scanner,
)
from tests.synth_sweep import sweep

REAL = SLSTUDIO / "calibration" / "calibration.xml"


@pytest.fixture(scope="module")
def scanner(paper_config):
    """(calibration, config): projector to the right, vertical fringes."""
    return small_scanner(paper_config)


@pytest.fixture(scope="module")
def scanner_below(paper_config):
    """Projector below the camera, horizontal fringes (y_p)."""
    proj = replace(paper_config.projector, position_mm=(0.0, 140.0, 0.0))
    return small_scanner(replace(paper_config, projector=proj), orientation="horizontal")


def surface_points(n: int, seed: int = 0) -> np.ndarray:
    """Points on three known surfaces: a tilted plane, a sphere cap and a random volume."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-60, 60, n), rng.uniform(-45, 45, n)
    plane = np.column_stack([x, y, 450.0 + 0.2 * x - 0.1 * y])
    r = 80.0  # sphere of radius 80 mm centred at Z = 520: its near cap
    sphere = np.column_stack([x / 2, y / 2, 520.0 - np.sqrt(r**2 - (x / 2) ** 2 - (y / 2) ** 2)])
    cloud = np.column_stack([x, y, rng.uniform(400, 500, n)])
    return np.concatenate([plane, sphere, cloud])


def coded(cal: ParametricCalibration, points: np.ndarray) -> np.ndarray:
    """The decoded coordinate of points (x_p or y_p), by OpenCV."""
    return projector_pixels(cal, points)[..., 0 if cal.orientation == "vertical" else 1]


@pytest.mark.parametrize("which", ["scanner", "scanner_below"])
def test_closed_loop_through_opencv_projection(which, request):
    """Points projected by OpenCV into camera and projector come back to < 1e-6 mm."""
    cal, _ = request.getfixturevalue(which)
    q = surface_points(3000)
    uv = camera_pixels(cal, q)
    look = cal.apply(uv[:, 0], uv[:, 1], coded(cal, q))
    seen = ((uv[:, 0] > 0) & (uv[:, 0] < cal.width_px - 1) & (uv[:, 1] > 0)
            & (uv[:, 1] < cal.height_px - 1))
    assert seen.sum() > 3000 and look.in_volume[seen].mean() > 0.95
    err = np.linalg.norm(look.xyz - q, axis=1)[look.in_volume]
    assert err.max() < 1e-6  # [mm]; float64 rounding, the Newton tolerance is 1e-9 px
    assert np.all(look.sigma_table[look.in_volume] == 0)


@needs_slstudio
def test_closed_loop_through_the_real_slstudio_calibration():
    """Known surfaces through the real calibration.xml's models (k1 of both lenses)."""
    cal = load_opencv_calibration(REAL)
    q = surface_points(5000, seed=1) * [1.0, 1.0, 0.9]  # the skull is at ~400 mm
    uv = camera_pixels(cal, q)
    look = cal.apply(uv[:, 0], uv[:, 1], coded(cal, q))
    assert look.in_volume.mean() > 0.8
    err = np.linalg.norm(look.xyz - q, axis=1)[look.in_volume]
    assert err.max() < 1e-6  # [mm]


def test_skewed_projector_matrix(scanner):
    """A projector matrix with skew takes the general branch; the reference is the
    projection written out here (cv2.projectPoints ignores skew)."""
    cal, _ = scanner
    kp = cal.projector.matrix.copy()
    kp[0, 1] = 15.0
    skewed = replace(cal, projector=replace(cal.projector, matrix=kp))
    q = surface_points(500)
    qp = q @ cal.rotation.T + cal.translation
    a, b = qp[:, 0] / qp[:, 2], qp[:, 1] / qp[:, 2]
    k1, k2, p1, p2, k3 = cal.projector.distortion
    r2 = a * a + b * b
    rad = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    ad = a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    bd = b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    xp = kp[0, 0] * ad + kp[0, 1] * bd + kp[0, 2]
    uv = camera_pixels(cal, q)
    look = skewed.apply(uv[:, 0], uv[:, 1], xp)
    assert look.in_volume.mean() > 0.9
    assert np.linalg.norm(look.xyz - q, axis=1)[look.in_volume].max() < 1e-6


def test_rays_match_opencv_undistortion(scanner):
    cal, _ = scanner
    x, y = camera_rays(cal)
    grid = cal.image_grid
    assert grid.valid.all()
    assert_allclose(grid.x, x, atol=1e-12)  # normalised [-]: ~1e-9 px
    assert_allclose(grid.y, y, atol=1e-12)


@pytest.mark.parametrize("which", ["scanner", "scanner_below"])
def test_slope_matches_finite_differences(which, request):
    """dQ/dx_p by implicit differentiation against central differences (h = 1e-3 px:
    truncation ~h^2 |Q'''| and rounding ~1e-13 mm / h, both < 1e-8 of the slope)."""
    cal, _ = request.getfixturevalue(which)
    q = surface_points(400)
    uv = camera_pixels(cal, q)
    xp = coded(cal, q)
    h = 1e-3
    look = cal.apply(uv[:, 0], uv[:, 1], xp)
    plus = cal.apply(uv[:, 0], uv[:, 1], xp + h, extrapolate=True)
    minus = cal.apply(uv[:, 0], uv[:, 1], xp - h, extrapolate=True)
    fd = (plus.xyz - minus.xyz) / (2 * h)
    ok = look.in_volume
    rel = np.linalg.norm(fd - look.slope, axis=1)[ok] / look.s_t[ok]
    assert ok.sum() > 1000 and rel.max() < 1e-6
    # the slope is along the camera ray, and of the size the pinhole geometry predicts
    ray = look.xyz / np.linalg.norm(look.xyz, axis=-1, keepdims=True)
    assert_allclose(np.abs(np.sum(ray * look.slope, axis=-1))[ok], look.s_t[ok], rtol=1e-9)


def test_rows_and_images_agree_with_points(scanner):
    cal, _ = scanner
    rng = np.random.default_rng(3)
    xp = rng.uniform(200, 1100, (cal.height_px, cal.width_px))
    xp[5, 7] = np.nan
    image = cal.apply_image(xp)
    v, u = np.indices(xp.shape, dtype=float)
    points = cal.apply(u, v, xp)
    assert_allclose(image.xyz, points.xyz, rtol=0, atol=1e-9, equal_nan=True)
    assert_array_equal(image.in_volume, points.in_volume)
    rows = cal.apply_rows(xp[40:47], 40)
    assert_allclose(rows.xyz, image.xyz[40:47], rtol=0, atol=0, equal_nan=True)
    select = np.array([3, 500, 1201])
    picked = cal.apply_rows(xp[40:47], 40, select)
    assert_allclose(picked.slope, image.slope[40:47].reshape(-1, 3)[select], atol=0)
    assert_array_equal(cal.in_volume_rows(xp[40:47], 40), image.in_volume[40:47])
    assert not image.in_volume[5, 7] and np.isnan(image.xyz[5, 7]).all()


def test_in_volume_rules(scanner):
    """Out of volume: outside the panel (coded or other coordinate), outside the depth
    range, behind the camera; NaN unless extrapolated."""
    cal, _ = scanner
    q = np.array([[0.0, 0.0, 450.0], [0.0, 0.0, 450.0], [10.0, 5.0, 300.0],
                  [-20.0, 25.0, 600.0]])
    uv = camera_pixels(cal, q)
    xp = coded(cal, q)
    xp[1] = cal.projector.width_px + 3.0  # past the panel's last column
    look = cal.apply(uv[:, 0], uv[:, 1], xp)
    assert_array_equal(look.in_volume, [True, False, True, True])
    assert np.isnan(look.xyz[1]).all() and np.isnan(look.slope[1]).all()
    near = replace(cal, depth_range_mm=(350.0, 500.0))
    look = near.apply(uv[:, 0], uv[:, 1], xp, extrapolate=True)
    assert_array_equal(look.in_volume, [True, False, False, False])
    assert_allclose(look.xyz[[2, 3]], q[[2, 3]], atol=1e-6)  # extrapolated, flagged
    # the other projector coordinate past the panel: a point far above the panel's top
    high = np.array([[0.0, -400.0, 450.0]])
    uv = camera_pixels(cal, high)
    assert projector_pixels(cal, high)[0, 1] < -0.5
    assert not cal.apply(uv[:, 0], uv[:, 1], coded(cal, high)).in_volume[0]


def test_a_solution_behind_the_camera_is_out_of_volume(scanner):
    """A projector 300 mm behind the camera (parallel axes) sees points behind the camera:
    Q = (-10, 0, -100) lies on the camera ray of the pixel it maps to (x/z = 0.1) and
    projects to x_p = 1000 (-110 / 200) + 640 = 90 inside the panel."""
    cal, _ = scanner
    k = np.array([[1000.0, 0, 640], [0, 1000.0, 400], [0, 0, 1]])
    rig = replace(cal, projector=Lens(k, np.zeros(5), 1280, 800), rotation=np.eye(3),
                  translation=np.array([-100.0, 0.0, 300.0]))
    u, v = rig.camera.project(np.array([-10.0, 0.0, -100.0]))
    look = rig.apply(u, v, 90.0, extrapolate=True)
    assert not look.in_volume
    assert_allclose(look.xyz, [-10.0, 0.0, -100.0], atol=1e-9)
    assert np.isnan(rig.apply(u, v, 90.0).xyz).all()


def test_both_calibrations_satisfy_the_interface(scanner, paper_config):
    cal, _ = scanner
    table, _ = build_table(sweep(_tiny(paper_config), np.linspace(430.0, 470.0, 6)),
                           _tiny(paper_config))
    for c in (cal, table):
        assert isinstance(c, Calibration)
        for name in ("width_px", "height_px", "weights", "cell_px", "z_range_mm",
                     "provenance", "image_grid"):
            getattr(c, name)

    class NoCheck:
        width_px = height_px = 1
        weights, cell_px, z_range_mm, provenance, image_grid = "", 1.0, (0, 1), {}, None

        def apply_rows(self, xp_rows, row0=0, select=None, extrapolate=False): ...

        def in_volume_rows(self, xp_rows, row0=0): ...

    assert not isinstance(NoCheck(), Calibration)  # check_scan is part of the interface


def _tiny(config):
    from tests.synth_sweep import small_camera

    return small_camera(config, 48, 32)


# ------------------------------------------------------------------ mismatches and checks


def _scan(cal, shape=None, **changes):
    shape = shape or (cal.height_px, cal.width_px)
    pm = phase_map(np.full(shape, 600.0), np.full(shape, 0.02), 5.0,
                   cal.projector.width_px)
    return replace(pm, **changes) if changes else pm


def test_compatible_scan_and_config_pass(scanner):
    cal, cfg = scanner
    cal.check_scan(cfg, _scan(cal))


MISMATCHES = {
    "image size": (lambda cal, cfg: (cfg, _scan(cal, (10, 12)))),
    "orientation": (lambda cal, cfg: (cfg, _scan(cal, orientation="horizontal"))),
    "coded range": (lambda cal, cfg: (cfg, _scan(cal, projector_width_px=1024))),
    "config camera": (lambda cal, cfg: (replace(cfg, camera=replace(cfg.camera, width_px=64)),
                                        _scan(cal))),
    "config projector": (lambda cal, cfg: (
        replace(cfg, projector=replace(cfg.projector, height_px=768)), _scan(cal))),
}
# a projector pose that differs from the calibration's is not an error: the calibration
# supplies the geometry (tests/test_geometry_source.py)
MESSAGES = {
    "image size": r"scan is 12 x 10 px but the calibration synthetic.xml is for a 400 x 300",
    "orientation": r"horizontal fringes but .* loaded for vertical",
    "coded range": r"codes x_p over 1024 projector px .* panel of 1280 px \(screenResX\)",
    "config camera": r"camera.width_px x height_px is 64 x 300 but .* has 400 x 300 "
                     r"\(frameWidth x frameHeight\)",
    "config projector": r"projector.width_px x height_px is 1280 x 768 .* 1280 x 800 "
                        r"\(screenResX x screenResY\)",
}


@pytest.mark.parametrize("case", sorted(MISMATCHES))
def test_every_mismatch_is_one_clear_error(scanner, case):
    cal, cfg = scanner
    config, scan = MISMATCHES[case](cal, cfg)
    with pytest.raises(InputError, match=MESSAGES[case]):
        annotate(scan, cal, config)


def _contents(**sizes) -> OpenCVCalibration:
    k = np.array([[1000.0, 0, 200], [0, 1000.0, 150], [0, 0, 1]])
    return OpenCVCalibration(k, np.zeros(5), k, np.zeros(5), np.eye(3),
                             np.array([-100.0, 0, 0]), sizes, {}, "cal.xml")


def test_sizes_from_file_or_caller():
    full = {"frameWidth": 400, "frameHeight": 300, "screenResX": 800, "screenResY": 600}
    cal = from_opencv(_contents(**full), camera_size=(400, 300), projector_size=(800, 600))
    assert (cal.width_px, cal.projector.height_px) == (400, 600)
    cal = from_opencv(_contents(), camera_size=(40, 30), projector_size=(80, 60))
    assert (cal.width_px, cal.projector.height_px) == (40, 60)
    with pytest.raises(InputError, match=r"frameWidth x frameHeight is 400 x 300 but the camera "
                                         r"is 640 x 480 px in the scanner config"):
        from_opencv(_contents(**full), camera_size=(640, 480))
    with pytest.raises(InputError, match=r"screenResX x screenResY is 800 x 600 but the "
                                         r"projector is 1280 x 800"):
        from_opencv(_contents(**full), projector_size=(1280, 800))
    with pytest.raises(InputError, match=r"has no screenResX/screenResY: give the projector"):
        from_opencv(_contents(frameWidth=400, frameHeight=300))


@pytest.mark.parametrize(("change", "message"), [
    ({"rotation": np.diag([1.0, 1.0, 2.0])}, r"Rp is not a rotation"),
    ({"rotation": np.diag([1.0, 1.0, -1.0])}, r"Rp is not a rotation .* det = -1"),
    ({"translation": np.zeros(3)}, r"Tp must be a non-zero translation"),
    ({"orientation": "diagonal"}, r"orientation must be one of"),
    ({"depth_range_mm": (500.0, 400.0)}, r"0 <= near < far"),
    ({"depth_range_mm": (500.0,)}, r"0 <= near < far"),
    ({"camera": Lens(np.eye(3) * -1, np.zeros(5), 4, 3)}, r"Kc must be a camera matrix"),
    ({"projector": Lens(np.eye(3), np.zeros(4), 4, 3)}, r"kp must be 5 finite numbers"),
])
def test_implausible_models_are_refused(scanner, change, message):
    cal, _ = scanner
    with pytest.raises(InputError, match=message):
        replace(cal, **change)


def test_load_calibration_dispatches_by_suffix(tmp_path, scanner):
    cal, cfg = scanner
    fs = cv2.FileStorage(str(tmp_path / "c.yaml"), cv2.FILE_STORAGE_WRITE)
    for key, value in {"Kc": cal.camera.matrix, "kc": cal.camera.distortion,
                       "Kp": cal.projector.matrix, "kp": cal.projector.distortion,
                       "Rp": cal.rotation, "Tp": cal.translation}.items():
        fs.write(key, value)
    fs.release()
    loaded = load_calibration(tmp_path / "c.yaml", cfg, "vertical", (400.0, 500.0))
    assert isinstance(loaded, ParametricCalibration) and loaded.z_range_mm == (400.0, 500.0)
    assert (loaded.width_px, loaded.projector.width_px) == (400, 1280)  # sizes from cfg
    q = surface_points(50)
    uv = camera_pixels(cal, q)
    assert_allclose(loaded.apply(uv[:, 0], uv[:, 1], coded(cal, q)).xyz,
                    cal.apply(uv[:, 0], uv[:, 1], coded(cal, q)).xyz, equal_nan=True)


# ------------------------------------------------------------------ annotate and QA


@pytest.fixture(scope="module")
def gauge_scanner(scanner):
    """The synthetic scanner with a 20 px working period, so that the model is valid on
    every block of the paper's artefact (at 5 px the 50.8 mm block is past its limit)."""
    cal, cfg = scanner
    return cal, replace(cfg, fringes=replace(cfg.fringes, periods_px=(20.0, 80.0)))


@pytest.fixture(scope="module")
def gauge_scan(gauge_scanner):
    """The paper's gauge artefact seen through the synthetic scanner, with phase noise of
    std s_O sigma_p drawn here (the model's own phase noise, so that a correct s_T and
    normal projection give measured / predicted ~ 1)."""
    cal, cfg = gauge_scanner
    layout = load_layout(ROOT / "calib" / "gauge_blocks_paper.toml")
    q = layout_scene(camera_rays(cal), 469.05, layout.blocks)
    xp = coded(cal, q)
    s_o = optics.predict(q, cfg, s_t=1.0).s_o
    noise = s_o * cfg.model.sigma_p_px
    rng = np.random.default_rng(7)
    xp_noisy = xp + rng.normal(0.0, 1.0, xp.shape) * noise
    assert np.isfinite(xp_noisy).all()
    return phase_map(xp_noisy, noise, cfg.fringes.working_period_px, 1280), layout, q


def test_annotate_and_qa_through_a_parametric_calibration(gauge_scanner, gauge_scan):
    cal, cfg = gauge_scanner
    scan, layout, _ = gauge_scan
    cloud = annotate(scan, cal, cfg)
    assert cloud.counts["written"] == scan.xp.size  # the whole artefact is in volume
    attrs = cloud.attributes
    assert np.isfinite(attrs["sigma_model_um"]).all()
    assert np.all(attrs["sigma_calibration_um"] == 0) and np.isnan(attrs["table_corr_mm"]).all()
    assert cloud.metadata["table"]["kind"] == "parametric"
    assert cloud.metadata["table"]["z_range_mm"] == [0.0, None]
    qa = run_qa(cloud, layout, config=cfg)
    ratios = [b.measured_std_um / b.predicted_std_um for b in qa.blocks]
    assert all(b.status == "ok" and b.n_points > 500 for b in qa.blocks)
    # 1 within sampling error (~700-1500 points per block: +-8 % at 3 sigma)
    assert_allclose(ratios, 1.0, atol=0.1)
    for step in qa.steps:
        assert abs(step.error_um) < 3 * step.u_um + 0.5, step  # exact geometry: noise only
        assert step.decision == "pass"


def test_points_of_the_scan_are_the_scene(gauge_scanner, gauge_scan):
    """Without noise, annotate returns the scene's points (closed loop through annotate)."""
    cal, cfg = gauge_scanner
    scan, _, q = gauge_scan
    clean = phase_map(coded(cal, q), scan.sigma_xp, scan.period_px, 1280)
    cloud = annotate(clean, cal, cfg)
    assert np.abs(cloud.xyz - q.reshape(-1, 3).astype(np.float32)).max() < 1e-4  # float32


def test_sigma_scales_with_the_triangulation_scale(scanner):
    """s_T from the calibration's geometry: a point twice as far has ~4x the s_T."""
    cal, _ = scanner
    q = np.array([[0.0, 0.0, 300.0], [0.0, 0.0, 600.0]])
    uv = camera_pixels(cal, q)
    s_t = cal.apply(uv[:, 0], uv[:, 1], coded(cal, q)).s_t
    # pinhole: s_T ~ Z^2 / (f_p b cos) grows ~ Z^2 (within 20 % for the angled projector)
    assert 3.2 < s_t[1] / s_t[0] < 4.8
    assert math.isfinite(s_t[0]) and s_t[0] > 0
