"""The renderer's compiled loops (scanqa.simulator.raykernels) against the numpy path.

The reference is the renderer's numpy geometry (``render._geometry``, which the ground
truth uses and the exact-truth tests in test_simulate.py check against ray-plane
intersections written out from scratch) and numpy's own float32 expressions for the
frame loops.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.simulator import blur, devices, experiments, raykernels, render, scene
from scanqa.simulator.optics_kernels import DiscAverage


def _window(config, size):
    """The paper scanner with a centred window of ``size`` px (same optics)."""
    return config.replace_simulator(roi_width_px=size, roi_height_px=size)


def _both(config, acq):
    """The numpy geometry and the compiled one of the window's first tile, with halo."""
    win = devices.sensor_window(config)
    tile = render._tiles(win)[0]
    uu, vv = render._supersample_grid(config, win, tile, render.halo_px(config, acq))
    ref = render._geometry(config, acq, uu, vv, 1)
    fast = raykernels.tile_geometry(config, acq.scene, acq.camera, acq.projector, uu, vv, 1)
    return ref, render._Points(*fast)


@pytest.mark.parametrize(("name", "position", "size", "shadows"), [
    ("gauge-blocks", 0.0, 200, True),    # box edges, block walls, shadows of the blocks
    ("camera-sweep", 7.0, 64, False),    # a tilted flat, the camera moved along its axis
    ("sphere", 450.0, 400, True),        # 327680 faces, fewer than rays; its rim unlit
    ("sphere", 450.0, 4, False),         # fewer rays than faces: the per-ray numerators
])
def test_tile_geometry_equals_numpy_geometry(paper_config, name, position, size, shadows):
    config = _window(paper_config, size)
    pos = experiments.build_positions(name, config, [position])[0]
    ref, fast = _both(config, experiments.acquisition(config, pos, 0, name))
    assert ref.lit.any() and (ref.hit & ~ref.lit).any() == shadows  # as the case says
    np.testing.assert_array_equal(fast.hit, ref.hit)
    np.testing.assert_array_equal(fast.lit, ref.lit)
    for field in ("world", "z_c", "x_p", "y_p", "z_p", "shade"):
        # the same float64 formulas in the same order: equal bits on x86-64 (measured);
        # rtol 1e-15 (~4 ulp) leaves room for a BLAS that sums a matrix product otherwise
        np.testing.assert_allclose(getattr(fast, field), getattr(ref, field), rtol=1e-15,
                                   atol=0, err_msg=field)


def test_frame_loops_repeat_numpys_float32_arithmetic():
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


@pytest.mark.parametrize("shape", [(768, 768), (300, 93), (3, 3)])
def test_pixel_means_repeat_numpys_float32_mean(shape):
    rng = np.random.default_rng(6)
    fine = rng.uniform(0, 4e4, shape).astype(np.float32)
    out = rng.uniform(0, 4e4, (shape[0] // 3, shape[1] // 3)).astype(np.float32)
    expected = out + fine.reshape(shape[0] // 3, 3, shape[1] // 3, 3).mean(axis=(1, 3))
    raykernels.add_pixel_means(out, fine, 3)
    np.testing.assert_array_equal(out, expected)  # numpy's summation order, bit for bit


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
        np.testing.assert_array_equal(contrast, ref_c)
        np.testing.assert_array_equal(angle, ref_a)


def _numpy_groups(diameter, hit):
    """blur._groups as numpy computed it: ladder positions, a stable argsort by layer."""
    flat = np.flatnonzero(hit)
    lam = blur.layer_coord(diameter.ravel()[flat])
    level = np.floor(lam).astype(np.int64)
    order = np.argsort(level, kind="stable")
    flat, level, frac = flat[order], level[order], (lam - level)[order]
    return [(int(lev), flat[level == lev], frac[level == lev]) for lev in np.unique(level)]


@pytest.mark.parametrize("shape", [(300, 300), (5, 7), (1, 1)])
def test_ladder_groups_equal_numpys_sort(shape):
    rng = np.random.default_rng(8)
    diameter = rng.uniform(0, 60, shape)
    diameter.flat[0] = 4.0  # the end of the ladder's linear part
    hit = rng.random(shape) < 0.7
    hit.flat[0] = True
    got = blur._groups(diameter, hit)
    expected = _numpy_groups(diameter, hit)
    assert [g[0] for g in got] == [e[0] for e in expected]
    for (_, idx, frac), (_, idx_ref, frac_ref) in zip(got, expected, strict=True):
        np.testing.assert_array_equal(idx, idx_ref)
        np.testing.assert_array_equal(frac, frac_ref)  # the same float64 operations
    assert blur._groups(diameter, np.zeros(shape, bool)) == []


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
