"""The defocus model, Eqs. 1-19 of Drouin et al. 2017, function by function."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import j1

from scanqa.design import tools
from scanqa.model import geometry, optics

from .model_reference import reference_point

FINITE = st.floats(min_value=0.0, max_value=1.2, allow_nan=False)


def test_attenuation_at_zero_is_one():
    np.testing.assert_allclose(optics.attenuation(0.0), 1.0, rtol=0, atol=0)
    np.testing.assert_allclose(optics.attenuation(1e-12), 1.0, rtol=1e-15)


def test_attenuation_first_zero():
    # first zero of J1 is 3.831705970 (Abramowitz & Stegun 9.5): r = 1.21967
    np.testing.assert_allclose(optics.FIRST_ZERO_RATIO, 1.2196698912665, rtol=1e-12)
    assert optics.attenuation(optics.FIRST_ZERO_RATIO) < 1e-28
    assert optics.attenuation(optics.FIRST_ZERO_RATIO - 0.05) > 1e-3


def test_attenuation_hand_value():
    # Eq. 12 evaluated by hand at r = 0.5: (2 J1(pi/2) / (pi/2))^2
    x = np.pi / 2
    np.testing.assert_allclose(optics.attenuation(0.5), (2 * j1(x) / x) ** 2, rtol=1e-14)
    # series 1 - x^2/8 + x^4/192 - x^6/9216 + x^8/737280 at x = pi/2, squared
    np.testing.assert_allclose(optics.attenuation(0.5), 0.520855, atol=2e-6)


def test_ratio_at_attenuation_inverts():
    for level in (0.25, 0.49, 0.9, 0.999):
        r = optics.ratio_at_attenuation(level)
        np.testing.assert_allclose(optics.attenuation(r), level, rtol=1e-10)
    with pytest.raises(optics.RangeError, match="attenuation level"):
        optics.ratio_at_attenuation(1.5)


def test_circle_of_confusion_eq2():
    # Eq. 2 by hand: Phi = 100/8 mm, Z' = 450 mm, Z = 460 mm -> 12.5 * 10 / 450
    np.testing.assert_allclose(optics.circle_of_confusion(460.0, 450.0, 12.5),
                               12.5 * 10 / 450, rtol=1e-15)


def test_projector_magnification_is_thin_lens_total_distance():
    # Eq. 3 as printed equals v/u of a thin lens whose object + image distance is Z_p
    f, z = 25.0, 471.2749
    s = np.sqrt(z * (z - 4 * f))
    u, v = (z + s) / 2, (z - s) / 2
    np.testing.assert_allclose(1 / u + 1 / v, 1 / f, rtol=1e-12)
    np.testing.assert_allclose(optics.projector_magnification(z, z, f), v / u, rtol=1e-12)


def test_airy_and_blur_areas():
    # Eq. 15/16: d_c = 2.44 * 450 nm * 8 = 8.784 um; b_d = pi (8.784 / 16)^2
    d = optics.airy_diameter(450e-6, 8.0)
    np.testing.assert_allclose(d, 8.784e-3, rtol=1e-12)
    np.testing.assert_allclose(optics.diffraction_blur_area(d, 8e-3),
                               np.pi * (8.784 / 16) ** 2, rtol=1e-12)
    # Eq. 13 clamps to one pixel
    np.testing.assert_allclose(optics.camera_blur_area([0.0, 0.1], 8e-3),
                               [1.0, np.pi * (100 / 16) ** 2], rtol=1e-12)


def test_filter_factor_readings():
    f_none = optics.filter_factor(1.0, 0.947, 3.0, "none")
    f_one = optics.filter_factor(1.0, 0.947, 3.0, "one")
    np.testing.assert_allclose(f_none, np.sqrt(0.947) / 3.0, rtol=1e-14)
    np.testing.assert_allclose(f_one, 1.0)
    with pytest.raises(ValueError, match="floor"):
        optics.filter_factor(1.0, 1.0, 1.0, "half")


def test_optical_scale_readings():
    np.testing.assert_allclose(optics.optical_scale(2.0, 0.5, 0.5, "power"), 2.0)
    np.testing.assert_allclose(optics.optical_scale(2.0, 0.5, 0.5, "amplitude"), 1.0)
    # mixed: 1 / (F sqrt(A_p) A_c) with A_p = 0.25, A_c = 0.5 -> 1 / (2 * 0.5 * 0.5) = 2
    np.testing.assert_allclose(optics.optical_scale(2.0, 0.25, 0.5, "mixed"), 2.0)
    np.testing.assert_allclose(optics.optical_scale(2.0, 0.5, 0.25, "mixed"),
                               1.0 / (2.0 * np.sqrt(0.5) * 0.25))
    with pytest.raises(ValueError, match="'mixed'"):
        optics.optical_scale(1.0, 1.0, 1.0, "linear")


def test_nan_in_nan_out(paper_config):
    assert np.isnan(optics.attenuation(np.nan))
    assert np.isnan(optics.circle_of_confusion(np.nan, 450.0, 12.5))
    assert np.isnan(optics.camera_blur_area(np.nan, 8e-3))
    pred = optics.predict([[0.0, 0.0, np.nan], [0.0, 0.0, 450.0]], paper_config)
    assert np.isnan(pred.sigma[0]) and not pred.valid[0]
    assert np.isfinite(pred.sigma[1]) and pred.valid[1]


def test_broadcasting(paper_config):
    pts = np.zeros((4, 5, 3))
    pts[..., 2] = np.linspace(440, 460, 20).reshape(4, 5)
    pred = optics.predict(pts, paper_config)
    assert pred.sigma.shape == (4, 5)
    flat = optics.predict(pts.reshape(-1, 3), paper_config)
    np.testing.assert_allclose(pred.sigma.ravel(), flat.sigma, rtol=1e-15)
    assert optics.attenuation(np.zeros((2, 3))).shape == (2, 3)


def test_validity_flag_and_first_zero(paper_config):
    z = np.array([450.0, 436.0, 425.0, 418.0])
    pred = optics.predict(np.stack([0 * z, 0 * z, z], -1), paper_config)
    assert pred.valid[0]
    assert not pred.valid[1]  # r_c > 1/2 at 436 mm: outside the paper's validity
    assert pred.ratio_camera[3] > optics.FIRST_ZERO_RATIO
    assert np.isnan(pred.sigma[3])  # past the first zero: no number at all
    assert np.isnan(pred.sigma_trusted[1])


def test_sigma_at_focus_matches_config_note(paper_config):
    # calib/paper_scanner.toml: sigma_p was chosen so that s_O sigma_p = 0.02 px at focus
    pred = optics.predict([0.0, 0.0, 450.0], paper_config)
    np.testing.assert_allclose(pred.s_o * paper_config.model.sigma_p_px, 0.02, rtol=1e-3)


def test_triangulation_scale_matches_finite_difference(paper_config):
    q = np.array([3.0, -2.0, 455.0])
    d = q / np.linalg.norm(q)
    proj = paper_config.projector

    def xp(point):
        qp = geometry.to_projector_frame(point, paper_config)
        return proj.principal_distance_px * qp[0] / qp[2]

    h = 1e-4
    slope = (xp(q + h * d) - xp(q - h * d)) / (2 * h)
    np.testing.assert_allclose(geometry.triangulation_scale(q, paper_config), 1 / abs(slope),
                               rtol=1e-7)


def test_w_shape(paper_config):
    """Issue 2: a local maximum of sigma at focus, a minimum each side, rising past the DOF."""
    curve = tools.axis_curve(paper_config, 420.0, 480.0, 0.25)
    z, s = curve["z_mm"], curve["sigma_um"]
    focus = paper_config.camera.focus_mm
    i_f = int(np.argmin(abs(z - focus)))
    near = (z > 430) & (z < focus)
    far = (z > focus) & (z < 470)
    i_near = np.flatnonzero(near)[np.argmin(s[near])]
    i_far = np.flatnonzero(far)[np.argmin(s[far])]
    dof = tools.camera_dof(paper_config, 0.49, 5)
    assert dof.near_mm < z[i_near] < focus < z[i_far] < dof.far_mm
    assert s[i_f] > 2 * s[i_near] and s[i_f] > 2 * s[i_far]
    # rising past the depth of field on both sides
    assert s[np.argmin(abs(z - 430))] > 2 * s[i_near]
    assert s[np.argmin(abs(z - 470))] > 2 * s[i_far]
    # slanted: the two minima differ (s_T grows with range)
    assert s[i_far] != pytest.approx(s[i_near], rel=0.01)


def test_floor_reading_removes_the_focus_maximum(paper_config):
    # with F >= 1, F = 1 near focus and sigma = s_T sigma_p / A: focus becomes a local
    # minimum, which contradicts Fig. 3 - the reason "none" is the default
    cfg = paper_config.replace_model(filter_floor="one")
    c = tools.axis_curve(cfg, 448.0, 452.0, 0.5)
    i_f = int(np.argmin(abs(c["z_mm"] - 450.0)))
    # (within 0.1 % of the minimum: s_T slants the curve by ~0.1 %/mm)
    assert c["sigma_um"][i_f] < min(c["sigma_um"][0], c["sigma_um"][-1])
    np.testing.assert_allclose(c["sigma_um"][i_f], c["sigma_um"].min(), rtol=1e-3)
    d = tools.axis_curve(paper_config, 448.0, 452.0, 2.0)  # as printed: maximum at focus
    assert d["sigma_um"][1] > max(d["sigma_um"][0], d["sigma_um"][2])


def test_dof_linear_in_period(paper_config):
    for level in (0.3, 0.64):
        base = tools.camera_dof(paper_config, level, 5.0).dof_mm
        np.testing.assert_allclose(tools.camera_dof(paper_config, level, 10.0).dof_mm,
                                   2 * base, rtol=1e-12)
        base_p = tools.projector_dof(paper_config, level, 5.0).dof_mm
        # projector: linear up to the Eq. 3 asymmetry, below 1 % here
        np.testing.assert_allclose(tools.projector_dof(paper_config, level, 10.0).dof_mm,
                                   2 * base_p, rtol=0.01)


@settings(max_examples=60, deadline=None)
@given(a=FINITE, b=FINITE)
def test_attenuation_monotone_on_main_lobe(a, b):
    lo, hi = sorted((a, b))
    assert optics.attenuation(lo) >= optics.attenuation(hi) - 1e-15


@settings(max_examples=60, deadline=None)
@given(dz=st.floats(min_value=0.0, max_value=200.0))
def test_circle_of_confusion_symmetric(dz):
    c_near = optics.circle_of_confusion(450.0 - dz, 450.0, 12.5)
    c_far = optics.circle_of_confusion(450.0 + dz, 450.0, 12.5)
    np.testing.assert_allclose(c_near, c_far, rtol=1e-12, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(level=st.floats(min_value=0.05, max_value=0.99))
def test_camera_dof_symmetric_and_projector_far_side_longer(paper_config, level):
    cam = tools.camera_dof(paper_config, level, 5.0)
    focus = paper_config.camera.focus_mm
    np.testing.assert_allclose(focus - cam.near_mm, cam.far_mm - focus, rtol=1e-12)
    proj = tools.projector_dof(paper_config, level, 5.0)
    z_f = paper_config.projector.focus_mm
    assert proj.far_mm - z_f > z_f - proj.near_mm  # omega_o grows with Z_p


@settings(max_examples=30, deadline=None)
@given(lo=st.floats(min_value=0.05, max_value=0.98), d=st.floats(min_value=0.005, max_value=0.5))
def test_dof_shrinks_as_level_rises(paper_config, lo, d):
    hi = min(lo + d, 0.99)
    for func in (tools.camera_dof, tools.projector_dof):
        assert func(paper_config, lo, 5.0).dof_mm >= func(paper_config, hi, 5.0).dof_mm


def test_usable_volume_is_part_of_total(paper_config):
    vol = tools.usable_volume(paper_config, 0.49, step=3.0)
    assert 0 < vol.usable_mm3 < vol.total_mm3
    strict = tools.usable_volume(paper_config, 0.81, step=3.0)
    assert strict.usable_mm3 < vol.usable_mm3
    assert vol.total_mm3 == strict.total_mm3


@pytest.mark.parametrize("floor", ["none", "one"])
def test_flatten_filter_brings_sigma_to_the_lowest_valid_sigma(paper_config, floor):
    """Sect. 5.2 forward: the filter's area, added to b_c in Eq. 17, must lower every valid
    sigma of the independent model chain (tests/model_reference.py) to the lowest one;
    sigma is 1 / F_gamma times quantities the filter does not change (Eqs. 18, 19)."""
    cfg = paper_config.replace_model(filter_floor=floor)
    res = tools.flatten_curve(cfg, 434.0, 466.0, 0.5)
    ref = [reference_point((0.0, 0.0, z), cfg, "power", floor) for z in res["z_mm"]]
    sigma = 1e3 * np.array([r["sigma"] for r in ref])
    valid = np.array([r["valid"] for r in ref])
    assert valid.any() and not valid.all()  # the range reaches past the validity
    np.testing.assert_array_equal(res["model_valid"], valid)
    np.testing.assert_allclose(res["sigma_um"], sigma, rtol=1e-9)
    target = sigma[valid].min()
    b_c = np.array([r["blur_area_camera"] for r in ref])
    f_before = np.array([r["filter_factor"] for r in ref])
    b_d = np.pi * (2 * 1.22 * 450e-6 * 8.0 / (2 * 8e-3)) ** 2  # Eqs. 15, 16 at f/8
    b_f = np.pi * (res["filter_diameter_px"] / 2) ** 2
    f_after = np.sqrt((b_c + b_f) * b_d) / 3.0  # Eq. 17, gamma = 3
    if floor == "one":
        f_after = np.maximum(f_after, 1.0)
    after = sigma * f_before / f_after
    np.testing.assert_allclose(after[valid], target, rtol=1e-9)
    np.testing.assert_allclose(res["sigma_flat_um"][valid], after[valid], rtol=1e-9)
    assert np.isnan(res["sigma_flat_um"][~valid]).all()
    assert np.isnan(res["filter_diameter_px"][~valid]).all()
    np.testing.assert_allclose(res["optical_blur_diameter_px"], 2 * np.sqrt(b_c / np.pi),
                               rtol=1e-12)
    # no filter where sigma is already at the target; between the two minima of the W the
    # largest filter is at focus (Fig. 7)
    assert res["filter_diameter_px"][valid][np.argmin(sigma[valid])] == 0.0
    z, d = res["z_mm"], res["filter_diameter_px"]
    inner = (z > 441.0) & (z < 459.0)
    assert z[inner][np.argmax(d[inner])] == pytest.approx(450.0, abs=1.0)


def test_flatten_hand_value_at_focus(paper_config):
    """At focus b_c = 1 (Eq. 13), so with Eq. 17 as printed the filter area is
    (sigma_focus / target)^2 - 1 and its diameter 2 sqrt(b_f / pi)."""
    res = tools.flatten_curve(paper_config, 438.0, 462.0, 0.5)
    i = int(np.flatnonzero(res["z_mm"] == 450.0)[0])
    ok = res["model_valid"]
    ratio = res["sigma_um"][i] / res["sigma_um"][ok].min()
    np.testing.assert_allclose(res["filter_diameter_px"][i],
                               2 * np.sqrt((ratio**2 - 1) / np.pi), rtol=1e-9)
    with pytest.raises(optics.RangeError, match="not valid anywhere"):
        tools.flatten_curve(paper_config, 400.0, 420.0, 1.0)


def test_smooth_floor_gamma_follows_the_range(paper_config):
    """The smooth floor's noise cells are fixed on the object: gamma [px] at Z_c is gamma
    x focus / Z_c (450 mm focus: 2.0 px at 450 mm, 1.0 px at 900 mm, by hand); the
    paper's floors keep gamma; NaN in, NaN out. The fit's fast path (s_o_with) and the
    model chain give the same s_O with it."""
    g = optics.correlation_gamma(2.0, np.array([450.0, 900.0, np.nan]), paper_config,
                                 "smooth")
    np.testing.assert_allclose(g[:2], [2.0, 1.0], rtol=1e-12)  # hand values
    assert np.isnan(g[2])
    np.testing.assert_array_equal(
        optics.correlation_gamma(2.0, np.array([450.0, 900.0]), paper_config, "one"), 2.0)
    cfg = paper_config.replace_model(filter_floor="smooth", filter_form="sum",
                                     noise_reading="two_source", sensor_sigma_p_px=0.005)
    z_c = np.array([430.0, 450.0, 470.0])
    z_p = z_c + 21.27
    terms = optics.optical_terms(z_c, z_p, cfg, gamma=2.2)
    # F^2 = 1 + (F_1 Z_c / (gamma Z_focus))^2 with F_1 the factor for gamma = 1
    expected = np.sqrt(1.0 + (terms.filter_base * z_c / (2.2 * 450.0)) ** 2)
    np.testing.assert_allclose(terms.filter_factor, expected, rtol=1e-12)
    fast = optics.optical_terms(z_c, z_p, cfg, gamma=1.0).s_o_with(
        2.2, "smooth", "two_source", 0.005 / cfg.model.sigma_p_px)
    np.testing.assert_allclose(fast, terms.s_o, rtol=1e-12)
