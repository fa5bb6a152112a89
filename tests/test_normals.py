"""Normals of a scan from its pixel grid (scanqa.model.normals), against surfaces whose
normals are known in closed form: a sphere and two tilted planes at different depths seen
by a pinhole camera at the origin; and in annotate's cloud and its metadata."""

from __future__ import annotations

import numpy as np

from scanqa.annotation.points import NORMAL_ATTRIBUTES, annotate
from scanqa.model.normals import GRID_METHOD, grid_normals, knn_normals, pixel_index

from .test_annotate import cfg, scan, table  # noqa: F401 - fixtures

F_PX, W, H = 800.0, 120, 100


def rays() -> np.ndarray:
    """Unit-depth rays (x/z, y/z, 1) of a W x H pinhole camera of F_PX [px]."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    return np.stack([(u - W / 2) / F_PX, (v - H / 2) / F_PX, np.ones_like(u)], -1)


def sphere(centre=(0.0, 0.0, 400.0), radius=30.0):
    """Points of the sphere's near side on the pixel grid, their true outward normals
    (which face the camera there) and which pixels hit it."""
    d = rays() / np.linalg.norm(rays(), axis=-1, keepdims=True)
    c = np.asarray(centre)
    b = d @ c
    disc = b**2 - (c @ c - radius**2)
    hit = disc > 0
    t = b - np.sqrt(np.where(hit, disc, 0.0))
    p = d * t[..., None]
    return p[hit], ((p - c) / radius)[hit], hit


def test_sphere_normals_from_the_pixel_grid():
    xyz, truth, hit = sphere()
    normals = grid_normals(xyz, pixel_index(hit), F_PX)
    assert normals.dtype == np.float32 and normals.shape == xyz.shape
    angle = np.degrees(np.arccos(np.clip(np.sum(normals * truth, axis=1), -1, 1)))
    sight = -xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    incidence = np.degrees(np.arccos(np.sum(sight * truth, axis=1)))
    # central differences on a 30 mm sphere sampled every 0.5 mm: exact to 0.05 deg
    # where it faces the camera, within a degree to 75 deg, worse towards the limb
    assert angle[incidence < 45].max() < 0.05
    assert np.percentile(angle[incidence < 75], 99) < 1.0
    found = np.any(normals, axis=1)
    assert found.mean() > 0.99  # zeros only at the limb (a neighbour beyond the sphere)
    assert (np.einsum("ij,ij->i", normals[found], xyz[found]) < 0).all()  # facing the camera


def test_a_depth_jump_is_not_bridged():
    """A plane tilted 30 deg about Y at 300 mm over the left half, one tilted -20 deg
    about X at 450 mm over the right: every normal is its own plane's, also at the edge."""
    r = rays()
    n_left = np.array([np.sin(np.radians(30)), 0.0, -np.cos(np.radians(30))])
    n_right = np.array([0.0, np.sin(np.radians(-20)), -np.cos(np.radians(-20))])
    left = np.arange(W)[None, :].repeat(H, 0) < W // 2
    # plane n . p = n . p0 through (0, 0, z0) met by the ray t r
    t = np.where(left, (n_left[2] * 300.0) / (r @ n_left), (n_right[2] * 450.0) / (r @ n_right))
    xyz = (r * t[..., None]).reshape(-1, 3)
    normals = grid_normals(xyz, pixel_index(np.ones((H, W), bool)), F_PX)
    truth = np.where(left.reshape(-1, 1), n_left, n_right)
    np.testing.assert_allclose(normals, truth, atol=1e-5)


def test_points_without_neighbours_get_zero_normals_and_bands_agree():
    keep = np.zeros((H, W), bool)
    keep[10:40, 10:60] = True
    keep[70, 5] = True  # alone
    keep[80, 20:30] = True  # one row: no column neighbour
    xyz, _, _ = sphere(radius=1e4, centre=(0.0, 0.0, 1e4 + 400.0))  # every pixel hits
    xyz = xyz.reshape(H, W, 3)[keep]
    index = pixel_index(keep)
    normals = grid_normals(xyz, index, F_PX)
    zero = ~np.any(normals, axis=1)
    assert zero.sum() == 11 and np.allclose(np.linalg.norm(normals[~zero], axis=1), 1)
    # band by band (as annotate runs them) gives the same normals as one pass, bands with
    # no point at all (rows 40-69 with 10-row bands) included
    for size in (25, 10):
        bands = np.concatenate([grid_normals(xyz, index, F_PX, (a, a + size))
                                for a in range(0, H, size)])
        np.testing.assert_array_equal(bands, normals)


def test_knn_normals_of_an_unorganised_cloud():
    xyz, truth, _ = sphere()
    rng = np.random.default_rng(0)
    order = rng.permutation(len(xyz))
    normals = knn_normals(xyz[order], k=16)
    angle = np.degrees(np.arccos(np.clip(np.sum(normals * truth[order], axis=1), -1, 1)))
    assert np.median(angle) < 0.5 and np.percentile(angle, 99) < 5.0


def test_annotate_writes_grid_normals_and_says_so(cfg, table, tmp_path):  # noqa: F811
    pm, _ = scan(cfg, sigma=0.0, nan_rows=3)  # a plane facing the camera
    cloud = annotate(pm, table, cfg, out=tmp_path / "c.ply")
    normals = np.stack([cloud.attributes[n] for n in NORMAL_ATTRIBUTES], -1)
    # the table's interpolation leaves sub-um bumps over ~0.3 mm between pixels
    assert np.percentile(np.degrees(np.arccos(-normals[:, 2])), 99) < 1.0
    assert cloud.metadata["normals"] == GRID_METHOD
    pcd = cloud.to_open3d()  # Open3D's own normals, as its PLY reader loads them
    np.testing.assert_array_equal(pcd.point["normals"].numpy(), normals)
    assert "nx" not in pcd.point
    plain = annotate(pm, table, cfg, normals=False)
    assert not set(NORMAL_ATTRIBUTES) & set(plain.attributes)
    assert "normals" not in plain.metadata
    for name in plain.attributes:
        np.testing.assert_array_equal(plain.attributes[name], cloud.attributes[name])


def test_the_compiled_loop_and_numpy_agree(monkeypatch):
    from scanqa.model import normals as module

    keep = np.ones((H, W), bool)
    keep[30:33, :] = False  # a gap of rows
    keep[:, 50] = False  # and of a column
    keep[70, 5] = False
    xyz, _, hit = sphere()
    keep &= hit
    full = np.zeros((H, W, 3))
    full[hit] = xyz
    xyz = full[keep]
    index = pixel_index(keep)
    compiled = [grid_normals(xyz, index, F_PX, (a, a + 30)) for a in range(0, H, 30)]
    monkeypatch.setattr(module, "HAVE_NUMBA", False)
    plain = [grid_normals(xyz, index, F_PX, (a, a + 30)) for a in range(0, H, 30)]
    for c, p in zip(compiled, plain, strict=True):
        np.testing.assert_allclose(c, p, atol=1e-6)
