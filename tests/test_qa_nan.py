"""NaN, inf and zero into every public numeric QA function (colour's per-function tests).

Each case gives a function NaN, inf or a zero (no points, a zero sigma, a zero size)
and expects one of two answers: a :class:`~scanqa.errors.ScanQAError` whose message
names what is wrong, or NaN (or "not evaluated") returned where the docstring says so.
Never a traceback of another type, never a finite number that hides the bad input.
Where a finite number is the right answer (a zero sigma predicts a zero bias, a point
left out of a fit), the expected value is computed by hand or without the bad point.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.errors import InputError, MethodError, ScanQAError
from scanqa.io.annotated_cloud import AnnotatedCloud
from scanqa.io.spec import BallBarCertificate, Mpe, Spec, SphereCertificate
from scanqa.qa import (
    artefacts,
    ballbar,
    blocks,
    budget,
    compare,
    correlation,
    detect,
    flat,
    paper,
    planes,
    ransac,
    sphere,
    vdi2634,
    verdict,
)
from scanqa.qa.layout import BlockSpec

from .qa_artefacts import along_sight, flat_patch, visible_cap

NAN, INF = math.nan, math.inf
RNG = np.random.default_rng(28)
CENTRE = np.array([0.0, 0.0, 450.0])
CAP, CAP_NORMALS = visible_cap(RNG, CENTRE, 12.7, 300)
CAP = along_sight(RNG, CAP, 0.005)
CAP_B, _ = visible_cap(RNG, CENTRE + np.array([100.0, 0, 0]), 12.7, 300)
SIG = np.full(300, 0.005)
FLAT, FLAT_ST = flat_patch(RNG, CENTRE, (0, 0.1, -1.0), 40.0, 400)
FLAT = FLAT + 0.003 * RNG.normal(size=FLAT.shape)
SPEC = Spec("test", {"PF": Mpe(20.0), "PS": Mpe(10.0), "SD": Mpe(30.0, 1000.0),
                     "F": Mpe(20.0)},
            sphere=SphereCertificate(25.4, 2.0, 2.0), ball_bar=BallBarCertificate(100.0, 3.0, 2.0))
EMPTY = np.zeros((0, 3))


def with_value(a, index, value):
    """A copy of ``a`` with one element set [same unit as a]."""
    out = np.array(a, dtype=float, copy=True)
    out.flat[index] = value
    return out


# ------------------------------------------------------------------ clear errors

RAISES = {
    # sphere
    "fit_sphere point nan": (lambda: sphere.fit_sphere(with_value(CAP, 4, NAN)),
                             r"sphere: 1 of 300 points are not finite"),
    "fit_sphere point inf": (lambda: sphere.fit_sphere(with_value(CAP, 4, INF)),
                             r"sphere: 1 of 300 points are not finite"),
    "fit_sphere no points": (lambda: sphere.fit_sphere(EMPTY), r"0 points, a fit needs"),
    "fit_sphere sigma nan": (lambda: sphere.fit_sphere(CAP, with_value(SIG, 2, NAN)),
                             r"sigma must be finite and >= 0"),
    "fit_sphere sigma inf": (lambda: sphere.fit_sphere(CAP, with_value(SIG, 2, INF)),
                             r"sigma must be finite and >= 0"),
    "fit_sphere every sigma 0": (lambda: sphere.fit_sphere(CAP, np.zeros(300)),
                                 r"every sigma is 0 \[mm\]"),
    "algebraic_sphere nan": (lambda: sphere.algebraic_sphere(with_value(CAP, 0, NAN)),
                             r"points are not finite"),
    "algebraic_sphere 3 points": (lambda: sphere.algebraic_sphere(CAP[:3]),
                                  r"3 points, a fit needs at least 4"),
    "cap_coverage nan": (lambda: sphere.cap_coverage(with_value(CAP, 0, NAN), CENTRE),
                         r"points are not finite"),
    "cap_coverage centre inf": (lambda: sphere.cap_coverage(CAP, [INF, 0, 450.0]),
                                r"centre must be 3 finite coordinates"),
    "cap_coverage no points": (lambda: sphere.cap_coverage(EMPTY, CENTRE), r"0 points"),
    "minimum_zone_sphere nan": (lambda: sphere.minimum_zone_sphere(with_value(CAP, 0, NAN)),
                                r"points are not finite"),
    "minimum_zone_sphere no points": (lambda: sphere.minimum_zone_sphere(EMPTY), r"0 points"),
    "sight_noise_bias radius 0": (
        lambda: sphere.sight_noise_bias(CAP, CENTRE, 0.0, SIG), r"radius must be finite and > 0"),
    "sight_noise_bias radius nan": (
        lambda: sphere.sight_noise_bias(CAP, CENTRE, NAN, SIG), r"radius must be finite"),
    "sight_noise_bias radius inf": (
        lambda: sphere.sight_noise_bias(CAP, CENTRE, INF, SIG), r"radius must be finite"),
    "sight_noise_bias point nan": (
        lambda: sphere.sight_noise_bias(with_value(CAP, 0, NAN), CENTRE, 12.7, SIG),
        r"points are not finite"),
    "sight_noise_bias no points": (
        lambda: sphere.sight_noise_bias(EMPTY, CENTRE, 12.7, 0.01), r"0 points"),
    # ball bar
    "fit_ball_bar point nan": (lambda: ballbar.fit_ball_bar(with_value(CAP, 0, NAN), CAP_B),
                               r"ball bar sphere a: 1 of 300 points are not finite"),
    "fit_ball_bar no points": (lambda: ballbar.fit_ball_bar(CAP, EMPTY),
                               r"ball bar sphere b: 0 points"),
    "fit_ball_bar every sigma 0": (
        lambda: ballbar.fit_ball_bar(CAP, CAP_B, np.zeros(300), SIG), r"every sigma is 0"),
    "find_ball_bar diameter inf": (lambda: ballbar.find_ball_bar(CAP, INF),
                                   r"ball diameter must be > 0 mm, got inf"),
    "find_ball_bar diameter 0": (lambda: ballbar.find_ball_bar(CAP, 0.0),
                                 r"ball diameter must be > 0 mm, got 0.0"),
    "find_ball_bar distance nan": (lambda: ballbar.find_ball_bar(CAP, 25.4, NAN),
                                   r"nominal distance must be finite and > 0"),
    "find_ball_bar point nan": (lambda: ballbar.find_ball_bar(with_value(CAP, 0, NAN), 25.4),
                                r"points are not finite"),
    "centre_distance same sphere": (
        lambda: ballbar.centre_distance(*[sphere.fit_sphere(CAP)] * 2), r"same centre"),
    # flat and planes
    "flatness nan": (lambda: flat.flatness(with_value(FLAT, 0, NAN)), r"flat: 1 of 400"),
    "flatness inf minimum zone": (lambda: flat.flatness(with_value(FLAT, 0, INF),
                                                        "minimum_zone"), r"flat: 1 of 400"),
    "flatness no points": (lambda: flat.flatness(EMPTY), r"flat: 0 points"),
    "minimum_zone_plane nan": (lambda: flat.minimum_zone_plane(with_value(FLAT, 0, NAN)),
                               r"not finite"),
    "fit_plane nan": (lambda: planes.fit_plane(with_value(FLAT, 0, NAN)),
                      r"NaN or infinite coordinates"),
    "fit_plane inf": (lambda: planes.fit_plane(with_value(FLAT, 0, INF)),
                      r"NaN or infinite coordinates"),
    "fit_plane no points": (lambda: planes.fit_plane(EMPTY), r"needs at least 3 points, got 0"),
    # correlation
    "tiles nan": (lambda: correlation.tiles(with_value(FLAT_ST, 0, NAN)),
                  r"tile coordinates must be .* finite values.* 1 not finite"),
    "tiles no points": (lambda: correlation.tiles(np.zeros((0, 2))), r"non-empty"),
    "tiles size 0": (lambda: correlation.tiles(FLAT_ST, 0.0),
                     r"tile size must be finite and > 0 mm, got 0.0"),
    "tiles size nan": (lambda: correlation.tiles(FLAT_ST, NAN), r"tile size must be finite"),
    "tiles size inf": (lambda: correlation.tiles(FLAT_ST, INF), r"tile size must be finite"),
    "noise_correlation coords inf": (
        lambda: correlation.noise_correlation(np.ones((400, 1)), np.ones(400),
                                              with_value(FLAT_ST, 3, INF)), r"not finite"),
    "tile_correlation size nan": (lambda: artefacts.tile_correlation(NAN),
                                  r"tile size must be finite"),
    "tile_correlation size 0": (lambda: artefacts.tile_correlation(0.0),
                                r"tile size must be finite and > 0"),
    # verdict
    "verdict unknown decision": (lambda: verdict.verdict(["pass", "nan"]),
                                 r"unknown decision 'nan' \(known: pass, fail"),
    # VDI/VDE 2634-2
    "quantity k nan": (lambda: vdi2634.quantity("PF", 0.01, 0.001, 0.02, k=NAN),
                       r"PF: the coverage factor k must be finite and > 0, got nan"),
    "quantity k inf": (lambda: vdi2634.quantity("PF", 0.01, 0.001, 0.02, k=INF),
                       r"coverage factor k must be finite"),
    "quantity k 0": (lambda: vdi2634.quantity("PS", 0.01, 0.001, 0.02, k=0.0),
                     r"PS: the coverage factor k must be finite and > 0, got 0.0"),
    "quantity u negative": (lambda: vdi2634.quantity("F", 0.01, -0.001, 0.02),
                            r"F: the standard uncertainty u must be >= 0 mm"),
    "probing_errors point inf": (lambda: vdi2634.probing_errors(with_value(CAP, 9, INF), SIG),
                                 r"sphere: 1 of 300 points are not finite"),
    "probing_errors no points": (lambda: vdi2634.probing_errors(EMPTY), r"0 points"),
    "probing_errors every sigma 0": (lambda: vdi2634.probing_errors(CAP, np.zeros(300)),
                                     r"every sigma is 0"),
    "probing_errors k 0": (lambda: vdi2634.probing_errors(CAP, SIG, k=0.0),
                           r"coverage factor k must be finite and > 0"),
    "probing_errors correlation nan": (
        lambda: vdi2634.probing_errors(CAP, SIG, correlation=NAN),
        r"noise-correlation factor must be finite and > 0"),
    "probing_errors u_table nan": (lambda: vdi2634.probing_errors(CAP, SIG, u_table=NAN),
                                   r"sphere: the table's standard uncertainty u_table"),
    "probing_errors drop nan": (lambda: vdi2634.probing_errors(CAP, SIG, drop_fraction=NAN),
                                r"drop_fraction must be in \[0, 0.5\), got nan"),
    "sphere_spacing point nan": (
        lambda: vdi2634.sphere_spacing_error(CAP, with_value(CAP_B, 0, NAN)),
        r"ball bar, ball b: 1 of 300 points are not finite"),
    "sphere_spacing u_table inf": (
        lambda: vdi2634.sphere_spacing_error(CAP, CAP_B, u_table=INF), r"u_table must be"),
    "sphere_spacing no points": (lambda: vdi2634.sphere_spacing_error(EMPTY, CAP_B),
                                 r"ball bar, ball a: 0 points"),
    "flatness_error point nan": (lambda: vdi2634.flatness_error(with_value(FLAT, 0, NAN)),
                                 r"flat: 1 of 400 points are not finite"),
    "flatness_error no points": (lambda: vdi2634.flatness_error(EMPTY), r"flat: 0 points"),
    "flatness_error correlation 0": (lambda: vdi2634.flatness_error(FLAT, correlation=0.0),
                                     r"noise-correlation factor must be > 0"),
    "flatness_error k inf": (lambda: vdi2634.flatness_error(FLAT, k=INF),
                             r"F: the coverage factor k must be finite"),
    # searches
    "ransac_sphere point nan": (lambda: ransac.ransac_sphere(with_value(CAP, 0, NAN), 12.7),
                                r"sphere search: 1 of 300 points are not finite"),
    "ransac_sphere radius nan": (lambda: ransac.ransac_sphere(CAP, NAN),
                                 r"sphere search: the radius must be finite and > 0 mm"),
    "ransac_sphere radius inf": (lambda: ransac.ransac_sphere(CAP, INF),
                                 r"the radius must be finite and > 0 mm, got inf"),
    "ransac_sphere radius 0": (lambda: ransac.ransac_sphere(CAP, 0.0),
                               r"the radius must be finite and > 0 mm, got 0.0"),
    "ransac_sphere threshold 0": (lambda: ransac.ransac_sphere(CAP, 12.7, threshold_mm=0.0),
                                  r"the threshold must be finite and > 0 mm"),
    "ransac_sphere no points": (lambda: ransac.ransac_sphere(EMPTY), r"0 points"),
    "ransac_plane threshold nan": (lambda: ransac.ransac_plane(FLAT, NAN),
                                   r"plane search: the threshold must be finite"),
    "ransac_plane threshold inf": (lambda: ransac.ransac_plane(FLAT, INF),
                                   r"plane search: the threshold must be finite"),
    "ransac_plane point inf": (lambda: ransac.ransac_plane(with_value(FLAT, 0, INF)),
                               r"plane search: 1 of 400 points are not finite"),
    "detect_blocks voxel 0": (lambda: detect.detect_blocks(FLAT, {1: 10.0}, voxel_mm=0.0),
                              r"finding blocks: the voxel size must be finite and > 0 mm"),
    "detect_blocks height nan": (lambda: detect.detect_blocks(FLAT, {3: NAN}),
                                 r"the nominal height of block 3 must be finite and > 0 mm"),
    "detect_blocks no points": (lambda: detect.detect_blocks(EMPTY, {1: 10.0}),
                                r"too few points"),
    # artefacts
    "point_sigma inf": (lambda: artefacts.point_sigma(
        AnnotatedCloud(CAP, {"sigma_model_um": with_value(np.full(300, 5.0), 3, INF)}),
        np.arange(300), CAP_NORMALS, artefacts.Options()),
        r"sigma_model_um holds 1 values that are 0, negative or infinite"),
    "point_sigma every sigma 0": (lambda: artefacts.point_sigma(
        AnnotatedCloud(CAP, {"sigma_model_um": np.zeros(300)}), np.arange(300), CAP_NORMALS,
        artefacts.Options()), r"holds 300 values that are 0"),
    "table_uncertainty area nan": (
        lambda: artefacts.table_uncertainty(AnnotatedCloud(FLAT, {}), np.arange(5), NAN),
        r"area must be finite and >= 0 mm\^2, got nan"),
    "table_uncertainty no points": (
        lambda: artefacts.table_uncertainty(AnnotatedCloud(FLAT, {}), np.arange(0), 10.0),
        r"the artefact has no points"),
    "table_uncertainty sigma inf": (
        lambda: artefacts.table_uncertainty(
            AnnotatedCloud(FLAT, {"sigma_calibration_um": with_value(np.full(400, 3.0), 1, INF)}),
            np.arange(5), 10.0), r"sigma_calibration_um holds negative or infinite"),
}


@pytest.mark.parametrize("call, match", RAISES.values(), ids=list(RAISES))
def test_bad_number_raises_a_clear_scanqa_error(call, match):
    with pytest.raises(ScanQAError, match=match):
        call()


def test_an_unknown_decision_is_still_a_value_error():
    """MethodError is a ScanQAError and, as before, a ValueError."""
    with pytest.raises(ValueError):
        verdict.verdict(["maybe"])
    assert issubclass(MethodError, ScanQAError) and issubclass(InputError, ScanQAError)


# ------------------------------------------------------------------ NaN out, documented

def test_decide_not_evaluated_for_nan_and_inf_and_by_hand_for_zero():
    for args in ((NAN, 0.1, 0.5), (INF, 0.1, 0.5), (0.1, NAN, 0.5), (0.1, INF, 0.5),
                 (0.1, 0.1, NAN), (0.1, 0.1, INF)):
        assert verdict.decide(*args) == "not evaluated", args
    # U = 0: the plain comparison (ISO 14253-1 with no uncertainty zone)
    assert verdict.decide(0.5, 0.0, 0.5) == "pass" and verdict.decide(0.51, 0.0, 0.5) == "fail"
    # limit 0: |0.1| lies within 0 +- 0.1, neither proven
    assert verdict.decide(0.1, 0.1, 0.0) == "undecided"
    assert verdict.verdict([])["verdict"] == "NOT EVALUATED"


def test_quantity_not_evaluated_says_which_input_is_missing():
    assert vdi2634.quantity("PF", NAN, 0.001, 0.02).note == "not measured"
    assert vdi2634.quantity("PF", INF, 0.001, 0.02).decision == "not evaluated"
    assert vdi2634.quantity("PF", 0.01, 0.001, NAN).note == "no MPE for it in the spec"
    for kw in ({"u": NAN}, {"u": INF}):
        q = vdi2634.quantity("PS", 0.01, mpe=0.02, **kw)
        assert q.decision == "not evaluated" and q.note.startswith("its uncertainty is not")
    q = vdi2634.quantity("SD", 0.01, 0.001, 0.02, bias=NAN, decide_with="total")
    assert q.decision == "not evaluated" and math.isnan(q.expanded)
    # u = 0 is an exact artefact, not a bad input: U_test = 0, |0.01| <= 0.02
    assert vdi2634.quantity("PF", 0.01, 0.0, 0.02).decision == "pass"


@pytest.mark.parametrize("sigma, n_dropped", [
    ([0.01, NAN, 0.01], 0), ([0.01, INF, 0.01], 0), (np.zeros(10), 0), ([], 0), ([0.01], 0),
    (np.full(10, 0.01), 9)])
def test_predicted_range_is_nan_without_a_prediction(sigma, n_dropped):
    predicted, u = vdi2634.predicted_range(sigma, n_dropped)
    assert math.isnan(predicted) and math.isnan(u)


def test_normal_sigma_is_nan_where_a_point_or_sigma_is():
    sig = vdi2634.normal_sigma(CAP[:3], [0.01, NAN, 0.01], CAP_NORMALS[:3])
    assert math.isnan(sig[1]) and np.isfinite(sig[[0, 2]]).all()
    sig = vdi2634.normal_sigma(with_value(CAP[:3], 3, INF), 0.01, CAP_NORMALS[:3])
    assert math.isnan(sig[1]) and np.isfinite(sig[[0, 2]]).all()
    assert math.isnan(vdi2634.normal_sigma(np.zeros((1, 3)), 0.01, [0, 0, 1.0])[0])
    assert vdi2634.normal_sigma(EMPTY, 0.01, EMPTY).shape == (0,)


def test_sight_noise_bias_nan_for_nan_sigma_zero_for_zero_sigma():
    assert np.isnan(sphere.sight_noise_bias(CAP, CENTRE, 12.7, with_value(SIG, 0, NAN))).all()
    assert np.isnan(sphere.sight_noise_bias(CAP, CENTRE, 12.7, with_value(SIG, 0, INF))).all()
    # no noise, no bias (the bias is second order in sigma): exactly 0
    np.testing.assert_array_equal(sphere.sight_noise_bias(CAP, CENTRE, 12.7, 0.0), 0.0)


def test_noise_correlation_nan_for_nan_or_zero_residuals():
    design = np.column_stack([np.ones(400), FLAT_ST])
    res = RNG.normal(size=400)
    for bad in (with_value(res, 7, NAN), with_value(res, 7, INF), np.zeros(400)):
        kappa, n_tiles = correlation.noise_correlation(design, bad, FLAT_ST)
        assert np.isnan(kappa).all() and n_tiles > correlation.MIN_TILES


def test_flatness_error_without_a_prediction_has_nan_u():
    """Every sigma 0: F is measured, its u and prediction NaN, nothing decided."""
    f = vdi2634.flatness_error(FLAT, np.zeros(400), SPEC).f
    assert math.isfinite(f.value) and math.isnan(f.u) and math.isnan(f.predicted)
    assert f.decision == "not evaluated"


def test_a_nan_sigma_takes_the_rms_residual():
    """Module notes of vdi2634: a missing sigma (NaN or inf) is the RMS residual."""
    rms = math.sqrt(float(np.mean(planes.fit_plane(FLAT).residuals ** 2)))
    sig = np.full(400, 0.003)
    with_nan = vdi2634.flatness_error(FLAT, with_value(sig, 0, NAN), drop_fraction=0.0).f
    by_hand = vdi2634.flatness_error(FLAT, with_value(sig, 0, rms / _cos(FLAT[0])),
                                     drop_fraction=0.0).f
    assert with_nan.predicted == pytest.approx(by_hand.predicted, rel=1e-9)


def _cos(point) -> float:
    """|cos| between the line of sight to ``point`` and the flat's normal [-]."""
    n = planes.fit_plane(FLAT).normal
    return abs(float(point @ n) / float(np.linalg.norm(point)))


def test_plane_design_nan_row_for_a_nan_point():
    fit = planes.fit_plane(FLAT)
    design = planes.plane_design(with_value(FLAT[:3], 3, NAN), fit)
    assert np.isnan(design[1, 1:]).all() and np.isfinite(design[[0, 2]]).all()
    assert planes.plane_design(EMPTY, fit).shape == (0, 3)


def test_point_sigma_keeps_nan_and_oblique_factor_is_one_where_it_cannot_be_formed():
    """A NaN sigma stays NaN (the fits replace it by the RMS residual); a modulation that
    is NaN, inf or 0 gives the documented factor 1 at that point, never a number from it."""
    cloud = AnnotatedCloud(CAP, {"sigma_model_um": with_value(np.full(300, 5.0), 3, NAN)})
    sig = artefacts.point_sigma(cloud, np.arange(300), CAP_NORMALS,
                                artefacts.Options(oblique="none"))
    assert math.isnan(sig[3]) and np.allclose(np.delete(sig, 3), 0.005, rtol=1e-15)
    for bad in (NAN, INF, 0.0):
        mod = with_value(np.full(300, 50.0), 3, bad)
        f = artefacts.oblique_factor(AnnotatedCloud(CAP, {"modulation_dn": mod}),
                                     np.arange(300), CAP_NORMALS, "modulation")
        assert f[3] == 1.0, bad


def test_paper_ratio_nan_without_a_printed_pair():
    assert math.isnan(paper.paper_ratio(0)) and math.isnan(paper.paper_ratio(6))


# ------------------------------------------------------------------ gauge blocks

N_BLOCK = 2000
BLOCK_XYZ = np.column_stack([RNG.uniform(0, 20, (N_BLOCK, 2)),
                             450.0 + 0.01 * RNG.normal(size=N_BLOCK)])
BLOCK = BlockSpec(1, 10.0, (0.0, 20.0, 0.0, 20.0))


def _block(xyz=BLOCK_XYZ, sigma=10.0, **kw):
    attrs = {"sigma_model_um": np.broadcast_to(np.asarray(sigma, float), (len(xyz),))}
    return blocks.analyse_block(xyz, attrs, BLOCK, kw.pop("margin", 1.0),
                                kw.pop("outlier_k", None), **kw)


def test_block_leaves_a_nan_or_inf_point_out():
    """The same numbers as the cloud without that point."""
    without = _block(np.delete(BLOCK_XYZ, 5, axis=0))
    for bad in (NAN, INF):
        res = _block(with_value(BLOCK_XYZ, 5 * 3 + 2, bad))
        assert res.n_points == without.n_points
        assert res.measured_std_um == pytest.approx(without.measured_std_um, rel=1e-12)


@pytest.mark.parametrize("sigma", [NAN, INF, 0.0, -1.0])
def test_block_with_no_usable_sigma_predicts_nan(sigma):
    res = _block(sigma=sigma)
    assert math.isnan(res.predicted_std_um) and math.isnan(res.ratio)
    assert math.isfinite(res.measured_std_um)


def test_block_with_no_points_has_nan_statistics():
    res = _block(np.full((10, 3), NAN))
    assert res.status == "no_points" and "no points inside its region" in res.message
    assert math.isnan(res.measured_std_um) and math.isnan(res.predicted_std_um)


@pytest.mark.parametrize("kw, match", [
    ({"margin": NAN}, r"edge margin must be >= 0 mm, got nan"),
    ({"margin": INF}, r"edge margin must be >= 0 mm, got inf"),
    ({"outlier_k": NAN}, r"outlier rejection K must be > 0"),
    ({"outlier_k": 0.0}, r"outlier rejection K must be > 0"),
    ({"z_window": 0.0}, r"height window must be > 0 mm"),
    ({"tile_mm": NAN}, r"tile size must be finite and > 0 mm, got nan"),
])
def test_block_refuses_a_bad_setting(kw, match):
    with pytest.raises(InputError, match=match):
        _block(**kw)


def test_step_refuses_bad_k_and_leaves_nan_tolerance_undecided():
    a = _block()
    b = blocks.analyse_block(BLOCK_XYZ + np.array([0, 0, 5.0]),
                             {"sigma_model_um": np.full(N_BLOCK, 10.0)},
                             BlockSpec(2, 5.0, (0.0, 20.0, 0.0, 20.0)), 1.0, None)
    for k in (NAN, INF, 0.0):
        with pytest.raises(InputError, match=r"k must be a number > 0"):
            blocks.step_between(a, b, k, 10.0)
    assert blocks.step_between(a, b, 2.0, NAN).decision == "not evaluated"


def test_local_std_nan_around_a_nan_residual():
    res = np.zeros(N_BLOCK)
    res[3] = NAN
    out = blocks.local_std(BLOCK_XYZ, res, np.zeros(N_BLOCK, int))
    assert math.isnan(out[3])
    assert np.nanmax(out) == 0.0  # the other residuals are exactly 0
    assert blocks.local_std(EMPTY, np.zeros(0), np.zeros(0, int)).shape == (0,)


def test_check_sigmas_refuses_zero_and_inf_and_lets_nan_mean_no_prediction():
    for bad in (0.0, INF, -2.0):
        with pytest.raises(InputError, match=r"0, negative or infinite"):
            blocks.check_sigmas({"sigma_model_um": with_value(np.full(5, 10.0), 2, bad)})
    blocks.check_sigmas({"sigma_model_um": with_value(np.full(5, 10.0), 2, NAN)})


# ------------------------------------------------------------------ compare

def _scan(xyz, sigma):
    return AnnotatedCloud(xyz, {"sigma_total_um": np.broadcast_to(
        np.asarray(sigma, float), (len(xyz),)).copy()})


def test_compare_refuses_zero_or_inf_sigma_and_bad_k():
    ref = AnnotatedCloud(BLOCK_XYZ, {})
    for bad in (0.0, INF, -1.0):
        with pytest.raises(InputError, match=r"sigma_total_um holds 1 values that are 0"):
            compare.compare_to_cloud(_scan(BLOCK_XYZ, with_value(np.full(N_BLOCK, 10.0), 4,
                                                                 bad)), ref)
    for k in (NAN, INF, 0.0):
        with pytest.raises(InputError, match=r"k must be > 0"):
            compare.compare_to_cloud(_scan(BLOCK_XYZ, 10.0), ref, k=k)
    with pytest.raises(InputError, match=r"no point of the cloud lies within reach"):
        compare.compare_to_cloud(_scan(EMPTY, 10.0), ref)


def test_compare_leaves_a_nan_point_and_a_nan_sigma_uncompared():
    ref = AnnotatedCloud(BLOCK_XYZ, {})
    sig = with_value(np.full(N_BLOCK, 10.0), 4, NAN)
    xyz = with_value(BLOCK_XYZ, 7 * 3, NAN)
    out = compare.compare_to_cloud(_scan(xyz, sig), ref, max_roughness_mm=1.0).cloud
    dev = np.asarray(out.attributes["deviation_um"])
    significance = np.asarray(out.attributes["significance"])
    assert math.isnan(dev[7]) and math.isnan(significance[7])
    assert math.isfinite(dev[4]) and math.isnan(significance[4])  # compared, not judged
    assert np.isfinite(significance[[0, 1, 2]]).all()


# ------------------------------------------------------------------ budget

def test_welch_satterthwaite_nan_contribution_gives_nan():
    assert math.isnan(budget.welch_satterthwaite([(NAN, 10.0), (1.0, 5.0)]))
    assert math.isnan(budget.welch_satterthwaite([(INF, 10.0), (1.0, 5.0)]))
    # documented: inf when every contribution with a finite dof is zero
    assert budget.welch_satterthwaite([(0.0, 10.0), (0.0, 5.0)]) == INF


def test_coverage_factor_nan_for_zero_or_negative_dof():
    for nu in (0.0, -3.0):
        assert math.isnan(budget.coverage_factor(nu))
    assert math.isnan(budget.coverage_factor(10.0, NAN))
    for p in (INF, 1.0, -0.5):  # not a probability
        with pytest.raises(ScanQAError, match="coverage probability"):
            budget.coverage_factor(10.0, p)
    # infinite dof is the normal quantile: 1.959964 at 95 % (GUM G.3)
    assert budget.coverage_factor(INF) == pytest.approx(1.959964, abs=1e-6)




def test_coverage_factor_of_nan_dof_is_not_the_normal_quantile():
    assert math.isnan(budget.coverage_factor(NAN))


def test_welch_satterthwaite_of_a_nan_dof_is_nan():
    assert math.isnan(budget.welch_satterthwaite([(1.0, NAN), (1.0, 5.0)]))


def test_coverage_factor_of_zero_coverage_is_refused():
    with pytest.raises(ScanQAError):
        budget.coverage_factor(10.0, 0.0)
