"""The renderer's compiled loops (scanqa.simulator.raykernels) against the numpy path.

The reference is the renderer's numpy geometry (``render._geometry``, which the ground
truth uses and the exact-truth tests in test_simulate.py check against ray-plane
intersections written out from scratch) and numpy's own float32 expressions for the
frame loops.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.simulator import blur, devices, experiments, raykernels, render, scene
from scanqa.simulator.optics_kernels import DiscAverage

from .cpu_targets import op_bound


def _window(config, size):
    """The paper scanner with a centred window of ``size`` px (same optics)."""
    return config.replace_simulator(roi_width_px=size, roi_height_px=size)


def _both(config, acq):
    """The numpy geometry and the compiled one of the window's first tile, with halo, and
    each ray's condition ``|d| / |n . d|`` (1 / cos of its incidence) [-]."""
    win = devices.sensor_window(config)
    tile = render._tiles(win)[0]
    uu, vv = render._supersample_grid(config, win, tile, render.halo_px(config, acq))
    ref = render._geometry(config, acq, uu, vv, 1)
    fast = raykernels.tile_geometry(config, acq.scene, acq.camera, acq.projector, uu, vv, 1)
    origins, dirs = devices.camera_rays(config, acq.camera, uu, vv)
    normals = acq.scene.cast(origins, dirs, threads=1).normals
    with np.errstate(invalid="ignore", divide="ignore"):
        cond = np.linalg.norm(dirs, axis=-1) / np.abs(np.einsum("...i,...i->...", normals,
                                                                dirs))
    return ref, render._Points(*fast), cond


def geometry_bounds(config, acq, ref, cond):
    """What two CPUs may give each field of the geometry [mm], [px], [-] (op_bound).

    t = n.(v0 - o) / n.d and world = o + t d: 16 operations on coordinates up to L (the
    scene's size from the world origin and the camera), times the ray's condition
    (a grazing ray moves its hit along the face). z_c and q = R (world - C): 8 more on
    |world - C|; x_p = f q0 / q2 + x0 moves by f / q2 (1 + |q0 / q2|) per mm of q;
    shade = n.(C - world) / |C - world|: 8 operations on 1, plus 2 |d world| / dist.
    """
    size = np.nanmax(np.abs(ref.world)) + np.abs(acq.camera.centre).max()
    d_world = op_bound(16, size * np.nan_to_num(cond, nan=1.0, posinf=1e12))
    p = ref.world - acq.projector.centre
    dist = np.linalg.norm(p, axis=-1)
    d_q = op_bound(8, dist) + d_world
    f = config.projector.principal_distance_px
    with np.errstate(invalid="ignore", divide="ignore"):
        gain = f / np.abs(ref.z_p) * (1.0 + np.abs((ref.x_p - config.projector.
                                                    principal_point_px[0]) / f))
        gain_y = f / np.abs(ref.z_p) * (1.0 + np.abs((ref.y_p - config.projector.
                                                      principal_point_px[1]) / f))
        return {"world": d_world[..., None], "z_c": d_q, "z_p": d_q,
                "x_p": gain * d_q + op_bound(3, np.abs(ref.x_p)),
                "y_p": gain_y * d_q + op_bound(3, np.abs(ref.y_p)),
                "shade": op_bound(8, 1.0) + 2.0 * d_world / dist}


def near_a_lighting_threshold(config, ref, fast, tol):
    """Samples whose lit flag may flip on another CPU: within their bound of the panel's
    edges, of facing the projector or of z_p = 0 (booleans away from those are exact)."""
    proj = config.projector
    with np.errstate(invalid="ignore"):
        near = ((np.abs(ref.x_p + 0.5) <= tol["x_p"])
                | (np.abs(ref.x_p - (proj.width_px - 0.5)) <= tol["x_p"])
                | (np.abs(ref.y_p + 0.5) <= tol["y_p"])
                | (np.abs(ref.y_p - (proj.height_px - 0.5)) <= tol["y_p"])
                | (np.abs(ref.z_p) <= tol["z_p"]))
    # facing: a lit sample of either path whose shade is within its bound of 0
    return near | (ref.lit & (ref.shade <= tol["shade"])) | (fast.lit & (fast.shade
                                                                         <= tol["shade"]))


@pytest.mark.compiled_vs_numpy
@pytest.mark.parametrize(("name", "position", "size", "shadows"), [
    ("gauge-blocks", 0.0, 200, True),    # box edges, block walls, shadows of the blocks
    ("camera-sweep", 7.0, 64, False),    # a tilted flat, the camera moved along its axis
    ("sphere", 450.0, 400, True),        # 327680 faces, fewer than rays; its rim unlit
    ("sphere", 450.0, 4, False),         # fewer rays than faces: the per-ray numerators
])
def test_tile_geometry_equals_numpy_geometry(paper_config, name, position, size, shadows):
    config = _window(paper_config, size)
    pos = experiments.build_positions(name, config, [position])[0]
    acq = experiments.acquisition(config, pos, 0, name)
    ref, fast, cond = _both(config, acq)
    assert ref.lit.any() and (ref.hit & ~ref.lit).any() == shadows  # as the case says
    # open3d's answer for the same float32 rays: the same triangles, exactly
    np.testing.assert_array_equal(fast.hit, ref.hit)
    tol = geometry_bounds(config, acq, ref, cond)
    # lit compares facing (shade > 0) and the panel's edges: a flag may flip only where a
    # sample lies within its bound of a threshold; unlit samples' shade is set to 0
    edge = near_a_lighting_threshold(config, ref, fast, tol)
    assert edge.sum() <= 1e-3 * edge.size  # the exemption is a few samples at most
    np.testing.assert_array_equal(fast.lit[~edge], ref.lit[~edge])
    for field in ("world", "z_c", "x_p", "y_p", "z_p", "shade"):
        got, want = getattr(fast, field), getattr(ref, field)
        keep = ~edge[..., None] if field == "world" else ~edge
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want), err_msg=field)
        excess = np.abs(got - want) - np.broadcast_to(tol[field], want.shape)
        assert not (np.nan_to_num(excess, nan=-1.0)[np.broadcast_to(keep, want.shape)]
                    > 0).any(), (field, np.nanmax(excess))


@pytest.mark.compiled_vs_numpy
def test_frame_loops_repeat_numpys_float32_arithmetic():
    # exact on every IEEE-754 CPU: float32 multiplies and adds, each rounded once, in
    # numpy's order (numba contracts no multiply-add without fastmath)
    rng = np.random.default_rng(5)
    base = rng.uniform(0, 4e4, (300, 310)).astype(np.float32)
    q_re, q_im = (rng.normal(0, 1e4, base.shape).astype(np.float32) for _ in range(2))
    c, s = np.float32(np.cos(2.1)), np.float32(np.sin(2.1))
    expected = base.copy()
    expected += c * q_re
    expected -= s * q_im
    got = base.copy()
    raykernels.add_fringe(got, c, q_re, s, q_im)
    np.testing.assert_array_equal(got, expected)  # float32 operations in numpy's order

    cells = rng.normal(size=(7, 9)).astype(np.float32)
    index = rng.integers(0, cells.size, base.shape).astype(np.intp)
    scale = rng.uniform(0, 300, base.shape).astype(np.float32)
    expected = got + cells.ravel()[index] * scale
    raykernels.add_cell_noise(got, cells, index, scale)
    np.testing.assert_array_equal(got, expected)


@pytest.mark.compiled_vs_numpy
@pytest.mark.parametrize("shape", [(768, 768), (300, 93), (3, 3)])
def test_pixel_means_repeat_numpys_float32_mean(shape):
    rng = np.random.default_rng(6)
    fine = rng.uniform(0, 4e4, shape).astype(np.float32)
    out = rng.uniform(0, 4e4, (shape[0] // 3, shape[1] // 3)).astype(np.float32)
    expected = out + fine.reshape(shape[0] // 3, 3, shape[1] // 3, 3).mean(axis=(1, 3))
    raykernels.add_pixel_means(out, fine, 3)
    # numpy's reduction order follows its SIMD kernels (another CPU, another order): 9
    # adds of terms up to max(fine), a divide and the add to out, in float32
    tol = op_bound(3 * 3 + 2, np.abs(expected) + fine.max(), np.float32)
    assert np.all(np.abs(out - expected) <= tol), np.max(np.abs(out - expected) / tol)


@pytest.mark.compiled_vs_numpy
def test_phasor_parts_repeat_numpys_interp_and_reduction():
    table = DiscAverage(37)
    rng = np.random.default_rng(7)
    n = 20000
    lit = rng.random(n) < 0.8
    d_panel = np.where(lit, rng.uniform(0, 20, n), 0.0)
    d_panel[:5] = [0.0, table.u[7] * 6 / np.pi, 1e3, table.u[-1] * 6 / np.pi, 2.5]  # grid
    lit[:5] = True                                     # points, beyond the table's end
    x_p = rng.uniform(-0.5, 1279.5, n)
    for harmonic in (1, 3):
        contrast, angle = raykernels.phasor_parts(lit, d_panel, x_p, harmonic, 6.0,
                                                  table.u, table.m)
        # the numpy expressions the renderer used before (np.interp, float64 reduction)
        ref_c = np.where(lit, np.interp(np.pi * d_panel * harmonic / 6.0, table.u, table.m),
                         0.0).astype(np.float32)
        cycles = np.where(lit, x_p, 0.0) * (harmonic / 6.0)
        ref_a = ((cycles - np.floor(cycles)) * (2.0 * np.pi)).astype(np.float32)
        # np.interp is C that a compiler may contract to a fused multiply-add (aarch64):
        # 5 float64 operations on values <= 1, then the float32 rounding, which a float64
        # difference can push across one float32 step
        tol = op_bound(5, 1.0) + np.spacing(np.abs(ref_c))
        np.testing.assert_array_less(np.abs(contrast - ref_c), tol + 1e-300)
        # exact: multiplies, a floor and a subtraction in numpy's order, each rounded once
        np.testing.assert_array_equal(angle, ref_a)


def _numpy_groups(diameter, hit):
    """blur._groups as numpy computed it: ladder positions, a stable argsort by layer."""
    flat = np.flatnonzero(hit)
    lam = blur.layer_coord(diameter.ravel()[flat])
    level = np.floor(lam).astype(np.int64)
    order = np.argsort(level, kind="stable")
    flat, level, frac = flat[order], level[order], (lam - level)[order]
    return [(int(lev), flat[level == lev], frac[level == lev]) for lev in np.unique(level)]


def _per_sample(groups, n):
    """Each flat sample's (ladder layer, fraction) from groups; layer -1 where absent."""
    level, frac = np.full(n, -1, np.int64), np.full(n, np.nan)
    for lev, idx, f in groups:
        assert np.all(np.diff(idx) > 0)  # within a layer, in flat order (a stable sort)
        level[idx], frac[idx] = lev, f
    return level, frac


@pytest.mark.compiled_vs_numpy
@pytest.mark.parametrize("shape", [(300, 300), (5, 7), (1, 1)])
def test_ladder_groups_equal_numpys_sort(shape):
    rng = np.random.default_rng(8)
    diameter = rng.uniform(0, 60, shape)
    diameter.flat[0] = 4.0  # the end of the ladder's linear part
    hit = rng.random(shape) < 0.7
    hit.flat[0] = True
    got = blur._groups(diameter, hit)
    expected = _numpy_groups(diameter, hit)
    level, frac = _per_sample(got, diameter.size)
    level_ref, frac_ref = _per_sample(expected, diameter.size)
    np.testing.assert_array_equal(level >= 0, hit.ravel())  # every hit sample, once
    # lam = lin + log(d / d_lin) / log(ratio): numpy's log is a SIMD kernel chosen per
    # CPU, numba's libm's (issue 46: 1.8e-15 apart on an AMD EPYC): 4 operations on |lam|
    lam = blur.layer_coord(diameter.ravel())
    tol = op_bound(4, np.abs(lam))
    # a sample may change layer only within its bound of a layer's edge; then its
    # fraction is ~0 in one path and ~1 in the other
    edge = np.abs(lam - np.rint(lam)) <= tol
    same = hit.ravel() & ~edge
    np.testing.assert_array_equal(level[same], level_ref[same])
    assert np.all(np.abs(level - level_ref)[edge] <= 1)
    assert np.all(np.abs(frac - frac_ref)[same] <= tol[same])
    assert blur._groups(diameter, np.zeros(shape, bool)) == []


def _splitmix_normal(key: int, ix: int, iy: int) -> float:
    """The scene noise's value of one cell, written out in Python integers and math."""
    def mix(x):
        x = (x + 0x9E3779B97F4A7C15) % 2**64
        x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) % 2**64
        x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) % 2**64
        return x ^ (x >> 31)
    h = mix(mix(key ^ (ix % 2**64)) ^ (iy % 2**64))
    u1 = ((h >> 11) + 1.0) * 2.0 ** -53
    u2 = (mix(h) >> 11) * 2.0 ** -53
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@pytest.mark.compiled_vs_numpy
def test_hash_normal_is_splitmix64_box_muller():
    rng = np.random.default_rng(9)
    ix = rng.integers(-2**40, 2**40, (300, 200))
    iy = rng.integers(-5000, 5000, ix.shape)
    key = 0x5DEECE66D1234567
    got = raykernels.hash_normal(key, ix, iy)
    assert got.dtype == np.float32 and got.shape == ix.shape
    want = raykernels.hash_normal_numpy(key, ix, iy)
    # log, sqrt, cos (libm or SIMD, per CPU) and 3 products on values below 9 (sqrt(-2
    # log 2**-53) = 8.6) in float64, then one float32 rounding that a float64 difference
    # may push across a float32 step
    tol = op_bound(6, 9.0) + np.spacing(np.abs(want))
    assert np.all(np.abs(got - want) <= tol)
    some = [(int(a), int(b)) for a, b in zip(ix.ravel()[:40], iy.ravel()[:40], strict=True)]
    direct = np.array([_splitmix_normal(key, a, b) for a, b in some], np.float32)
    assert np.all(np.abs(got.ravel()[:40] - direct) <= tol.ravel()[:40])
    assert abs(float(got.mean())) < 0.02 and abs(float(got.std()) - 1.0) < 0.02  # N(0, 1)



def test_chunked_cast_equals_one_open3d_call(paper_config, monkeypatch):
    # Inside the tile pool (threads=1) open3d is called in chunks so that it lets go of
    # the GIL between them; the reference is one open3d call over all the rays
    # (threads=0 is never chunked). A tile's camera rays with its halo, in chunks of
    # 4099 rays, so that the last chunk is partial; some rays miss.
    config = _window(paper_config, 96)
    pos = experiments.build_positions("gauge-blocks", config, [0.0])[0]
    acq = experiments.acquisition(config, pos, 0, "gauge-blocks")
    monkeypatch.setattr(acq.scene, "boxes", None)  # open3d's path (test_simulator_boxcast)
    win = devices.sensor_window(config)
    uu, vv = render._supersample_grid(config, win, render._tiles(win)[0],
                                      render.halo_px(config, acq))
    origins, dirs = devices.camera_rays(config, acq.camera, uu, vv)
    dirs = np.array(dirs)
    dirs[:, :40] *= -1.0  # a band of rays that look away from the scene: misses
    rays = raykernels.camera_rays32(np.ascontiguousarray(origins.reshape(-1, 3)[0]),
                                    np.ascontiguousarray(dirs).reshape(-1, 3))
    ref_prim, ref_t = acq.scene.first_hits(rays, 0)
    ref_cast = acq.scene.cast(origins, dirs, threads=0)
    calls = []
    cast_rays = acq.scene._raycast.cast_rays
    monkeypatch.setattr(scene, "CAST_CHUNK_RAYS", 4099)
    monkeypatch.setattr(acq.scene, "_raycast", _Counting(cast_rays, calls))
    prim, t = acq.scene.first_hits(rays, 1)
    assert len(calls) == -(-rays.shape[0] // 4099) and max(calls) == 4099  # chunked
    np.testing.assert_array_equal(prim, ref_prim)
    np.testing.assert_array_equal(t, ref_t)
    assert (ref_prim != raykernels.NO_HIT).any() and (ref_prim == raykernels.NO_HIT).any()
    hits = acq.scene.cast(origins, dirs, threads=1)
    for field in ("t", "hit", "normals", "face"):
        np.testing.assert_array_equal(getattr(hits, field), getattr(ref_cast, field))


class _Counting:
    """open3d's ``cast_rays`` that records the rays of every call."""

    def __init__(self, cast_rays, calls: list) -> None:
        self._cast_rays, self._calls = cast_rays, calls

    def cast_rays(self, rays, nthreads: int = 0):
        self._calls.append(rays.shape[0])
        return self._cast_rays(rays, nthreads=nthreads)
