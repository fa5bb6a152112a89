"""Table lookups (bilinear in (u, v), cubic Hermite in s) against a brute-force reference.

The reference evaluates a small random table point by point as the notes of
:mod:`scanqa.calibration.lookup` describe it, with other tools than the code: scipy's
CubicHermiteSpline per node for Z and dZ/ds, a straight line through the two nearest s
nodes for the table's sigma, numpy's polyval2d for the shear, and the bilinear weights
and the per-node lateral rays written out per point. The code packs the table into
float32 Hermite coefficients, gathers per band of rows and blends in float32, so the two
agree to float32 rounding (~1e-6 mm).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import polynomial as P
from scipy.interpolate import CubicHermiteSpline

from scanqa.calibration import lookup
from scanqa.calibration.shear import DEGREE
from scanqa.calibration.table import CalibrationTable

WIDTH, HEIGHT, CELL = 40, 30, 8.0
S_NODES = np.arange(-6, 7) * 2.0  # [projector px]


def random_table(seed: int = 0, width: int = WIDTH, height: int = HEIGHT, cell: float = CELL,
                 shear: np.ndarray | None = None) -> CalibrationTable:
    """A table over a camera of width x height px (5 x 4 nodes by default), 13 s nodes, a
    random shear, random smooth values per node and random calibrated ranges (one node
    without any)."""
    rng = np.random.default_rng(seed)
    node_u = np.arange(int(np.ceil(width / cell))) * cell + (cell - 1) / 2
    node_v = np.arange(int(np.ceil(height / cell))) * cell + (cell - 1) / 2
    n_v, n_u, n_s = node_v.size, node_u.size, S_NODES.size
    s = S_NODES[None, None, :]
    a0 = 450.0 + rng.normal(0, 5, (n_v, n_u, 1))
    a1 = 3.0 + rng.normal(0, 0.3, (n_v, n_u, 1))
    a2 = rng.normal(0, 0.05, (n_v, n_u, 1))
    z = a0 + a1 * s + a2 * s**2 + rng.normal(0, 0.01, (n_v, n_u, n_s))
    dz = a1 + 2 * a2 * s + rng.normal(0, 0.02, (n_v, n_u, n_s))
    kx = rng.normal(0.05, 0.02, (n_v, n_u, 1))
    ky = rng.normal(-0.03, 0.02, (n_v, n_u, 1))
    x0 = rng.normal(0, 20, (n_v, n_u, 1))
    y0 = rng.normal(0, 15, (n_v, n_u, 1))
    xyz = np.stack([x0 + kx * z, y0 + ky * z, z], -1)
    dxyz = np.stack([kx * dz + rng.normal(0, 1e-3, dz.shape),
                     ky * dz + rng.normal(0, 1e-3, dz.shape), dz], -1)
    sigma = rng.uniform(1e-3, 5e-3, (n_v, n_u, n_s))
    s_lo = rng.uniform(-12, -4, (n_v, n_u))
    s_hi = rng.uniform(4, 12, (n_v, n_u))
    if n_v * n_u > 4:  # a node that was never calibrated: no range, no values
        s_lo[-1, -1] = s_hi[-1, -1] = np.nan
        xyz[-1, -1] = dxyz[-1, -1] = sigma[-1, -1] = np.nan
    if shear is None:
        shear = np.zeros((DEGREE + 1) * (DEGREE + 2) // 2)
        shear[:6] = [600.0, 4.0, -1.5, 30.0, 0.8, 2.5]  # 1, v, v^2, v^3, v^4, u (module order)
        shear[6:] = rng.normal(0, 0.5, shear.size - 6)
    return CalibrationTable(node_u, node_v, np.zeros((n_v, n_u)), S_NODES, xyz, dxyz, sigma,
                            s_lo, s_hi, shear, width, height, "none", {}, {})


def shear_at(t: CalibrationTable, u, v) -> np.ndarray:
    """x_shear = sum c_ij un^i vn^j, un = 2 u / (W - 1) - 1 (coefficients u^i v^j, i + j <= d,
    i major), by numpy's 2-D polynomial evaluation."""
    c = np.zeros((DEGREE + 1, DEGREE + 1))
    k = 0
    for i in range(DEGREE + 1):
        for j in range(DEGREE + 1 - i):
            c[i, j] = t.shear[k]
            k += 1
    un = 2.0 * np.asarray(u, float) / (t.width_px - 1) - 1.0
    vn = 2.0 * np.asarray(v, float) / (t.height_px - 1) - 1.0
    return P.polyval2d(un, vn, c)


def _cell(nodes: np.ndarray, coord: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower node of each coordinate's cell (edge cells extrapolate) and the fraction."""
    f = (coord - nodes[0]) / cell
    i = np.minimum(np.maximum(np.floor(f), 0), nodes.size - 2).astype(int)
    return i, f - i


def reference(t: CalibrationTable, u, v, xp) -> dict:
    """Points by brute force: the cell and fractions, the four nodes' Hermite Z(s) (scipy),
    linear sigma(s) and lateral rays, blended with bilinear weights; arrays like ``u``."""
    u, v, xp = (np.asarray(a, float).ravel() for a in (u, v, xp))
    s = xp - shear_at(t, u, v)
    iu, tu = _cell(t.node_u, u, t.cell_px)
    iv, tv = _cell(t.node_v, v, t.cell_px)
    h = S_NODES[1] - S_NODES[0]
    k = np.minimum(np.maximum(np.floor(np.nan_to_num((s - S_NODES[0]) / h)), 0),
                   S_NODES.size - 2).astype(int)
    frac = (s - S_NODES[k]) / h
    centre = S_NODES.size // 2
    acc = {name: np.zeros(u.size) for name in ("z", "dz", "sig", "x0", "kx", "y0", "ky")}
    lo, hi = np.full(u.size, -np.inf), np.full(u.size, np.inf)
    for dv, du, w in ((0, 0, (1 - tv) * (1 - tu)), (0, 1, (1 - tv) * tu),
                      (1, 0, tv * (1 - tu)), (1, 1, tv * tu)):
        for a in range(t.node_v.size):
            for b in range(t.node_u.size):
                m = (iv + dv == a) & (iu + du == b)
                if not m.any():
                    continue
                # a node never calibrated (NaN) leaves no calibrated range in its cells
                lo[m] = np.maximum(lo[m], t.s_lo[a, b])
                hi[m] = np.minimum(hi[m], t.s_hi[a, b])
                z, dz, sig = t.xyz[a, b, :, 2], t.dxyz[a, b, :, 2], t.sigma_node[a, b]
                if not np.isfinite(z).all():  # and no values: every blend with it is NaN
                    for values in acc.values():
                        values[m] = np.nan
                    continue
                spline = CubicHermiteSpline(S_NODES, z, dz, extrapolate=True)
                kx = t.dxyz[a, b, centre, 0] / t.dxyz[a, b, centre, 2]
                ky = t.dxyz[a, b, centre, 1] / t.dxyz[a, b, centre, 2]
                acc["z"][m] += w[m] * spline(s[m])
                acc["dz"][m] += w[m] * spline(s[m], 1)
                acc["sig"][m] += w[m] * (sig[k[m]] + frac[m] * (sig[k[m] + 1] - sig[k[m]]))
                acc["x0"][m] += w[m] * (t.xyz[a, b, centre, 0] - kx * z[centre])
                acc["kx"][m] += w[m] * kx
                acc["y0"][m] += w[m] * (t.xyz[a, b, centre, 1] - ky * z[centre])
                acc["ky"][m] += w[m] * ky
    z, dz = acc["z"], acc["dz"]
    with np.errstate(invalid="ignore"):
        inside = (lo <= s) & (s <= hi)
    return {"xyz": np.stack([acc["x0"] + acc["kx"] * z, acc["y0"] + acc["ky"] * z, z], -1),
            "slope": np.stack([acc["kx"] * dz, acc["ky"] * dz, dz], -1),
            "sigma": acc["sig"], "inside": inside}


def _check(look, u, v, xp, table, extrapolate: bool) -> None:
    ref = reference(table, u, v, xp)
    xyz, slope = look.xyz.reshape(-1, 3), look.slope.reshape(-1, 3)
    sigma, inside = look.sigma_table.ravel(), look.in_volume.ravel()
    np.testing.assert_array_equal(inside, ref["inside"])
    shown = ref["inside"] | (extrapolate & np.isfinite(xp.ravel()))
    assert np.isnan(xyz[~shown]).all() and np.isnan(slope[~shown]).all()
    assert np.isnan(sigma[~shown]).all()
    # float32 coefficients of Z - mean(Z) (|Z - mean| < 60 mm): ~4e-6 mm
    np.testing.assert_allclose(xyz[shown], ref["xyz"][shown], rtol=0, atol=2e-5)
    np.testing.assert_allclose(slope[shown], ref["slope"][shown], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(sigma[shown], ref["sigma"][shown], rtol=1e-5, atol=1e-8)


@pytest.fixture(scope="module")
def table() -> CalibrationTable:
    return random_table()


def _queries(table, n: int, seed: int):
    """Random pixels (fractional, a little past the image edges) and phases from 2 px
    before the s grid to 2 px past it, and a few NaN."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1.0, WIDTH, n)
    v = rng.uniform(-1.0, HEIGHT, n)
    xp = shear_at(table, u, v) + rng.uniform(S_NODES[0] - 2, S_NODES[-1] + 2, n)
    xp[::17] = np.nan
    return u, v, xp


@pytest.mark.parametrize("extrapolate", [False, True])
def test_points_match_brute_force(table, extrapolate):
    u, v, xp = _queries(table, 400, seed=1)
    look = table.apply(u, v, xp, extrapolate=extrapolate)
    assert look.in_volume.any() and not look.in_volume.all()
    _check(look, u, v, xp, table, extrapolate)
    # shape of the query is kept
    look2 = table.apply(u.reshape(20, 20), v.reshape(20, 20), xp.reshape(20, 20), extrapolate)
    assert look2.xyz.shape == (20, 20, 3) and look2.slope.shape == (20, 20, 3)
    assert look2.sigma_table.shape == (20, 20) and look2.in_volume.shape == (20, 20)
    np.testing.assert_array_equal(look2.xyz.reshape(-1, 3), look.xyz)
    np.testing.assert_allclose(look.s_t, np.linalg.norm(look.slope, axis=-1))


def _phase_image(table, seed: int, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v, u = np.indices((height, width), dtype=float)
    xp = shear_at(table, u, v) + rng.uniform(S_NODES[0] - 2, S_NODES[-1] + 2, u.shape)
    xp[rng.uniform(size=u.shape) < 0.05] = np.nan
    return xp


@pytest.mark.parametrize("extrapolate", [False, True])
def test_image_matches_brute_force(table, extrapolate):
    xp = _phase_image(table, 2)
    look = table.apply_image(xp, extrapolate=extrapolate)
    v, u = np.indices(xp.shape, dtype=float)
    assert look.xyz.shape == (HEIGHT, WIDTH, 3)
    _check(look, u, v, xp, table, extrapolate)


def test_rows_and_selected_pixels_match_the_whole_image(table):
    """A band of rows (all pixels or a selection) gives the whole image's numbers there."""
    xp = _phase_image(table, 3)
    whole = table.apply_image(xp, extrapolate=True)
    band = table.apply_rows(xp[11:23], row0=11, extrapolate=True)
    for name in ("xyz", "slope", "sigma_table", "in_volume"):
        np.testing.assert_array_equal(getattr(band, name), getattr(whole, name)[11:23])
    select = np.array([0, 5, WIDTH + 3, 4 * WIDTH + 39, 11 * WIDTH + 20])
    picked = table.apply_rows(xp[11:23], row0=11, select=select, extrapolate=True)
    flat = {name: getattr(whole, name)[11:23].reshape(len(xp[11:23]) * WIDTH, -1)
            for name in ("xyz", "slope")}
    np.testing.assert_array_equal(picked.xyz, flat["xyz"][select])
    np.testing.assert_array_equal(picked.slope, flat["slope"][select])
    np.testing.assert_array_equal(picked.in_volume, whole.in_volume[11:23].ravel()[select])
    np.testing.assert_array_equal(table.in_volume_rows(xp[11:23], row0=11),
                                  whole.in_volume[11:23])
    out = lookup.empty_lookup((len(select),))
    again = lookup.apply_rows(table, xp[11:23], 11, select, True, out)
    assert again is out
    np.testing.assert_array_equal(out.sigma_table, whole.sigma_table[11:23].ravel()[select])


def test_node_index_extrapolates_at_the_edges(table):
    """Below the first node: cell 0 with a negative fraction; past the last: the last cell
    with a fraction > 1."""
    i, t = lookup.node_index(table, np.array([-1.0, 3.5, 5.5, 35.5, 39.0]), 1)
    np.testing.assert_array_equal(i, [0, 0, 0, 3, 3])
    np.testing.assert_allclose(t, [-4.5 / 8, 0.0, 0.25, 1.0, 1.4375])
    i, t = lookup.node_index(table, np.array([0.0, 12.0, 29.0]), 0)
    np.testing.assert_array_equal(i, [0, 1, 2])
    np.testing.assert_allclose(t, [-3.5 / 8, 8.5 / 8 - 1, 25.5 / 8 - 2])


def test_exact_at_the_nodes(table):
    """At a node's pixel and an s node, the lookup returns that node's stored values."""
    for iv, iu, k in ((0, 0, 6), (2, 2, 1), (1, 4, 11), (3, 0, 2)):  # not by node (3, 4)
        u, v = table.node_u[iu], table.node_v[iv]
        xp = S_NODES[k] + shear_at(table, u, v)
        look = table.apply(u, v, xp, extrapolate=True)
        np.testing.assert_allclose(look.xyz[2], table.xyz[iv, iu, k, 2], atol=1e-5)
        np.testing.assert_allclose(look.slope[2], table.dxyz[iv, iu, k, 2], rtol=1e-5)
        np.testing.assert_allclose(look.sigma_table, table.sigma_node[iv, iu, k], rtol=1e-5)


def test_large_query_runs_in_bands(table):
    """40 000 points are three bands of 16 384 (scanqa.chunks): every band lands in place."""
    u, v, xp = _queries(table, 40_000, seed=4)
    look = table.apply(u, v, xp, extrapolate=False)
    _check(look, u, v, xp, table, extrapolate=False)


def test_calibrated_range_is_inclusive():
    """A phase exactly at the lowest or the highest calibrated s of a cell is inside. The
    shear is the constant 600.25 px (exact in binary), so s = x_p - 600.25 is exact."""
    shear = np.zeros((DEGREE + 1) * (DEGREE + 2) // 2)
    shear[0] = 600.25
    t = random_table(seed=6, shear=shear)
    t.s_lo[...] = -7.5
    t.s_hi[...] = 7.25
    t.s_lo[1, 2] = -8.0  # a lower bound at one corner does not widen the cell's range
    t.s_hi[1, 2] = 7.75
    u = np.array([10.0, 12.0, 30.0, 17.0, 17.0])
    v = np.array([5.0, 9.0, 20.0, 13.0, 13.0])
    xp = 600.25 + np.array([-7.5, 7.25, 7.25, -7.5 - 2**-20, 7.25 + 2**-20])
    look = t.apply(u, v, xp)
    np.testing.assert_array_equal(look.in_volume, [True, True, True, False, False])
    img = np.full((HEIGHT, WIDTH), 600.25 - 7.5)
    img[::2] = 600.25 + 7.25
    img[:, 7] = 600.25 + 7.25 + 2**-20
    inside = t.apply_image(img).in_volume
    assert inside[:, :7].all() and not inside[:, 7].any()
    np.testing.assert_array_equal(t.in_volume_rows(img[3:9], row0=3), inside[3:9])


def test_smallest_table_two_nodes_each_way():
    """A 2 x 2 px camera with one node per pixel (cell 1 px): one cell, the shear's
    normalised coordinates are -1 and +1 exactly."""
    t = random_table(seed=8, width=2, height=2, cell=1.0)
    assert t.node_u.size == 2 and t.node_v.size == 2
    rng = np.random.default_rng(9)
    xp = shear_at(t, *np.indices((2, 2))[::-1]) + rng.uniform(-4, 4, (2, 2))
    look = t.apply_image(xp)
    v, u = np.indices((2, 2), dtype=float)
    _check(look, u, v, xp, t, extrapolate=False)
    u, v = rng.uniform(-0.5, 1.5, 50), rng.uniform(-0.5, 1.5, 50)
    xp = shear_at(t, u, v) + rng.uniform(-14, 14, 50)
    _check(t.apply(u, v, xp, extrapolate=True), u, v, xp, t, extrapolate=True)


def test_whole_image_in_bands_with_an_uncalibrated_node(recwarn):
    """A 200 x 100 px camera is two bands of rows (scanqa.chunks); pixels in the cells of
    the node without data are NaN and out of the volume, silently; in_volume is boolean
    (it indexes the points) and the packed table is float32 (half the memory traffic)."""
    t = random_table(seed=10, width=200, height=100)
    xp = _phase_image(t, 11, width=200, height=100)
    look = t.apply_image(xp)
    v, u = np.indices(xp.shape, dtype=float)
    _check(look, u, v, xp, t, extrapolate=False)
    assert look.in_volume.dtype == bool and look.xyz[~look.in_volume].shape[1] == 3
    corner = np.s_[92:, 188:]  # the cell of the last node (99.5, 195.5); cell 8 px
    assert not look.in_volume[corner].any() and np.isnan(look.xyz[corner]).all()
    ext = t.apply_image(xp, extrapolate=True)
    assert np.isnan(ext.xyz[corner]).all()
    assert t.packed.coef.dtype == np.float32
    assert [str(w.message) for w in recwarn] == []
