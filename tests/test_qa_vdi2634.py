"""VDI/VDE 2634-2 quantities: closed loops on simulated artefacts, Monte Carlo checks of
the predictions, and ISO 14253-1 decisions computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.stats import norm

from scanqa.errors import InputError
from scanqa.io.spec import BallBarCertificate, FlatCertificate, Mpe, Spec, SphereCertificate
from scanqa.qa.sphere import sight_noise_bias
from scanqa.qa.vdi2634 import (
    decide,
    flatness_error,
    normal_sigma,
    predicted_range,
    probing_errors,
    quantity,
    sphere_spacing_error,
)

from .qa_artefacts import along_sight, flat_patch, visible_cap

CENTRE = np.array([15.0, 10.0, 480.0])
DIAMETER = 25.4
SPEC = Spec("test", {"PF": Mpe(250.0), "PS": Mpe(10.0), "SD": Mpe(20.0, 1000.0), "F": Mpe(300.0)},
            sphere=SphereCertificate(DIAMETER, 1.0, 2.0, form_um=1.0),
            ball_bar=BallBarCertificate(300.0, 2.0, 2.0),
            flat=FlatCertificate(2.0))


@pytest.mark.parametrize("value, expanded, mpe, expected", [
    (0.375, 0.125, 0.5, "pass"),        # |E| = MPE - U: conformance proven (boundary)
    (-0.375, 0.125, 0.5, "pass"),       # the sign does not matter
    (0.5, 0.125, 0.5, "undecided"),     # inside the uncertainty zone
    (0.625, 0.125, 0.5, "undecided"),   # |E| = MPE + U: not yet proven non-conforming
    (0.6250001, 0.125, 0.5, "fail"),
    (0.0, 0.5, 0.5, "pass"),            # U = MPE: only E = 0 passes
    (0.0625, 0.5, 0.5, "undecided"),
    (math.nan, 0.125, 0.5, "not evaluated"),
    (0.25, math.nan, 0.5, "not evaluated"),
    (0.25, 0.125, math.nan, "not evaluated"),
])
def test_decisions_at_the_boundaries(value, expanded, mpe, expected):
    assert decide(value, expanded, mpe) == expected


def test_quantity_says_why_it_is_not_evaluated():
    assert quantity("PF", 0.01, 0.001, math.nan).note == "no MPE for it in the spec"
    assert quantity("PS", math.nan, math.nan, 0.01).note == "not measured"
    q = quantity("SD", 0.3125, 0.0625, 0.5, bias=-0.0625, decide_with="total")
    assert q.expanded == 0.1875 and q.decision == "pass"  # U = k u + |bias| = 0.125 + 0.0625
    assert quantity("SD", 0.3125, 0.0625, 0.5, bias=0.0625001,
                    decide_with="total").decision == "undecided"
    assert q.row()["U_um"] == 187.5 and q.row()["name"] == "sphere-spacing error"


def test_decision_uses_the_test_uncertainty_by_default():
    """The scanner's own noise is what the test measures: the default decision takes
    only the artefact's part U_test = k u_artefact (here 2 x 0.03125 = 0.0625 mm)."""
    q = quantity("SD", 0.4375, 0.0625, 0.5, bias=0.01, u_artefact=0.03125)
    assert q.expanded_test == 0.0625 and q.decision == "pass"   # 0.4375 <= 0.5 - 0.0625
    assert q.expanded == 0.135                                    # U = 0.125 + 0.01
    assert quantity("SD", 0.4375, 0.0625, 0.5, u_artefact=0.03125,
                    decide_with="total").decision == "undecided"  # 0.4375 > 0.5 - 0.125
    assert quantity("SD", 0.5625001, 0.0625, 0.5, u_artefact=0.03125).decision == "fail"
    assert_allclose(q.u_points, math.sqrt(0.0625**2 - 0.03125**2))
    assert q.row()["U_test_um"] == 62.5 and q.row()["decided_with"] == "test"
    with pytest.raises(InputError, match="decide_with must be one of test, total"):
        quantity("PF", 0.01, 0.001, 0.1, decide_with="both")


def test_predicted_range_of_equal_sigmas_is_the_central_997_percent():
    """10^5 points, 300 dropped: the kept range is close to the two-sided 99.7 % range of
    a Gaussian, 2 x 2.968 sigma (the tail count is Gamma(301), so within ~0.5 %)."""
    pred, u = predicted_range(np.full(100_000, 0.01), 300)
    assert_allclose(pred, 2 * norm.ppf(1 - 0.0015) * 0.01, rtol=5e-3)
    assert 2 * norm.ppf(1 - 0.0015) == pytest.approx(5.936, abs=1e-3)
    assert u < 0.01 * pred


@pytest.mark.parametrize("n, drop", [(1500, 4), (1500, 0), (400, 1)])
def test_predicted_range_matches_monte_carlo(n, drop):
    """Mean and std of the kept range over 3000 draws of Gaussian residuals with unequal
    sigmas: the prediction within 2 %, its std within 10 %."""
    rng = np.random.default_rng(n + drop)
    sigma = rng.uniform(0.01, 0.03, n)
    r = rng.normal(size=(3000, n)) * sigma
    if drop:
        keep = np.argpartition(-np.abs(r), drop, axis=1)[:, drop:]
        r = np.take_along_axis(r, keep, axis=1)
    ranges = np.ptp(r, axis=1)
    pred, u = predicted_range(sigma, drop)
    assert_allclose(pred, ranges.mean(), rtol=0.02)
    assert_allclose(u, ranges.std(), rtol=0.10)


def test_predicted_range_without_sigmas_is_nan():
    assert all(math.isnan(v) for v in predicted_range([0.01, np.nan, 0.02], 0))
    assert all(math.isnan(v) for v in predicted_range([0.01], 0))


def test_normal_sigma_by_hand():
    pts = np.array([[0, 0, 100.0], [0, 0, 200.0]])
    normals = np.array([[0, 0, -1.0], [0, math.sin(math.pi / 3), -0.5]])
    assert_allclose(normal_sigma(pts, [0.02, 0.04], normals), [0.02, 0.02])  # cos 60 = 0.5
    assert_allclose(normal_sigma(pts, 0.03, normals, view_origin=None), [0.03, 0.03])


def sphere_scan(rng, n=2000, sigma_range=(0.01, 0.03)):
    p, _ = visible_cap(rng, CENTRE, DIAMETER / 2, n)
    sigma = rng.uniform(*sigma_range, n)
    return along_sight(rng, p, sigma), sigma


def test_probing_errors_closed_loop():
    """Simulated sphere scans (noise along the line of sight, exact truth): PF within 20 %
    of its prediction in each scan and on average within 3 standard errors (from PF's
    predicted u), PS within U in 9 scans of 10 or more, the 0.3 % rule applied, the
    minimum zone inside the least-squares range."""
    rng = np.random.default_rng(1)
    ratios, rel_u, ps_in = [], [], 0
    for _ in range(10):
        pts, sigma = sphere_scan(rng)
        t = probing_errors(pts, sigma, SPEC)
        ratios.append(t.pf.value / t.pf.predicted)
        rel_u.append(t.pf.u / t.pf.predicted)
        ps_in += abs(t.ps.value) <= t.ps.expanded
        assert t.pf.n_dropped == 6 and t.kept.sum() == 1994 and t.fit.n_points == 1994
        assert t.zone.width <= t.pf.value
        assert t.pf.decision == "pass" and t.ps.decision == "pass"
    assert np.all(np.abs(np.array(ratios) - 1) < 0.2), ratios
    assert abs(np.mean(ratios) - 1) < 3 * np.mean(rel_u) / np.sqrt(len(ratios)), ratios
    assert ps_in >= 9


def test_ps_uncertainty_and_bias_by_parts():
    rng = np.random.default_rng(2)
    pts, sigma = sphere_scan(rng)
    t = probing_errors(pts, sigma, SPEC)
    u_cert = 1e-3 * 1.0 / 2.0
    assert_allclose(t.ps.u, math.hypot(2 * t.fit.u_radius, u_cert))
    bias = sight_noise_bias(pts[t.kept], t.fit.centre, t.fit.radius, sigma[t.kept])
    assert_allclose(t.ps.bias, 2 * bias[3])
    assert t.ps.bias < 0 and abs(t.ps.bias) < t.ps.u  # small against u at 2000 points
    assert_allclose(t.ps.expanded, 2 * t.ps.u + abs(t.ps.bias))
    # PF's u holds the certified form (1 um, rectangular) beside the sampling term
    assert t.pf.u > 1e-3 / math.sqrt(3)


def test_the_03_percent_rule_removes_gross_outliers():
    rng = np.random.default_rng(3)
    pts, sigma = sphere_scan(rng)
    radial = (pts[:5] - CENTRE) / np.linalg.norm(pts[:5] - CENTRE, axis=1, keepdims=True)
    pts[:5] += 0.5 * radial  # five points 0.5 mm off the surface
    kept = probing_errors(pts, sigma, SPEC)
    assert not kept.kept[:5].any() and kept.pf.value < 0.2
    every = probing_errors(pts, sigma, SPEC, drop_fraction=0.0)
    assert every.pf.n_dropped == 0 and every.pf.value > 0.5
    assert every.pf.decision == "fail"  # 0.5 mm against an MPE of 250 um
    with pytest.raises(InputError, match=r"drop_fraction must be in \[0, 0.5\)"):
        probing_errors(pts, sigma, SPEC, drop_fraction=0.6)


def test_without_certificate_or_mpe_nothing_is_decided():
    pts, sigma = sphere_scan(np.random.default_rng(4), n=500)
    t = probing_errors(pts, sigma, Spec("pf only", {"PF": Mpe(250.0)}))
    assert t.ps.decision == "not evaluated"
    assert t.ps.note == "no sphere certificate (calibrated diameter) in the spec"
    bare = probing_errors(pts)
    assert bare.pf.decision == "not evaluated" and math.isfinite(bare.pf.value)
    assert math.isnan(bare.pf.predicted) and "no per-point sigma" in bare.pf.note


def test_missing_sigmas_are_replaced_by_the_rms_residual():
    pts, sigma = sphere_scan(np.random.default_rng(9), n=800)
    sigma[::10] = np.nan
    t = probing_errors(pts, sigma, SPEC)
    assert np.isfinite([t.pf.value, t.pf.u, t.pf.predicted, t.ps.u, t.ps.bias]).all()
    assert t.fit.sigma_source == "points"


def test_sphere_with_too_few_points_or_a_small_cap_is_refused():
    rng = np.random.default_rng(5)
    pts, sigma = sphere_scan(rng, n=15)
    with pytest.raises(InputError, match="sphere: 15 points, a fit needs at least 20"):
        probing_errors(pts, sigma, SPEC)
    cap, _ = visible_cap(rng, CENTRE, DIAMETER / 2, 2000, max_incidence_deg=30.0)
    with pytest.raises(InputError, match="of a hemisphere"):
        probing_errors(cap, 0.02, SPEC)


def test_sphere_spacing_error_closed_loop():
    rng = np.random.default_rng(6)
    direction = np.array([1.0, 0.2, 0.1]) / np.linalg.norm([1.0, 0.2, 0.1])
    ca, cb = CENTRE - 150 * direction, CENTRE + 150 * direction  # 300 mm apart
    inside = 0
    for _ in range(10):
        pa, _ = visible_cap(rng, ca, DIAMETER / 2, 1500)
        pb, _ = visible_cap(rng, cb, DIAMETER / 2, 1500)
        sa, sb = rng.uniform(0.01, 0.03, 1500), rng.uniform(0.01, 0.03, 1500)
        t = sphere_spacing_error(along_sight(rng, pb, sb), along_sight(rng, pa, sa), sb, sa,
                                 SPEC)
        inside += abs(t.sd.value) <= t.sd.expanded
        assert t.sd.mpe == pytest.approx(0.0203)  # 20 um + 300 mm / 1000
        assert t.sd.length == 300.0 and t.sd.n_points == 3000
        assert_allclose(t.sd.u, math.hypot(t.bar.u_distance, 1e-3))
    assert inside >= 9
    bare = sphere_spacing_error(pa, pb)
    assert bare.sd.decision == "not evaluated" and "no ball-bar certificate" in bare.sd.note


def test_flatness_error_closed_loop():
    rng = np.random.default_rng(7)
    normal = np.array([0.05, 0.1, -1.0])
    ratios = []
    for _ in range(5):
        p, _ = flat_patch(rng, [0.0, 0.0, 500.0], normal, 60.0, 4000)
        sigma = rng.uniform(0.01, 0.03, len(p))
        t = flatness_error(along_sight(rng, p, sigma), sigma, SPEC)
        ratios.append(t.f.value / t.f.predicted)
        assert t.f.n_dropped == 12 and t.zone.width <= t.f.value
        assert t.f.u > 2e-3 / math.sqrt(3)  # the certified flatness enters u
    assert np.all(np.abs(np.array(ratios) - 1) < 0.2), ratios
    with pytest.raises(InputError, match="noise-correlation factor must be > 0"):
        flatness_error(p, sigma, SPEC, correlation=0.0)


def test_correlation_factor_widens_the_form_uncertainty():
    rng = np.random.default_rng(8)
    p, _ = flat_patch(rng, [0.0, 0.0, 500.0], [0, 0, -1.0], 60.0, 3000)
    q = along_sight(rng, p, 0.02)
    one = flatness_error(q, 0.02)
    four = flatness_error(q, 0.02, correlation=4.0)
    assert_allclose(four.f.u, 2 * one.f.u)  # no certificate: u = sqrt(kappa) u_s
    assert four.f.value == one.f.value and four.f.predicted == one.f.predicted
