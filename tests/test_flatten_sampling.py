"""The sampling error of a std measured on a correlated noise field
(:func:`scanqa.annotation.filterbank.effective_pixels`,
:func:`~scanqa.annotation.filterbank.std_interval`),
against truth computed here independently: white Gaussian noise filtered by a known disc
(scipy), whose effective number of independent pixels is n / sum_lag rho^2 with rho the
kernel's normalised autocorrelation, and the scatter of the std over many such fields."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage, signal

from scanqa.annotation.filterbank import disc_kernel, effective_pixels, std_interval

SIZE = 96


def _fields(kernel: np.ndarray, count: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    pad = kernel.shape[0]
    return [ndimage.convolve(rng.normal(size=(SIZE + 2 * pad,) * 2), kernel)[pad:-pad, pad:-pad]
            for _ in range(count)]


def test_white_noise_has_every_pixel_independent():
    n, n_eff = effective_pixels(_fields(np.ones((1, 1)), 1, 0)[0])
    assert n == SIZE * SIZE
    # only the lags' estimation noise is left after the bias correction
    assert n_eff == pytest.approx(n, rel=0.10)


@pytest.mark.parametrize("diameter_px", [4.0, 7.0])
def test_a_filtered_field_has_the_kernels_effective_pixels(diameter_px):
    kernel = disc_kernel(diameter_px)
    auto = signal.correlate(kernel, kernel)
    truth = SIZE * SIZE / np.sum((auto / auto.max()) ** 2)  # 450 for the 7 px disc
    measured = [effective_pixels(f)[1] for f in _fields(kernel, 20, 1)]
    # the field's finite edges and the estimate's own noise: within 10 %
    np.testing.assert_allclose(np.mean(measured), truth, rtol=0.10)


def test_the_std_scatters_as_the_effective_pixels_say():
    """300 fields filtered by a 7 px disc: the relative std of their measured std is
    1 / sqrt(2 n_eff) (0.033 here), within the Monte Carlo's own 6 % error x 2."""
    fields = _fields(disc_kernel(7.0), 300, 2)
    stds = np.array([f.std() for f in fields])
    n_eff = np.mean([effective_pixels(f)[1] for f in fields[:30]])
    np.testing.assert_allclose(stds.std(ddof=1) / stds.mean(), 1 / np.sqrt(2 * n_eff),
                               rtol=0.12)
    low, high = zip(*(std_interval(s, n_eff) for s in stds), strict=True)
    covered = np.mean((np.array(low) <= 1.0 * stds.mean()) & (np.array(high) >= stds.mean()))
    assert 0.90 <= covered <= 0.99  # a 95 % interval: 300 draws, +-2.5 % binomial


def test_nan_pixels_are_left_out_and_tiny_fields_are_their_own_count():
    field = _fields(disc_kernel(4.0), 1, 3)[0]
    holed = field.copy()
    holed[:, :10] = np.nan
    n, n_eff = effective_pixels(holed)
    assert n == SIZE * (SIZE - 10) and 0 < n_eff < n
    assert effective_pixels(np.array([[1.0, np.nan]])) == (1, 1.0)
    lo, hi = std_interval(2.0, 450.0)
    assert lo < 2.0 < hi and hi - 2.0 > 2.0 - lo  # chi-square: longer above


# ------------------------------------------------ the filter's gain on the scene noise


def _scene_field(cell_px: float, blur_px: float, airy_px: float, size: int, seed: int,
                 fine: int = 4) -> np.ndarray:
    """Scene noise built here from its definition: i.i.d. values per square cell of
    ``cell_px`` (a random grid offset), on a grid of ``fine`` samples per pixel, blurred
    by the defocus disc and the Airy pattern (scipy), averaged over each pixel."""
    from scipy.special import j1

    rng = np.random.default_rng(seed)
    n = size * fine
    u = (np.arange(n) + 0.5) / fine + rng.uniform(0, cell_px, 2)[:, None]
    iy, ix = np.floor(u / cell_px).astype(int)
    values = rng.normal(size=(iy.max() + 1, ix.max() + 1))
    field = values[np.ix_(iy, ix)]
    reach = int((max(blur_px / 2, 2.2 * airy_px) + 1) * fine)  # the Airy's 5th ring
    r = np.arange(-reach, reach + 1) / fine
    rho = np.hypot(r[:, None], r[None, :])
    disc = (rho <= blur_px / 2).astype(float) if blur_px > 0.25 else (rho == 0).astype(float)
    x = np.maximum(rho * 3.8317 / (airy_px / 2), 1e-9)
    airy = np.where(x <= 16.4706, (2 * j1(x) / x) ** 2, 0.0)
    for kern in (disc, airy):
        field = signal.fftconvolve(field, kern / kern.sum(), mode="same")
    return field.reshape(size, fine, size, fine).mean(axis=(1, 3))


@pytest.mark.parametrize("z_mm, level", [(450.0, 9.2), (455.0, 8.5)])
def test_the_filters_gain_on_scene_noise_is_the_exact_second_order_one(z_mm, level):
    """The paper's f/11 camera, cells of gamma = 2.10 px at focus: the std of the scene
    noise built here, filtered by the bank's blend at ``level``, over its std unfiltered
    (16 fields of 128 px, Monte Carlo error ~0.5 %), against scene_gain within 1.5 %, and
    closer than the smooth law (areas add) at both depths (docs/flattening.rst)."""
    from dataclasses import replace

    from scanqa.annotation.filterbank import default_bank, reduction, scene_gain
    from scanqa.model import optics
    from scanqa.model.config import load_config
    from tests.conftest import ROOT

    cfg = load_config(ROOT / "calib" / "paper_scanner.toml", profile="f11")
    cfg = cfg.replace_model(gamma=2.10, filter_floor="smooth", filter_form="sum",
                            noise_reading="two_source")
    cam, pixel = cfg.camera, cfg.camera.pixel_um * 1e-3
    cell = 2.10 * cam.focus_mm / z_mm
    blur = float(optics.image_blur_diameter(z_mm, cam.focal_mm, cam.focus_mm,
                                            cam.aperture_mm)) / pixel
    airy = optics.airy_diameter(cfg.model.wavelength_nm * 1e-6, cam.f_number) / pixel
    bank = default_bank()
    k, w = int(level), level - int(level)
    size = bank.kernels[k + 1].shape[0]
    kern = (1 - w) * np.pad(bank.kernels[k], (size - bank.kernels[k].shape[0]) // 2) \
        + w * bank.kernels[k + 1]
    ratios = []
    for seed in range(16):
        field = _scene_field(cell, blur, airy, 128, seed)
        ratios.append(signal.fftconvolve(field, kern, mode="valid").std()
                      / field[size:-size, size:-size].std())
    measured = float(np.mean(ratios))
    exact = float(scene_gain(np.array([z_mm]), np.array([level]), cfg, bank)[0])
    np.testing.assert_allclose(exact, measured, rtol=0.015)
    print(f"scene gain at {z_mm} mm, level {level}: built here {measured:.4f}, "
          f"exact {exact:.4f}", end=" ")
    from scanqa.annotation.filterbank import camera_noise_area_px2

    smooth = replace(cfg.model, filter_floor="one")  # the areas-add law, gamma held
    gaussian = reduction(camera_noise_area_px2(np.array(z_mm), cfg), np.array(1.0),
                         np.array(level), cfg.replace_model(gamma=cell), bank,
                         transfer=True)[0]
    assert smooth.filter_floor == "one"
    # measured here: 450 mm 0.426 (exact 0.428, the law 0.420), 455 mm 0.646 (0.644, 0.627)
    print(f"areas-add law {float(gaussian):.4f}")
    assert abs(exact / measured - 1) < abs(float(gaussian) / measured - 1), \
        (exact, float(gaussian), measured)
