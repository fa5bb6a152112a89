"""The sampling error of a std measured on a correlated noise field
(:func:`scanqa.runs.filterbank.effective_pixels`, :func:`~scanqa.runs.filterbank.std_interval`),
against truth computed here independently: white Gaussian noise filtered by a known disc
(scipy), whose effective number of independent pixels is n / sum_lag rho^2 with rho the
kernel's normalised autocorrelation, and the scatter of the std over many such fields."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage, signal

from scanqa.runs.filterbank import disc_kernel, effective_pixels, std_interval

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
