"""Table lookups (bilinear in (u, v), cubic Hermite in s) against a brute-force reference.

The reference evaluates a small random table point by point as docs/calibration.rst
describes it, with other tools than the code: scipy's CubicHermiteSpline per node for Z
and dZ/ds, a straight line through the two nearest s nodes for the table's sigma, numpy's
polyval2d for the shear, and the bilinear weights and the per-node lateral rays written
out per point. The code packs the table into float32 Hermite coefficients, gathers per
band of rows and blends in float32, so the two agree to float32 rounding (~1e-6 mm).
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


def random_table(seed: int = 0) -> CalibrationTable:
    """A table over a 40 x 30 px camera with 5 x 4 nodes, 13 s nodes, a random shear, random
    smooth values per node and random calibrated ranges (one node without any)."""
    rng = np.random.default_rng(seed)
    node_u = np.arange(5) * CELL + (CELL - 1) / 2
    node_v = np.arange(4) * CELL + (CELL - 1) / 2
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
    s_lo[3, 4] = s_hi[3, 4] = np.nan  # a node that was never calibrated
    shear = np.zeros((DEGREE + 1) * (DEGREE + 2) // 2)
    shear[:6] = [600.0, 4.0, -1.5, 30.0, 0.8, 2.5]  # terms 1, v, v^2, v^3, v^4, u (module order)
    shear[6:] = rng.normal(0, 0.5, shear.size - 6)
    return CalibrationTable(node_u, node_v, np.zeros((n_v, n_u)), S_NODES, xyz, dxyz, sigma,
                            s_lo, s_hi, shear, WIDTH, HEIGHT, "none", {}, {})


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


_SPLINES: dict = {}


def _spline(t: CalibrationTable, node: tuple[int, int]) -> CubicHermiteSpline:
    """Z(s) of one node: the cubic Hermite spline through its values and slopes."""
    key = (id(t), node)
    if key not in _SPLINES:  # (the table is kept with its splines: its id stays unique)
        _SPLINES[key] = (t, CubicHermiteSpline(S_NODES, t.xyz[node][:, 2],
                                               t.dxyz[node][:, 2], extrapolate=True))
    return _SPLINES[key][1]


def reference(t: CalibrationTable, u: float, v: float, xp: float) -> dict:
    """One point by brute force: the cell and fractions, four nodes, their Hermite Z(s),
    linear sigma(s) and lateral rays, blended with bilinear weights."""
    s = xp - float(shear_at(t, u, v))
    fu, fv = (u - t.node_u[0]) / CELL, (v - t.node_v[0]) / CELL
    iu = int(min(max(np.floor(fu), 0), t.node_u.size - 2))  # edge cells extrapolate
    iv = int(min(max(np.floor(fv), 0), t.node_v.size - 2))
    tu, tv = fu - iu, fv - iv
    centre = S_NODES.size // 2
    h = S_NODES[1] - S_NODES[0]
    k = int(min(max(np.floor((s - S_NODES[0]) / h), 0), S_NODES.size - 2)) \
        if np.isfinite(s) else 0
    out = {"z": 0.0, "dz": 0.0, "sig": 0.0, "x0": 0.0, "kx": 0.0, "y0": 0.0, "ky": 0.0}
    lo, hi = -np.inf, np.inf
    for dv, du, w in ((0, 0, (1 - tv) * (1 - tu)), (0, 1, (1 - tv) * tu),
                      (1, 0, tv * (1 - tu)), (1, 1, tv * tu)):
        node = (iv + dv, iu + du)
        spline = _spline(t, node)
        sig = t.sigma_node[node]
        frac = (s - S_NODES[k]) / h
        kx = t.dxyz[node][centre, 0] / t.dxyz[node][centre, 2]
        ky = t.dxyz[node][centre, 1] / t.dxyz[node][centre, 2]
        zc = t.xyz[node][centre, 2]
        out["z"] += w * spline(s)
        out["dz"] += w * spline(s, 1)
        out["sig"] += w * (sig[k] + frac * (sig[k + 1] - sig[k]))
        out["x0"] += w * (t.xyz[node][centre, 0] - kx * zc)
        out["kx"] += w * kx
        out["y0"] += w * (t.xyz[node][centre, 1] - ky * zc)
        out["ky"] += w * ky
        # a node never calibrated (NaN) leaves no calibrated range in its cells
        lo, hi = np.maximum(lo, t.s_lo[node]), np.minimum(hi, t.s_hi[node])
    inside = bool(lo <= s <= hi)
    z, dz = out["z"], out["dz"]
    return {"xyz": np.array([out["x0"] + out["kx"] * z, out["y0"] + out["ky"] * z, z]),
            "slope": np.array([out["kx"] * dz, out["ky"] * dz, dz]),
            "sigma": out["sig"], "inside": inside}


def _check(look, u, v, xp, table, extrapolate: bool) -> None:
    for i, (uu, vv, x) in enumerate(zip(u.ravel(), v.ravel(), xp.ravel(), strict=True)):
        ref = reference(table, uu, vv, x)
        got_xyz = look.xyz.reshape(-1, 3)[i]
        assert look.in_volume.ravel()[i] == ref["inside"], (uu, vv, x)
        if not (ref["inside"] or extrapolate) or not np.isfinite(x):
            assert np.isnan(got_xyz).all() or not np.isfinite(x)
            if not extrapolate:
                assert np.isnan(look.sigma_table.ravel()[i])
                assert np.isnan(look.slope.reshape(-1, 3)[i]).all()
            continue
        # float32 coefficients of Z - mean(Z) (|Z - mean| < 60 mm): ~4e-6 mm
        np.testing.assert_allclose(got_xyz, ref["xyz"], rtol=0, atol=2e-5)
        np.testing.assert_allclose(look.slope.reshape(-1, 3)[i], ref["slope"], rtol=1e-5,
                                   atol=1e-6)
        np.testing.assert_allclose(look.sigma_table.ravel()[i], ref["sigma"], rtol=1e-5)


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


def _phase_image(table, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v, u = np.indices((HEIGHT, WIDTH), dtype=float)
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
    for iv, iu, k in ((0, 0, 6), (2, 3, 1), (1, 4, 11), (3, 0, 2)):
        u, v = table.node_u[iu], table.node_v[iv]
        xp = S_NODES[k] + shear_at(table, u, v)
        look = table.apply(u, v, xp, extrapolate=True)
        np.testing.assert_allclose(look.xyz[2], table.xyz[iv, iu, k, 2], atol=1e-5)
        np.testing.assert_allclose(look.slope[2], table.dxyz[iv, iu, k, 2], rtol=1e-5)
        np.testing.assert_allclose(look.sigma_table, table.sigma_node[iv, iu, k], rtol=1e-5)
