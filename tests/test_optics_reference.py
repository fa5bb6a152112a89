"""The model chain (Eqs. 1-19 of Drouin et al. 2017) against an independent scalar version
(tests/model_reference.py): a wrong constant, operator or argument anywhere in the chain
changes at least one field of the prediction."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanqa.model import geometry, optics

from .model_reference import FLOORS, FORMS, READINGS, attenuation, reference_point


def _grid_points() -> np.ndarray:
    """On and off axis, in focus, inside the DOF, past its validity and past the first zero."""
    zs = np.array([415.0, 430.0, 436.0, 441.5, 447.0, 450.0, 453.0, 458.5, 466.0, 480.0])
    xs = np.array([-45.0, 0.0, 30.0])
    ys = np.array([-35.0, 0.0, 20.0])
    return np.array([[x, y, z] for z in zs for x in xs for y in ys])


FIELDS = ("z_c", "z_p", "omega_o", "ratio_camera", "ratio_projector", "attenuation_camera",
          "attenuation_projector", "blur_area_camera", "filter_factor", "s_o", "s_t", "sigma")


def _compare(pred, ref_rows: list[dict]) -> None:
    for name in FIELDS:
        want = np.array([r[name] for r in ref_rows])
        got = np.asarray(getattr(pred, name))
        # float64 agreement ~1e-12 (atol: |Z - Z'| cancels near focus); 1e-9 leaves room
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, equal_nan=True,
                                   err_msg=name)
    np.testing.assert_array_equal(pred.valid, [r["valid"] for r in ref_rows])


@pytest.mark.parametrize("reading", READINGS)
@pytest.mark.parametrize("floor", FLOORS)
def test_predict_matches_independent_chain(paper_config, reading, floor):
    pts = _grid_points()
    pred = optics.predict(pts, paper_config, filter_floor=floor, noise_reading=reading)
    ref = [reference_point(p, paper_config, reading, floor) for p in pts]
    _compare(pred, ref)
    assert pred.filter_floor == floor and pred.noise_reading == reading
    # the grid reaches every regime of the model
    assert any(r["valid"] for r in ref) and not all(r["valid"] for r in ref)
    assert any(math.isnan(r["sigma"]) for r in ref)
    assert any(r["blur_area_camera"] == 1.0 for r in ref)  # Eq. 13's floor at focus
    assert any(r["blur_area_camera"] > 1.0 for r in ref)
    assert any(r["filter_factor"] > 1.0 for r in ref)
    assert any(r["filter_factor"] < 1.0 for r in ref) == (floor == "none")


def test_config_defaults_period_sigma_p_and_given_s_t(paper_config):
    """The config's readings, working period and sigma_p are the defaults; a given
    period, sigma_p and s_T replace them."""
    cfg = paper_config.replace_model(filter_floor="one", noise_reading="mixed")
    pts = _grid_points()
    pred = optics.predict(pts, cfg)
    _compare(pred, [reference_point(p, cfg, "mixed", "one") for p in pts])
    pred7 = optics.predict(pts, cfg, period_px=7.0, s_t=0.125, sigma_p=0.01)
    ref7 = [reference_point(p, cfg, "mixed", "one", period=7.0) for p in pts]
    for name in ("omega_o", "ratio_camera", "ratio_projector", "s_o"):
        np.testing.assert_allclose(getattr(pred7, name), [r[name] for r in ref7],
                                   rtol=1e-9, atol=1e-12, equal_nan=True, err_msg=name)
    np.testing.assert_allclose(pred7.s_t, 0.125)
    np.testing.assert_allclose(pred7.sigma, [0.125 * r["s_o"] * 0.01 for r in ref7],
                               rtol=1e-9, equal_nan=True)


def test_optical_terms_gamma_and_overrides(paper_config):
    """optical_terms: the given gamma replaces the config's (Eq. 17 scales as 1 / gamma)."""
    z_c = np.array([440.0, 450.0, 462.0])
    z_p = np.array([460.0, 471.2749, 485.0])
    t3 = optics.optical_terms(z_c, z_p, paper_config)
    t6 = optics.optical_terms(z_c, z_p, paper_config, gamma=6.0, filter_floor="none",
                              noise_reading="power")
    np.testing.assert_allclose(t6.filter_factor, t3.filter_factor / 2.0, rtol=1e-14)
    np.testing.assert_allclose(t6.s_o, 2.0 * t3.s_o, rtol=1e-14)
    for zc, zp, so in zip(z_c, z_p, t3.s_o, strict=True):
        pc = _point_at(paper_config, zc, zp)
        r = reference_point(pc, paper_config, "power", "none")
        np.testing.assert_allclose(r["z_p"], zp, rtol=1e-9)
        np.testing.assert_allclose(so, r["s_o"], rtol=1e-9)


def _point_at(cfg, z_c: float, z_p: float) -> tuple[float, float, float]:
    """The point with Y = 0 at camera depth z_c and projector depth z_p [mm]."""
    px, _, pz = cfg.projector.position_mm
    ax, az = cfg.projector.look_at_mm[0] - px, cfg.projector.look_at_mm[2] - pz
    norm = math.hypot(ax, az)
    # z_p = ((x - px) ax + (z_c - pz) az) / norm, solved for x
    x = px + (z_p * norm - (z_c - pz) * az) / ax
    return (x, 0.0, z_c)


def test_focus_hand_value(paper_config):
    """calib/paper_scanner.toml's note: s_O(focus) = 3.0830 at f/8, gamma = 3 (Eq. 19 with
    A_c = 1, b_c = 1 and b_d = pi (2.44 * 0.45 um * 8 / 16 um)^2 = 0.94688)."""
    b_d = math.pi * (2.44 * 0.45 * 8 / 16) ** 2
    np.testing.assert_allclose(b_d, 0.94688, rtol=1e-5)
    terms = optics.optical_terms(450.0, 471.2749, paper_config)
    np.testing.assert_allclose(terms.filter_factor, math.sqrt(b_d) / 3.0, rtol=1e-12)
    np.testing.assert_allclose(terms.attenuation_camera, 1.0, rtol=0, atol=0)
    np.testing.assert_allclose(terms.s_o, 3.0830, rtol=1e-4)


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-60, 60), y=st.floats(-50, 50), z=st.floats(425.0, 480.0),
       reading=st.sampled_from(READINGS), floor=st.sampled_from(FLOORS))
def test_predict_matches_independent_chain_anywhere(paper_config, x, y, z, reading, floor):
    pred = optics.predict([x, y, z], paper_config, filter_floor=floor, noise_reading=reading)
    _compare(pred, [reference_point((x, y, z), paper_config, reading, floor)])


def test_image_blur_diameter_eq14_and_thin_lens():
    """Eq. 14 by hand, and within 1 % of the thin-lens blur of a sensor focused at Z' over
    +-10 mm (they differ by f |Z - Z'| / (Z' (Z - f)) relative, to first order)."""
    f, focus, phi = 100.0, 450.0, 12.5
    # Eq. 14 at Z = 460: f / (Z - f) * Phi |Z - Z'| / Z' = 100 / 360 * 12.5 * 10 / 450
    np.testing.assert_allclose(optics.image_blur_diameter(460.0, f, focus, phi),
                               100 / 360 * 12.5 * 10 / 450, rtol=1e-14)
    z = np.array([440.0, 445.0, 449.0, 450.0, 455.0, 460.0])
    v, v_focus = f * z / (z - f), f * focus / (focus - f)  # thin lens: image distances
    geometric = phi * np.abs(v - v_focus) / v
    got = optics.image_blur_diameter(z, f, focus, phi)
    np.testing.assert_allclose(got, geometric, rtol=0.01, atol=1e-15)
    assert got[3] == 0.0


def test_validity_boundary_is_inclusive():
    """The paper's validity is r <= 1/2 (Sect. 3.1): r = 0.5 exactly is valid."""
    one = np.ones(3)
    terms = optics.OpticalTerms(*(one,) * 5, one, one, one, one, one, "none", "power")
    terms = dataclasses.replace(terms, ratio_camera=np.array([0.5, 0.5, 0.5000001]),
                                ratio_projector=np.array([0.5, 0.4999999, 0.1]))
    np.testing.assert_array_equal(terms.within_validity, [True, True, False])
    terms = dataclasses.replace(terms, ratio_camera=np.array([0.1, 0.1, 0.1]),
                                ratio_projector=np.array([0.5, 0.5000001, 0.0]))
    np.testing.assert_array_equal(terms.within_validity, [True, False, True])


def test_config_with_list_pose_still_predicts(paper_config):
    """A projector whose pose fields are lists (unhashable: no rotation cache) gives the
    same numbers through the uncached rotation."""
    proj = dataclasses.replace(paper_config.projector)
    object.__setattr__(proj, "position_mm", list(proj.position_mm))
    cfg = dataclasses.replace(paper_config, projector=proj)
    with pytest.raises(TypeError):
        hash(proj)
    pts = _grid_points()
    _compare(optics.predict(pts, cfg), [reference_point(p, paper_config, "power", "none")
                                        for p in pts])
    np.testing.assert_allclose(geometry.to_projector_frame(pts, cfg),
                               geometry.to_projector_frame(pts, paper_config), rtol=1e-15)


def test_to_projector_frame_by_hand(paper_config):
    """Q_p = R (Q - position) with R built by hand for a projector at (140, 0, 0) looking at
    (0, 0, 450): z axis (-140, 0, 450) / n, x axis (450, 0, 140) / n, y axis +Y."""
    n = math.hypot(140.0, 450.0)
    q = np.array([[10.0, -7.0, 440.0], [-30.0, 25.0, 470.0]])
    d = q - [140.0, 0.0, 0.0]
    want = np.stack([(450 * d[:, 0] + 140 * d[:, 2]) / n, d[:, 1],
                     (-140 * d[:, 0] + 450 * d[:, 2]) / n], -1)
    np.testing.assert_allclose(geometry.to_projector_frame(q, paper_config), want, rtol=1e-13)
    np.testing.assert_allclose(geometry.projector_depth(q, paper_config), want[:, 2], rtol=1e-13)
    # the axes crossing at (0, 0, 450) is at the projector's focus distance hypot(140, 450)
    np.testing.assert_allclose(geometry.projector_depth([0.0, 0.0, 450.0], paper_config),
                               n, rtol=1e-13)


def test_ratio_at_attenuation_hand_values():
    """Inverse of Eq. 12 against the power-series attenuation: A(r_a) = a on the main lobe;
    a = 1 is r = 0 exactly, and a = 0.49 gives the r_a = 0.52148 of calib/paper_scanner.toml."""
    assert optics.ratio_at_attenuation(1.0) == 0.0
    np.testing.assert_allclose(optics.ratio_at_attenuation(0.49), 0.52148, atol=5e-6)
    for level in (1e-6, 0.1, 0.49, 0.8, 1 - 1e-9):
        r = optics.ratio_at_attenuation(level)
        assert 0.0 < r < 1.2196698912665045
        np.testing.assert_allclose(attenuation(r), level, rtol=1e-9)
        assert abs(attenuation(r) - level) < 1e-13  # solved to xtol 1e-14, not brentq's 2e-12
    for bad in (0.0, -0.2, 1.0000001, math.nan):
        with pytest.raises(optics.RangeError, match=r"attenuation level must be in \(0, 1\]"):
            optics.ratio_at_attenuation(bad)


def test_attenuation_against_series_and_side_lobe():
    """Eq. 12 vs the power series on and past the main lobe (A rises again in side lobes);
    negative r gives the same (the kernel is symmetric); the input is not modified."""
    r = np.array([1e-9, 0.05, 0.3, 0.5, 0.9, 1.2, 1.5, 2.0, 2.6])
    want = [attenuation(v) for v in r]
    np.testing.assert_allclose(optics.attenuation(r), want, rtol=1e-11)
    np.testing.assert_allclose(optics.attenuation(-r), want, rtol=1e-11)
    before = r.copy()
    optics.attenuation(r)
    np.testing.assert_array_equal(r, before)
    assert optics.attenuation(1.5) > optics.attenuation(1.2)  # side lobe


def test_defaults_of_the_readings():
    """Called without a reading, Eq. 17 and Eq. 19 are applied as printed."""
    np.testing.assert_allclose(optics.filter_factor(4.0, 0.25, 2.0), 0.5, rtol=1e-15)
    np.testing.assert_allclose(optics.optical_scale(0.5, 0.5, 0.8), 1 / (0.5 * 0.4),
                               rtol=1e-15)


def test_integer_input():
    """Integer arrays (e.g. ranges typed by hand) give the same numbers as floats."""
    np.testing.assert_array_equal(optics.attenuation(0), 1.0)
    np.testing.assert_allclose(optics.attenuation(np.array([0, 1])),
                               [1.0, attenuation(1.0)], rtol=1e-11)
    np.testing.assert_allclose(optics.circle_of_confusion([440, 460], 450, 12), [12 / 45] * 2,
                               rtol=1e-15)


def test_degenerate_inputs_give_nan_or_inf_without_warnings(paper_config, recwarn):
    """The documented NaN / inf cases are silent (no RuntimeWarning): r = 0 in Eq. 12, an
    attenuation of 0 in Eq. 19, Z_p < 4 f_p in Eq. 3, a point at the scanner's origin or on
    the baseline."""
    assert optics.attenuation(np.array([0.0, np.nan]))[0] == 1.0
    assert np.isinf(optics.optical_scale(1.0, np.array([0.0]), 0.5, "power"))[0]
    assert np.isinf(optics.optical_scale(1.0, 0.5, np.array([0.0]), "mixed"))[0]
    assert np.isnan(optics.projector_magnification(np.array([50.0]), 471.0, 25.0))[0]
    assert np.isnan(geometry.triangulation_scale(np.zeros((1, 3)), paper_config))[0]
    # a point on the baseline: camera and projector rays coincide, s_T is infinite
    assert np.isinf(geometry.triangulation_scale(np.array([[70.0, 0.0, 0.0]]), paper_config))[0]
    pred = optics.predict([[0.0, 0.0, np.nan], [0.0, 0.0, 405.0], [0.0, 0.0, 450.0]],
                          paper_config)
    assert np.isnan(pred.sigma[:2]).all() and np.isfinite(pred.sigma[2])
    assert [str(w.message) for w in recwarn] == []


def _tilted_config(paper_config):
    """The paper's scanner with the projector raised, set back and aimed off the XZ plane."""
    proj = dataclasses.replace(paper_config.projector, position_mm=(140.0, 30.0, -12.0),
                               look_at_mm=(5.0, -8.0, 455.0))
    return dataclasses.replace(paper_config, projector=proj)


def test_projector_frame_of_a_general_pose(paper_config):
    """For a projector off the XZ plane: its position maps to the origin, the point it looks
    at to (0, 0, distance), distances are kept, its x axis is horizontal (no Y component)
    and right-handed with y and z; projector_depth is the frame's third coordinate."""
    cfg = _tilted_config(paper_config)
    pos, look = np.array([140.0, 30.0, -12.0]), np.array([5.0, -8.0, 455.0])
    np.testing.assert_allclose(geometry.to_projector_frame(pos, cfg), 0.0, atol=1e-12)
    np.testing.assert_allclose(geometry.to_projector_frame(look, cfg),
                               [0.0, 0.0, np.linalg.norm(look - pos)], atol=1e-9)
    rng = np.random.default_rng(2)
    q = rng.uniform([-60, -50, 400], [60, 50, 500], (50, 3))
    qp = geometry.to_projector_frame(q, cfg)
    np.testing.assert_allclose(np.linalg.norm(qp, axis=1), np.linalg.norm(q - pos, axis=1),
                               rtol=1e-12)
    x_axis = geometry.to_projector_frame(pos + np.array([1.0, 0.0, 0.0]), cfg)  # scanner X
    y_axis = geometry.to_projector_frame(pos + np.array([0.0, 1.0, 0.0]), cfg)
    assert abs(y_axis[0]) < 1e-12  # the projector's x axis has no scanner-Y component
    assert x_axis[0] > 0.9 and y_axis[1] > 0.9
    np.testing.assert_allclose(geometry.projector_depth(q, cfg), qp[:, 2], rtol=1e-12)
    # and the whole chain with this pose: Z_p is that depth, s_T the finite difference
    pred = optics.predict(q, cfg)
    np.testing.assert_allclose(pred.z_p, qp[:, 2], rtol=1e-12)
    d = q / np.linalg.norm(q, axis=1, keepdims=True)
    f_p = cfg.projector.principal_distance_px

    def x_p(points):
        p = geometry.to_projector_frame(points, cfg)
        return f_p * p[:, 0] / p[:, 2]

    h = 1e-3
    slope = (x_p(q + h * d) - x_p(q - h * d)) / (2 * h)
    np.testing.assert_allclose(pred.s_t, 1 / np.abs(slope), rtol=1e-6)


# -- the two-source model and the "sum" filter form (docs/noise_model.rst) ---------------

SENSOR_PX = 0.0042  # sigma_s, about a sixth of the paper config's sigma_p


def _two_source_config(paper_config, form: str, floor: str, reading: str,
                       sensor: float = SENSOR_PX):
    return paper_config.replace_model(filter_form=form, filter_floor=floor,
                                      noise_reading=reading, sensor_sigma_p_px=sensor)


@pytest.mark.parametrize("reading", [*READINGS, "two_source"])
@pytest.mark.parametrize("floor", FLOORS)
@pytest.mark.parametrize("form", FORMS)
def test_predict_every_variant_matches_independent_chain(paper_config, form, floor, reading):
    """Every floor, form and reading from the config, against the scalar chain written from
    the variances; the scene and sensor parts too (the sensor part is 0 but for
    "two_source")."""
    cfg = _two_source_config(paper_config, form, floor, reading)
    pts = _grid_points()
    pred = optics.predict(pts, cfg)
    ref = [reference_point(p, cfg, reading, floor, form=form) for p in pts]
    _compare(pred, ref)
    for name in ("sigma_scene", "sigma_sensor"):
        np.testing.assert_allclose(getattr(pred, name), [r[name] for r in ref], rtol=1e-9,
                                   atol=1e-15, equal_nan=True, err_msg=name)
    assert (pred.filter_floor, pred.noise_reading, pred.filter_form) == (floor, reading, form)
    assert any(r["filter_factor"] < 1.0 for r in ref) == (floor == "none")
    if reading == "two_source":  # sigma^2 = scene^2 + sensor^2, both parts present
        np.testing.assert_allclose(pred.sigma**2, pred.sigma_scene**2 + pred.sigma_sensor**2,
                                   rtol=1e-12)
        ok = np.isfinite(pred.sigma)
        assert (pred.sigma_sensor[ok] > 0).all() and (pred.sigma_scene[ok] > 0).all()
    else:
        assert np.all(pred.sigma_sensor[np.isfinite(pred.sigma)] == 0.0)


@pytest.mark.parametrize("form", FORMS)
def test_optical_terms_fields_and_s_o_with(paper_config, form):
    """optical_terms keeps F_1 (gamma 1, no floor) as filter_base and the scene and sensor
    parts of s_O; s_o_with redoes s_O for another gamma, floor, reading and sensor ratio
    as the scalar chain does with those in the config."""
    cfg = _two_source_config(paper_config, form, "one", "two_source")
    pts = _grid_points()
    z_p = geometry.projector_depth(pts, cfg)
    terms = optics.optical_terms(pts[:, 2], z_p, cfg)
    ref = [reference_point(p, cfg, "two_source", "one", form=form) for p in pts]
    for name in ("filter_base", "s_o_scene", "s_o_sensor", "s_o", "filter_factor"):
        np.testing.assert_allclose(getattr(terms, name), [r[name] for r in ref], rtol=1e-9,
                                   atol=1e-15, equal_nan=True, err_msg=name)
    assert terms.filter_form == form
    # integer depths give float terms
    ints = optics.optical_terms([450, 460], [471, 480], cfg)
    assert ints.z_c.dtype == ints.z_p.dtype == np.float64
    for gamma, floor, reading, rho in ((1.5, "none", "two_source", 0.5),
                                       (4.0, "one", "two_source", 0.0),
                                       (2.0, "none", "mixed", 0.3),
                                       (1.0, "one", "power", 0.0)):
        other = cfg.replace_model(gamma=gamma, filter_floor=floor, noise_reading=reading,
                                  sensor_sigma_p_px=rho * cfg.model.sigma_p_px)
        want = [reference_point(p, other, reading, floor, form=form)["s_o"] for p in pts]
        np.testing.assert_allclose(terms.s_o_with(gamma, floor, reading, rho), want,
                                   rtol=1e-9, equal_nan=True, err_msg=f"{gamma} {floor}")
    # the sensor ratio defaults to 0; a ratio exactly at the first zero of J1 is NaN
    np.testing.assert_allclose(terms.s_o_with(2.0, "one", "two_source"),
                               terms.s_o_with(2.0, "one", "two_source", 0.0), rtol=0)
    ok = np.flatnonzero(np.isfinite(terms.s_o))[:2]
    edge = dataclasses.replace(terms, ratio_camera=np.where(
        np.arange(len(pts)) == ok[0], optics.FIRST_ZERO_RATIO, terms.ratio_camera),
        ratio_projector=np.where(np.arange(len(pts)) == ok[1], optics.FIRST_ZERO_RATIO,
                                 terms.ratio_projector))
    s_o = edge.s_o_with(3.0, "one", "two_source", 0.2)
    assert np.isnan(s_o[ok]).all() and np.isfinite(s_o).sum() == np.isfinite(terms.s_o).sum() - 2


def test_overrides_of_form_and_sensor_ratio(paper_config):
    """optical_terms takes the form and the sensor ratio as arguments over the config's;
    predict's sigma_p replaces the scene-side noise only (the sensor's is kept)."""
    cfg = _two_source_config(paper_config, "product", "none", "power")
    pts = _grid_points()
    z_p = geometry.projector_depth(pts, cfg)
    terms = optics.optical_terms(pts[:, 2], z_p, cfg, filter_form="sum", filter_floor="one",
                                 noise_reading="two_source", sensor_ratio=0.25)
    other = _two_source_config(paper_config, "sum", "one", "two_source",
                               0.25 * cfg.model.sigma_p_px)
    ref = [reference_point(p, other, "two_source", "one", form="sum") for p in pts]
    for name in ("filter_factor", "s_o", "s_o_sensor"):
        np.testing.assert_allclose(getattr(terms, name), [r[name] for r in ref], rtol=1e-9,
                                   equal_nan=True, err_msg=name)
    cfg = _two_source_config(paper_config, "sum", "one", "two_source")
    pred = optics.predict(pts, cfg, sigma_p=0.01)
    assert optics.predict([[0, 0, 450]], cfg, s_t=1).s_t.dtype == np.float64
    ref = [reference_point(p, cfg.replace_model(sigma_p_px=0.01), "two_source", "one",
                           form="sum") for p in pts]
    _compare(pred, ref)
    np.testing.assert_allclose(pred.sigma_sensor, [r["sigma_sensor"] for r in ref],
                               rtol=1e-9, equal_nan=True)


def test_sum_form_and_two_source_hand_values():
    """F = sqrt(area) / gamma for the sum form, clamped at 1 by the floor;
    camera_noise_area = 1 + pi (c / 2 s)^2 + b_d; s_O = sqrt(1 / F^2 + rho^2) /
    sqrt(A_p A_c) with its parts 1 / (F sqrt(A_p A_c)) and rho / sqrt(A_p A_c)."""
    np.testing.assert_allclose(optics.filter_factor(9.0, 100.0, 2.0, form="sum"), 1.5,
                               rtol=1e-15)
    np.testing.assert_allclose(optics.filter_factor(2.25, 100.0, 3.0, "none", "sum"), 0.5,
                               rtol=1e-15)
    np.testing.assert_allclose(optics.filter_factor(2.25, 100.0, 3.0, "one", "sum"), 1.0,
                               rtol=1e-15)
    np.testing.assert_allclose(optics.filter_factor(2.25, 4.0, 1.0, "one", "product"), 3.0,
                               rtol=1e-15)
    # c = 0.016 mm on 0.008 mm pixels: a disc of 2 px diameter, area pi
    np.testing.assert_allclose(optics.camera_noise_area(0.016, 0.008, 0.25),
                               1.0 + math.pi + 0.25, rtol=1e-15)
    np.testing.assert_allclose(optics.camera_noise_area(np.array([0.0, 0.004]), 0.002, 0.0),
                               [1.0, 1.0 + math.pi], rtol=1e-15)
    # F = 2, A_p = 0.25, A_c = 0.64: sqrt(A_p A_c) = 0.4
    got = optics.optical_scale(2.0, 0.25, 0.64, "two_source", 0.5)
    np.testing.assert_allclose(got, math.sqrt(0.25 + 0.25) / 0.4, rtol=1e-15)
    scene, sensor = optics.noise_scales(2.0, 0.25, 0.64, "two_source", 0.5)
    np.testing.assert_allclose([scene, sensor], [1 / (2 * 0.4), 0.5 / 0.4], rtol=1e-15)
    scene, sensor = optics.noise_scales(2.0, 0.25, 0.64, "two_source", 0.0)
    np.testing.assert_allclose([scene, sensor], [1 / (2 * 0.4), 0.0], rtol=1e-15)
    # the paper's readings have no sensor part, whatever rho
    for reading, a in (("power", 0.16), ("amplitude", 0.4), ("mixed", 0.5 * 0.64)):
        scene, sensor = optics.noise_scales(2.0, 0.25, 0.64, reading, 0.5)
        np.testing.assert_allclose(scene, 1 / (2 * a), rtol=1e-15)
        assert sensor == 0.0
        np.testing.assert_allclose(optics.optical_scale(2.0, 0.25, 0.64, reading, 0.5),
                                   1 / (2 * a), rtol=1e-15)
    assert np.isinf(optics.optical_scale(1.0, 0.0, 0.5, "two_source", 0.5))
    assert np.isinf(optics.optical_scale(1.0, 0.0, 0.5, "two_source", 0.0))  # no 0 / 0
    # defaults: no sensor part, and the paper's reading
    np.testing.assert_allclose(optics.optical_scale(2.0, 0.25, 0.64, "two_source"), 1 / 0.8,
                               rtol=1e-15)
    scene, sensor = optics.noise_scales(2.0, 0.25, 0.64, "two_source")
    assert sensor == 0.0
    scene, sensor = optics.noise_scales(2.0, 0.25, 0.64)
    np.testing.assert_allclose(scene, 1 / (2 * 0.16), rtol=1e-15)


def test_unknown_form_floor_or_reading_is_refused():
    with pytest.raises(ValueError, match=r"^form must be 'product' or 'sum', got 'add'$"):
        optics.filter_factor(4.0, 1.0, 1.0, "none", "add")
    with pytest.raises(ValueError, match=r"^floor must be 'none', 'one' or 'smooth', got 'two'$"):
        optics.filter_factor(4.0, 1.0, 1.0, "two", "sum")
    with pytest.raises(ValueError, match=r"^reading must be 'power', 'amplitude', 'mixed' or "
                                         r"'two_source', got 'cube'$"):
        optics.noise_scales(1.0, 0.5, 0.5, "cube")


def test_sum_form_filters_where_the_product_cannot(paper_config):
    """docs/noise_model.rst: with pixels much larger than the Airy disc (b_d << 1) the
    product sqrt(b_c b_d) stays below 1 even 30 mm out of focus, while the sum form's F
    grows with the blur disc. A 64 um pixel at f/11: b_d = pi (2.44 * 0.45 * 11 / 128)^2."""
    cam = dataclasses.replace(paper_config.camera, pixel_um=64.0, f_number=11.0)
    base = dataclasses.replace(paper_config, camera=cam)
    b_d = math.pi * (2.44 * 0.45 * 11 / 128) ** 2
    assert 0.02 < b_d < 0.04
    z_c = np.array([cam.focus_mm, cam.focus_mm + 30.0])
    z_p = np.full(2, paper_config.projector.focus_mm)
    prod = optics.optical_terms(z_c, z_p, base.replace_model(filter_form="product",
                                                             filter_floor="none"), gamma=1.0)
    summ = optics.optical_terms(z_c, z_p, base.replace_model(filter_form="sum",
                                                             filter_floor="none"), gamma=1.0)
    assert (prod.filter_factor < 1.0).all()
    np.testing.assert_allclose(summ.filter_factor[0], math.sqrt(1 + b_d), rtol=1e-12)
    assert summ.filter_factor[1] > 2.0 * summ.filter_factor[0]
