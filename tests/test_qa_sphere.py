"""Sphere fits against exact truth: visible caps with known noise along the line of sight."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.optimize import minimize

from scanqa.errors import InputError
from scanqa.qa.sphere import (
    algebraic_sphere,
    cap_coverage,
    fit_sphere,
    minimum_zone_sphere,
    sight_noise_bias,
)

from .qa_artefacts import along_sight, rigid, sight_cosine, visible_cap

CENTRE = np.array([20.0, -10.0, 480.0])
RADIUS = 12.7


def test_algebraic_fit_is_exact_on_noiseless_points():
    p, _ = visible_cap(np.random.default_rng(0), CENTRE, RADIUS, 50)
    c, r = algebraic_sphere(p)
    assert_allclose(c, CENTRE, atol=1e-9)  # exact data, exact equation
    assert_allclose(r, RADIUS, atol=1e-9)


def test_fit_recovers_truth_within_its_uncertainty():
    rng = np.random.default_rng(1)
    p, nrm = visible_cap(rng, CENTRE, RADIUS, 3000)
    sigma = rng.uniform(0.01, 0.03, len(p))  # along the line of sight [mm]
    fit = fit_sphere(along_sight(rng, p, sigma), sigma * sight_cosine(p, nrm))
    assert fit.sigma_source == "points"
    z = np.append(fit.centre - CENTRE, fit.radius - RADIUS) / np.sqrt(np.diag(fit.covariance))
    assert np.all(np.abs(z) < 4), z  # within 4 standard uncertainties of the truth
    assert fit.u_radius < 2e-3 and fit.iterations < 10
    assert 0.55 < fit.coverage <= 1.0 and 55 < fit.half_angle_deg < 90


def test_covariance_is_honest_by_monte_carlo():
    """The scatter of centre and radius over 500 noisy scans of the same cap matches the
    covariance predicted from the per-point sigmas within 10 %."""
    rng = np.random.default_rng(2)
    p, nrm = visible_cap(rng, CENTRE, RADIUS, 400)
    sigma = rng.uniform(0.01, 0.04, len(p))
    radial = sigma * sight_cosine(p, nrm)
    est, pred = [], None
    for _ in range(500):
        fit = fit_sphere(along_sight(rng, p, sigma), radial)
        est.append(np.append(fit.centre, fit.radius))
        pred = np.sqrt(np.diag(fit.covariance))
    ratio = np.std(est, axis=0, ddof=1) / pred
    assert_allclose(ratio, 1.0, atol=0.10)  # 500 draws: std of a std ~3 %
    bias = (np.mean(est, axis=0) - np.append(CENTRE, RADIUS)) / (pred / np.sqrt(len(est)))
    assert np.all(np.abs(bias) < 4), bias  # no bias beyond 4 standard errors of the mean


def test_covariance_from_residuals_without_sigmas():
    rng = np.random.default_rng(3)
    p, nrm = visible_cap(rng, CENTRE, RADIUS, 2000)
    radial_sigma = 0.02
    q = p + nrm * rng.normal(0, radial_sigma, (len(p), 1))  # radial noise, known sigma
    a = fit_sphere(q)
    b = fit_sphere(q, radial_sigma)
    assert a.sigma_source == "residuals"
    # s^2 (J^T J)^-1 with s ~ sigma: the two agree within the scatter of s (~2 %)
    assert_allclose(np.sqrt(np.diag(a.covariance)), np.sqrt(np.diag(b.covariance)), rtol=0.05)


def test_correlation_factor_scales_the_variances():
    rng = np.random.default_rng(4)
    p, nrm = visible_cap(rng, CENTRE, RADIUS, 500)
    q = p + nrm * rng.normal(0, 0.02, (len(p), 1))
    base = fit_sphere(q, 0.02)
    seen = {}

    def factor(points, jac, res):
        seen["shapes"] = (points.shape, jac.shape, res.shape)
        return np.array([4.0, 4.0, 4.0, 9.0])

    scaled = fit_sphere(q, 0.02, correlation=factor)
    assert seen["shapes"] == ((500, 3), (500, 4), (500,))
    assert_allclose(np.diag(scaled.covariance), np.diag(base.covariance) * [4, 4, 4, 9])
    assert_allclose(fit_sphere(q, 0.02, correlation=2.0).covariance, 2 * base.covariance)
    with pytest.raises(InputError, match="noise-correlation factor must be finite and > 0"):
        fit_sphere(q, 0.02, correlation=-1.0)


def test_too_few_points_is_a_clear_error():
    p, _ = visible_cap(np.random.default_rng(5), CENTRE, RADIUS, 12)
    with pytest.raises(InputError, match="sphere: 12 points, a fit needs at least 20"):
        fit_sphere(p)
    with pytest.raises(InputError, match=r"must be an \(n, 3\) array"):
        fit_sphere(p[:, :2])
    bad = p.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="1 of 12 points are not finite"):
        fit_sphere(bad, min_points=5)
    with pytest.raises(InputError, match="sigma must be finite and >= 0"):
        fit_sphere(p, np.full(len(p), np.nan), min_points=5)


def test_a_cap_smaller_than_half_a_hemisphere_is_refused():
    rng = np.random.default_rng(6)
    p, _ = visible_cap(rng, CENTRE, RADIUS, 3000, max_incidence_deg=35.0)
    with pytest.raises(InputError, match=r"cover \d+% of a hemisphere .* needs at least 50%"):
        fit_sphere(p)
    fit = fit_sphere(p, min_coverage=0.1)  # accepted when asked for less
    assert fit.half_angle_deg < 40


def test_a_stripe_is_refused_though_its_half_opening_is_wide():
    """A band across the sphere spans a wide angle but a small solid angle."""
    rng = np.random.default_rng(7)
    p, _ = visible_cap(rng, CENTRE, RADIUS, 20000)
    stripe = p[np.abs(p[:, 1] - CENTRE[1]) < 1.0]
    coverage, half, _ = cap_coverage(stripe, CENTRE)
    assert half > 60 and coverage < 0.3
    with pytest.raises(InputError, match="of a hemisphere"):
        fit_sphere(stripe)


def test_coverage_of_evenly_covered_caps():
    """Fraction of a hemisphere = 1 - cos(half-opening) for an evenly covered cap; the
    ring at the cap's edge counts whole, so the estimate is high by at most one ring."""
    rng = np.random.default_rng(8)
    for half in (30.0, 60.0, 85.0):
        t = rng.uniform(np.cos(np.radians(half)), 1.0, 5000)
        phi = rng.uniform(0, 2 * np.pi, t.size)
        s = np.sqrt(1 - t**2)
        u = np.column_stack([s * np.cos(phi), s * np.sin(phi), t])
        cov, h, axis = cap_coverage(CENTRE + 5.0 * u, CENTRE)
        exact = 1 - np.cos(np.radians(half))
        assert exact <= cov <= exact + 1 / 16 + 1e-12, (half, cov)
        assert abs(h - half) < 1.0 and axis[2] > 0.999


def test_minimum_zone_never_exceeds_the_least_squares_range():
    rng = np.random.default_rng(9)
    for n in (50, 2000):
        p, nrm = visible_cap(rng, CENTRE, RADIUS, n)
        form = 0.01 * np.cos(3 * np.arctan2(nrm[:, 1], nrm[:, 0]))  # a lobed form error
        q = p + nrm * (form + rng.normal(0, 0.01, n))[:, None]
        ls = fit_sphere(q)
        mz = minimum_zone_sphere(q)
        assert mz.width <= np.ptp(ls.residuals) + 1e-12
        d = np.linalg.norm(q - mz.centre, axis=1)
        assert_allclose([d.min(), d.max()], [mz.r_inner, mz.r_outer], atol=1e-12)
        # a local search on the exact width from the result finds nothing thinner
        simplex = mz.centre + np.vstack([np.zeros(3), 1e-3 * np.eye(3)])
        local = minimize(lambda c, q=q: np.ptp(np.linalg.norm(q - c, axis=1)), mz.centre,
                         method="Nelder-Mead", options={"initial_simplex": simplex})
        assert local.fun >= mz.width - 1e-9


@pytest.mark.parametrize("seed", [10, 11])
def test_minimum_zone_equals_brute_force_on_small_sets(seed):
    """Nelder-Mead from 12 starts on the exact width max|p-c| - min|p-c| (another
    algorithm on the exact objective) finds no thinner shell than the LP method."""
    rng = np.random.default_rng(seed)
    p, nrm = visible_cap(rng, CENTRE, RADIUS, 12)
    q = p + nrm * rng.normal(0, 0.03, (len(p), 1))
    mz = minimum_zone_sphere(q)

    def width(c):
        return np.ptp(np.linalg.norm(q - c, axis=1))

    best = min(minimize(width, mz.centre + rng.normal(0, 0.2, 3), method="Nelder-Mead",
                        options={"xatol": 1e-11, "fatol": 1e-13, "maxiter": 20000}).fun
               for _ in range(12))
    assert mz.width <= best + 1e-10
    assert mz.width >= best - 1e-8  # Nelder-Mead stops short by at most this


def test_invariant_under_a_rigid_transform():
    rng = np.random.default_rng(14)
    p, nrm = visible_cap(rng, CENTRE, RADIUS, 600)
    q = p + nrm * rng.normal(0, 0.02, (len(p), 1))
    rot, shift = rigid(rng)
    a, b = fit_sphere(q, 0.02), fit_sphere(q @ rot.T + shift, 0.02)
    assert_allclose(b.centre, rot @ a.centre + shift, atol=1e-9)
    assert_allclose(b.radius, a.radius, atol=1e-10)
    assert_allclose(b.residuals, a.residuals, atol=1e-10)
    assert_allclose(b.covariance[:3, :3], rot @ a.covariance[:3, :3] @ rot.T, atol=1e-14)
    assert_allclose(b.coverage, a.coverage)
    assert_allclose(minimum_zone_sphere(q @ rot.T + shift).width,
                    minimum_zone_sphere(q).width, atol=1e-10)


def test_bias_from_noise_along_the_line_of_sight_is_predicted():
    """Large noise (0.1-0.2 mm) makes the second-order bias of the fit stand out of the
    scatter of 200 scans; its prediction matches the Monte Carlo mean within 4 standard
    errors (centre along the view and radius, the two it moves)."""
    rng = np.random.default_rng(15)
    p, _ = visible_cap(rng, CENTRE, RADIUS, 2000)
    sigma = rng.uniform(0.1, 0.2, len(p))
    est = []
    for _ in range(200):
        fit = fit_sphere(along_sight(rng, p, sigma))
        est.append(np.append(fit.centre, fit.radius))
    mc = np.mean(est, axis=0) - np.append(CENTRE, RADIUS)
    se = np.std(est, axis=0, ddof=1) / np.sqrt(len(est))
    pred = sight_noise_bias(p, CENTRE, RADIUS, sigma)
    assert pred[3] < -5 * se[3] and pred[2] < -5 * se[2]  # a real, negative bias
    assert np.all(np.abs(mc - pred) < 4 * se), (mc, pred, se)
