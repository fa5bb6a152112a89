"""Orthogonal least-squares planes against the eigenvectors of the scatter matrix."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanqa.errors import InputError
from scanqa.qa.planes import fit_plane


def _eigen_plane(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and unit normal by another algorithm than the SVD: the eigenvector of the
    smallest eigenvalue of the 3 x 3 scatter matrix (numpy's eigh)."""
    c = pts.mean(axis=0)
    _, vec = np.linalg.eigh((pts - c).T @ (pts - c))
    return c, vec[:, 0]


@settings(max_examples=40, deadline=None)
@given(tilt_x=st.floats(-0.6, 0.6), tilt_y=st.floats(-0.6, 0.6), z0=st.floats(300.0, 600.0),
       x0=st.floats(-100.0, 100.0), seed=st.integers(0, 2**16))
def test_fit_plane_matches_scatter_eigenvector(tilt_x, tilt_y, z0, x0, seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-10, 10, (60, 2)) * [1.0, 0.6] + [x0, 0.0]
    z = z0 + tilt_x * (xy[:, 0] - x0) + tilt_y * xy[:, 1] + rng.normal(0, 0.01, 60)
    pts = np.column_stack([xy, z])
    fit = fit_plane(pts)
    c, n = _eigen_plane(pts)
    n = n if n @ c < 0 else -n  # towards the camera at the origin
    np.testing.assert_allclose(fit.centroid, c, rtol=1e-12)
    np.testing.assert_allclose(fit.normal, n, atol=1e-9)
    assert fit.normal @ fit.centroid < 0  # faces the scanner origin
    np.testing.assert_allclose(fit.residuals, (pts - c) @ n, atol=1e-9)
    # the in-plane axes complete an orthonormal frame
    frame = np.vstack([fit.axes, fit.normal])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)


def test_residual_sign_is_towards_the_camera():
    """A point nearer the camera than the plane (smaller Z here) has a positive residual."""
    x, y = np.meshgrid(np.arange(-5.0, 5.1), np.arange(-5.0, 5.1))
    pts = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 450.0)])
    centre = x.size // 2  # (0, 0): the bump does not tilt the fit on a symmetric grid
    pts[centre, 2] -= 0.11
    fit = fit_plane(pts)
    np.testing.assert_allclose(fit.normal, [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(fit.residuals[centre], 0.11 * 120 / 121, rtol=1e-9)
    np.testing.assert_allclose(np.delete(fit.residuals, centre), -0.11 / 121, rtol=1e-9)
    # the plane behind the scanner (Z < 0): still oriented towards the origin
    fit = fit_plane(pts * [1.0, 1.0, -1.0])
    assert fit.normal[2] > 0.99


def test_degenerate_inputs_name_the_block():
    line = np.outer(np.arange(10.0), [1.0, 0.5, 0.0]) + np.array([0.0, 0.0, 450.0])
    with pytest.raises(InputError, match=r"^block 4: the points are collinear"):
        fit_plane(line, "block 4")
    # a line wobbling by 1e-12 mm over 10 mm is still a line; 1e-6 mm is a (thin) plane
    wobble = line + np.outer((-1.0) ** np.arange(10), [0.0, 0.0, 1e-12])
    with pytest.raises(InputError, match="collinear"):
        fit_plane(wobble)
    thin = line + np.outer((-1.0) ** np.arange(10), [0.0, 0.0, 1e-6])
    assert fit_plane(thin).residuals.shape == (10,)
    with pytest.raises(InputError, match=r"^points: a plane needs at least 3 points, got 2$"):
        fit_plane(line[:2])
    assert fit_plane([*line[:2].tolist(), [0.0, 1.0, 450.0]]).residuals.shape == (3,)
    with pytest.raises(InputError, match="collinear"):
        fit_plane(np.zeros((5, 3)))
    # not an (n, 3) array: the same message, with the length of the first axis
    with pytest.raises(InputError, match=r"^points: a plane needs at least 3 points, got 9$"):
        fit_plane(np.zeros(9))
    with pytest.raises(InputError, match=r"^points: a plane needs at least 3 points, got 5$"):
        fit_plane(np.ones((5, 2)))
    bad = thin.copy()
    bad[3, 1] = np.inf
    with pytest.raises(InputError) as err:
        fit_plane(bad, "block 6")
    assert str(err.value) == "block 6: points with NaN or infinite coordinates"


def test_collinearity_threshold_is_relative_to_the_extent():
    """s_2 <= 1e-9 s_1 (singular values of the centred points): a 100 mm line of 1000
    points wobbling by 1e-9 mm is a line; a 0.01 mm patch 1e-10 mm wide is a plane."""
    t = np.linspace(0.0, 100.0, 1000)
    line = np.column_stack([t, 0.5 * t, np.full_like(t, 450.0)])
    line[:, 2] += 1e-9 * (-1.0) ** np.arange(1000)
    with pytest.raises(InputError, match="collinear"):
        fit_plane(line)
    t = np.linspace(0.0, 0.01, 50)
    patch = np.column_stack([t, 1e-10 * (-1.0) ** np.arange(50), np.full_like(t, 450.0)])
    fit = fit_plane(patch)
    np.testing.assert_allclose(abs(fit.normal[2]), 1.0, atol=1e-6)


def test_orientation_near_the_origin():
    """A plane 0.5 mm in front of the scanner still faces it (the sign test is n . c < 0,
    not a distance)."""
    x, y = np.meshgrid(np.linspace(-5, 5, 11), np.linspace(-5, 5, 11))
    pts = np.column_stack([x.ravel() + 0.3, y.ravel(), np.full(x.size, 0.5)])
    fit = fit_plane(pts)
    np.testing.assert_allclose(fit.normal, [0.0, 0.0, -1.0], atol=1e-12)
    fit = fit_plane(pts * [1.0, 1.0, -1.0])  # 0.5 mm behind
    np.testing.assert_allclose(fit.normal, [0.0, 0.0, 1.0], atol=1e-12)
