"""Flatness: least-squares and minimum-zone planes against the exact convex-hull width."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial import ConvexHull

from scanqa.errors import InputError
from scanqa.qa.flat import flatness, minimum_zone_plane

from .qa_artefacts import flat_patch, rigid


def hull_width(points):
    """Exact minimum width of a point set: the smallest extent over the facet normals of
    its convex hull and the normals of every pair of hull edges (the width is attained by
    a facet-vertex or an edge-edge pair of antipodal features)."""
    hull = ConvexHull(points)
    edges = {tuple(sorted((s[i], s[(i + 1) % 3]))) for s in hull.simplices for i in range(3)}
    e = np.array(sorted(edges))
    d = points[e[:, 1]] - points[e[:, 0]]
    i, j = np.triu_indices(len(d), 1)
    cross = np.cross(d[i], d[j])
    norm = np.linalg.norm(cross, axis=1)
    normals = np.vstack([hull.equations[:, :3], cross[norm > 0] / norm[norm > 0, None]])
    return float(np.min(np.ptp(points[hull.vertices] @ normals.T, axis=0)))


def noisy_flat(rng, n, sigma=0.02, size=40.0, form=0.0):
    p, st = flat_patch(rng, [5.0, -3.0, 450.0], [0.1, -0.2, -1.0], size, n)
    normal = np.array([0.1, -0.2, -1.0]) / np.linalg.norm([0.1, -0.2, -1.0])
    bump = form * np.cos(2 * np.pi * st[:, 0] / size)  # one period across the patch [mm]
    return p + normal * (bump + rng.normal(0, sigma, n))[:, None]


@pytest.mark.parametrize("n", [6, 12, 40])
def test_minimum_zone_equals_the_exact_hull_width(n):
    rng = np.random.default_rng(n)
    for _ in range(3):
        p = noisy_flat(rng, n)
        assert_allclose(minimum_zone_plane(p).width, hull_width(p), atol=1e-10)


def test_minimum_zone_never_exceeds_least_squares():
    rng = np.random.default_rng(1)
    for n, form in ((100, 0.0), (20000, 0.05)):
        p = noisy_flat(rng, n, form=form)
        zone = minimum_zone_plane(p)
        ls = flatness(p)
        assert zone.width <= ls + 1e-12
        h = p @ zone.normal
        assert_allclose([h.min(), h.max()], [zone.lower, zone.upper], atol=1e-9)
        assert zone.normal @ np.array([0.1, -0.2, -1.0]) > 0  # oriented as the LS normal


def test_flatness_of_a_known_form():
    """A noiseless cosine of amplitude 0.05 mm over one period, on a grid symmetric about
    the patch centre: the least-squares plane is its mean plane (on that grid the cosine
    is orthogonal to 1, s and t), so both flatness measures are the peak-to-valley of the
    cosine's samples."""
    s, t = np.meshgrid(np.arange(-19.75, 20, 0.5), np.arange(-19.75, 20, 0.5))
    z = 0.05 * np.cos(2 * np.pi * s.ravel() / 40)
    rot, shift = rigid(np.random.default_rng(2))
    p = np.column_stack([s.ravel(), t.ravel(), z]) @ rot.T + shift
    assert_allclose(flatness(p), np.ptp(z), rtol=1e-9)
    assert_allclose(flatness(p, "minimum_zone"), np.ptp(z), rtol=1e-9)


def test_invariant_under_a_rigid_transform():
    rng = np.random.default_rng(3)
    p = noisy_flat(rng, 3000, form=0.02)
    rot, shift = rigid(rng)
    q = p @ rot.T + shift
    assert_allclose(flatness(q), flatness(p), atol=1e-10)
    assert_allclose(minimum_zone_plane(q).width, minimum_zone_plane(p).width, atol=1e-10)


def test_bad_input():
    with pytest.raises(InputError, match="method must be 'least_squares' or 'minimum_zone'"):
        flatness(np.eye(4, 3) + 1, "chebyshev")
    with pytest.raises(InputError, match="flat: 3 points, a fit needs at least 4"):
        minimum_zone_plane(np.eye(3))
    with pytest.raises(InputError, match="collinear"):
        minimum_zone_plane(np.outer(np.arange(6.0), [1.0, 2.0, 3.0]))
