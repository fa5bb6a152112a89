"""The simulator's layered camera blur against a direct float64 computation of the same
operator, and the background writer of ``scanqa simulate``.

The reference below splits every supersample between the two ladder layers around its
own diameter (the definition in docs/simulator.rst, step 4), convolves each layer's
weighted light with its kernel by a direct linear convolution in float64, and takes the
mean of each pixel's s x s supersamples on the tile's core. The renderer's plan instead
merges faces of one diameter into one item, sums large items in the frequency domain in
float32 and folds the pixel integration into the spectrum, and convolves small items
on their bounding boxes; it must give the same pixels to float32 rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import fftconvolve

from scanqa.errors import InputError
from scanqa.simulator import blur, experiments
from scanqa.simulator.optics_kernels import airy_kernel, camera_kernel

S = 3  # supersamples per pixel and axis (the simulator's default)
#: A level of the paper scanner's images [e-]: its shot noise is sqrt(2e4) = 141 e-.
LEVEL_E = 2.0e4


def _reference(radiance, diameter, hit, airy, margin):
    """Direct float64 layered blur, then the pixel means on the core [e-]."""
    lam = blur.layer_coord(np.where(hit, diameter, 0.0))
    i0 = np.floor(lam).astype(int)
    frac = lam - i0
    out = np.zeros(radiance.shape)
    for lev in np.unique(i0[hit]):
        for layer, w in ((lev, np.where(hit & (i0 == lev), 1.0 - frac, 0.0)),
                         (lev + 1, np.where(hit & (i0 == lev), frac, 0.0))):
            kern = camera_kernel(blur.layer_diameter(int(layer)), airy)
            out += fftconvolve(radiance * w, kern, mode="same")
    core = out[margin:-margin, margin:-margin]
    rows, cols = core.shape[0] // S, core.shape[1] // S
    return core.reshape(rows, S, cols, S).mean(axis=(1, 3))


def _scene_tile(px_rows, px_cols, halo_px, seed):
    """A tile of three kinds of surface: a face of one diameter (a block's top), a slope
    of varying diameter (a wall) and a small patch of another diameter; misses between."""
    rng = np.random.default_rng(seed)
    shape = ((px_rows + 2 * halo_px) * S, (px_cols + 2 * halo_px) * S)
    rr, cc = np.mgrid[:shape[0], :shape[1]]
    diameter = np.full(shape, 13.7)  # the face: every sample at one ladder position
    slope = cc > 0.6 * shape[1]
    diameter[slope] = 9.0 + 0.3 * (cc[slope] - 0.6 * shape[1])
    patch = (abs(rr - 0.3 * shape[0]) < 4) & (abs(cc - 0.3 * shape[1]) < 5)
    diameter[patch] = 21.0
    hit = ~((rr > 0.8 * shape[0]) & (cc < 0.2 * shape[1]))  # a corner sees nothing
    radiance = np.where(hit, LEVEL_E * rng.uniform(0.2, 1.8, shape), 0.0)
    return radiance, diameter, hit


@pytest.mark.parametrize(("px_rows", "px_cols", "halo_px"), [
    (24, 30, 6),   # kernels within the halo: tile-size transforms
    (25, 19, 3),   # the largest kernel wider than the halo (padded), odd FFT sizes
])
def test_blur_matches_direct_layered_convolution(px_rows, px_cols, halo_px):
    radiance, diameter, hit = _scene_tile(px_rows, px_cols, halo_px, seed=3)
    airy = airy_kernel(450e-6, 8.0, 0.008 / S)
    margin = halo_px * S
    plan = blur.blur_plan(diameter, hit, airy, margin, S)
    assert plan.summed and plan.crops  # both paths are exercised
    got = blur.blur(radiance.astype(np.float32), plan)
    want = _reference(radiance, diameter, hit, airy, margin)
    assert got.shape == (px_rows, px_cols)
    # float32 transforms of a 2e4 e- level: rounding of ~1e-3 e-; 0.05 e- is far below
    # the shot noise (141 e-) and the scene noise (~1000 e-) of the simulated images
    np.testing.assert_allclose(got, want, rtol=0, atol=0.05)


def test_one_diameter_face_is_one_item():
    """A face perpendicular to the camera axis (one diameter) costs one transform."""
    diameter = np.full((60, 60), 30.0)
    hit = np.ones((60, 60), bool)
    airy = airy_kernel(450e-6, 8.0, 0.008 / S)
    items = blur._items(diameter, hit)
    assert len(items) == 1
    (level, f), idx, w = items[0]
    assert idx.size == hit.size and np.all(w == 1.0)
    lam = float(blur.layer_coord(np.array(30.0)))
    assert level == int(np.floor(lam)) and f == pytest.approx(lam - level, abs=1e-12)
    # the item's kernel is the ladder's interpolation between its two layers
    k0 = camera_kernel(blur.layer_diameter(level), airy)
    k1 = camera_kernel(blur.layer_diameter(level + 1), airy)
    pad = (k1.shape[0] - k0.shape[0]) // 2
    want = f * k1
    want[pad:pad + k0.shape[0], pad:pad + k0.shape[0]] += (1 - f) * k0
    np.testing.assert_allclose(blur.item_kernel((level, f), airy), want, atol=1e-15)


def test_failed_write_publishes_nothing(paper_config, tmp_path, monkeypatch):
    """An error on the background writer reaches the caller; no folder is published."""
    def broken(path, arrays):
        raise InputError(f"cannot write {path}: disk full (test)")

    monkeypatch.setattr(experiments, "write_npz", broken)
    config = paper_config.replace_simulator(roi_width_px=16, roi_height_px=16)
    out = tmp_path / "gauge"
    with pytest.raises(InputError, match="disk full"):
        experiments.run_experiment("gauge-blocks", config, out, repeats=1)
    assert not out.exists()
