"""Ball bars and the sphere/plane search: closed loops against exact truth."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from scanqa.errors import InputError
from scanqa.qa.ballbar import centre_distance, find_ball_bar, fit_ball_bar
from scanqa.qa.ransac import find_spheres, ransac_plane, ransac_sphere

from .qa_artefacts import along_sight, flat_patch, rigid, sight_cosine, visible_cap

RADIUS = 12.7
CENTRE_A = np.array([-110.0, 20.0, 470.0])
CENTRE_B = np.array([95.0, -40.0, 520.0])
LENGTH = float(np.linalg.norm(CENTRE_B - CENTRE_A))


def bar_scan(rng, n=1500, sigma=0.02):
    pa, na = visible_cap(rng, CENTRE_A, RADIUS, n)
    pb, nb = visible_cap(rng, CENTRE_B, RADIUS, n)
    return (along_sight(rng, pa, sigma), sigma * sight_cosine(pa, na),
            along_sight(rng, pb, sigma), sigma * sight_cosine(pb, nb))


def test_centre_distance_within_its_uncertainty():
    qa, sa, qb, sb = bar_scan(np.random.default_rng(0))
    bar = fit_ball_bar(qb, qa, sb, sa)  # given in either order
    assert bar.sphere_a.centre[0] < bar.sphere_b.centre[0]
    assert abs(bar.distance - LENGTH) < 4 * bar.u_distance
    assert_allclose(bar.direction, (CENTRE_B - CENTRE_A) / LENGTH, atol=1e-4)


def test_distance_uncertainty_is_honest_by_monte_carlo():
    """u(L) from both centres' covariances matches the scatter of L over 300 scans within
    10 % (std of a std over 300 draws ~4 %)."""
    rng = np.random.default_rng(1)
    pa, na = visible_cap(rng, CENTRE_A, RADIUS, 300)
    pb, nb = visible_cap(rng, CENTRE_B, RADIUS, 300)
    sig_a, sig_b = rng.uniform(0.01, 0.04, 300), rng.uniform(0.01, 0.04, 300)
    lengths, u = [], None
    for _ in range(300):
        bar = fit_ball_bar(along_sight(rng, pa, sig_a), along_sight(rng, pb, sig_b),
                           sig_a * sight_cosine(pa, na), sig_b * sight_cosine(pb, nb))
        lengths.append(bar.distance)
        u = bar.u_distance
    assert_allclose(np.std(lengths, ddof=1) / u, 1.0, atol=0.10)


def test_distance_uncertainty_by_hand():
    """Diagonal covariances: u^2 = sum over both centres of g_j^2 var_j."""
    from scanqa.qa.sphere import SphereFit

    def sphere(c, var):
        cov = np.diag([*var, 1e-6])
        return SphereFit(np.asarray(c, float), 5.0, np.zeros(30), cov, "points", np.ones(4),
                         1.0, 80.0, np.array([0, 0, 1.0]), 3)

    a = sphere([0, 0, 0], [1e-6, 4e-6, 9e-6])
    b = sphere([3, 4, 0], [1e-6, 1e-6, 1e-6])
    length, u = centre_distance(a, b)
    assert length == 5.0
    assert_allclose(u, np.sqrt((0.36 * 2e-6) + (0.64 * 5e-6)))  # g = (0.6, 0.8, 0)
    with pytest.raises(InputError, match="the same centre"):
        centre_distance(a, a)


def test_find_ball_bar_in_a_scene_with_a_base_plate():
    rng = np.random.default_rng(2)
    qa, _, qb, _ = bar_scan(rng)
    plate, _ = flat_patch(rng, [0.0, 0.0, 560.0], [0, 0, -1.0], 300.0, 20000)
    scene = np.vstack([plate, qa, qb])
    rot, shift = rigid(rng)
    idx_a, idx_b = find_ball_bar(scene, 2 * RADIUS, distance_mm=LENGTH)
    # every ball point found, no plate point taken
    got = {tuple(sorted(set(idx_a.tolist()) | set(idx_b.tolist())))}
    assert got == {tuple(range(20000, 20000 + 2 * 1500))}
    # the same spheres after a rigid motion of the whole scene (the order may change)
    moved = find_ball_bar(scene @ rot.T + shift, 2 * RADIUS, distance_mm=LENGTH)
    assert {len(moved[0]), len(moved[1])} == {1500}
    assert set(moved[0].tolist()) | set(moved[1].tolist()) == set(range(20000, 23000))


def test_ball_bar_with_one_sphere_missing_is_a_clear_error():
    rng = np.random.default_rng(3)
    qa, _, _, _ = bar_scan(rng)
    plate, _ = flat_patch(rng, [0.0, 0.0, 560.0], [0, 0, -1.0], 300.0, 5000)
    with pytest.raises(InputError, match=r"ball bar: found 1 of 2 spheres of radius 12\.7 mm"):
        find_ball_bar(np.vstack([plate, qa]), 2 * RADIUS)


def test_ball_bar_at_the_wrong_distance_is_a_clear_error():
    qa, _, qb, _ = bar_scan(np.random.default_rng(4))
    with pytest.raises(InputError, match=r"are 21\d\.\d\d mm apart, the bar's nominal"):
        find_ball_bar(np.vstack([qa, qb]), 2 * RADIUS, distance_mm=300.0)


def test_ransac_is_seeded_and_respects_the_radius_prior():
    rng = np.random.default_rng(5)
    big, _ = visible_cap(rng, [0, 0, 500.0], 25.0, 3000)
    small, _ = visible_cap(rng, [80, 0, 500.0], 10.0, 1000)
    scene = np.vstack([big, small])
    a = ransac_sphere(scene, radius_mm=10.0, threshold_mm=0.05)
    b = ransac_sphere(scene, radius_mm=10.0, threshold_mm=0.05)
    assert_allclose(a.centre, [80, 0, 500.0], atol=1e-6)  # noiseless: exact
    assert_allclose(a.radius, 10.0, atol=1e-6)
    np.testing.assert_array_equal(a.inliers, b.inliers)
    assert set(a.inliers.tolist()) == set(range(3000, 4000))
    assert ransac_sphere(scene, radius_mm=40.0, threshold_mm=0.05) is None
    found = find_spheres(scene, 2)  # no prior: the larger sphere first
    assert_allclose([f.radius for f in found], [25.0, 10.0], atol=1e-6)


def test_ransac_plane_finds_the_plate():
    rng = np.random.default_rng(6)
    plate, _ = flat_patch(rng, [0.0, 0.0, 560.0], [0.1, 0, -1.0], 200.0, 5000)
    ball, _ = visible_cap(rng, [0, 0, 500.0], 12.7, 2000)
    normal, offset, inliers = ransac_plane(np.vstack([ball, plate]), threshold_mm=0.05)
    n_true = np.array([0.1, 0, -1.0]) / np.linalg.norm([0.1, 0, -1.0])
    assert abs(abs(normal @ n_true) - 1) < 1e-9
    assert_allclose(abs(offset), abs(n_true @ [0, 0, 560.0]), atol=1e-6)
    assert set(inliers.tolist()) == set(range(2000, 7000))
