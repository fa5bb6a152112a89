"""The renderer's compiled loops (scanqa.simulator.raykernels) against the numpy path.

The reference is the renderer's numpy geometry (``render._geometry``, which the ground
truth uses and the exact-truth tests in test_simulate.py check against ray-plane
intersections written out from scratch) and numpy's own float32 expressions for the
frame loops.
"""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.simulator import devices, experiments, raykernels, render


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
