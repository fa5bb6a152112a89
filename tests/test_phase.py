"""Phase decoding (scanqa.phase, scanqa.unwrap) on synthetic images with known x_p.

Images come from the shared image model ``I_k = A + B cos(2 pi x_p / P + delta_k)``
(scanqa.io.patterns.synthesize_images); noise is added here with fixed seeds.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    SensorModel,
    Thresholds,
)
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.demodulate import demodulate, sample_variance
from scanqa.decoding.patternset import synthesize_images
from scanqa.decoding.phasemap import (
    MASK_INCONSISTENT,
    MASK_LOW_MODULATION,
    MASK_OUT_OF_RANGE,
    MASK_SATURATED,
    MASK_VALID,
    PhaseMap,
)
from scanqa.errors import InputError

WIDTH = 1280
SHAPE = (64, 256)  # 16384 pixels per image: std estimates good to ~0.6 %
UNEQUAL = (0.0, 1.2, 2.9, 4.4, 5.5)


def _three_periods(steps: int = 4, shifts: tuple = (), **kw) -> PatternDescription:
    sets = tuple(PhaseSet(f"p{p:g}", p, steps, shifts) for p in (1280.0, 80.0, 16.0))
    return PatternDescription(WIDTH, sets, **kw)


def _random_xp(seed: int = 0, low: float = 0.0, high: float = WIDTH - 1.0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(low, high, SHAPE)


def _gaussian_sensor(sigma_dn: float) -> SensorModel:
    """Read noise of sigma_dn [DN] and (practically) no shot noise."""
    gain = 1e9
    return SensorModel(bit_depth=16, gain_e_per_dn=gain, read_noise_e=sigma_dn * gain)


# --------------------------------------------------------------------- demodulation

def test_demodulate_matches_classical_four_step():
    # hand formula for delta_k = k pi / 2: phi = atan2(I3 - I1, I0 - I2)
    rng = np.random.default_rng(1)
    frames = rng.uniform(100, 200, (4, 8, 9))
    got = demodulate(frames)
    expected = np.mod(np.arctan2(frames[3] - frames[1], frames[0] - frames[2]), 2 * np.pi)
    np.testing.assert_allclose(got.phase_rad, expected, atol=1e-12)  # rounding only
    np.testing.assert_allclose(got.offset_dn, frames.mean(axis=0), rtol=1e-12)
    b = 0.5 * np.hypot(frames[3] - frames[1], frames[0] - frames[2])
    np.testing.assert_allclose(got.modulation_dn, b, rtol=1e-12)


@pytest.mark.parametrize("shifts", [(), UNEQUAL, (0.3, 2.0, 4.0)])
def test_demodulate_recovers_phase_offset_modulation(shifts):
    steps = len(shifts) or 6
    d = np.asarray(shifts or 2 * np.pi * np.arange(6) / 6)
    phi = np.linspace(0, 2 * np.pi, 500, endpoint=False).reshape(5, 100)
    frames = 700 + 300 * np.cos(phi + d[:, None, None])
    got = demodulate(frames, shifts or None)
    assert frames.shape[0] == steps
    err = np.angle(np.exp(1j * (got.phase_rad - phi)))
    np.testing.assert_allclose(err, 0, atol=1e-12)  # least squares is exact without noise
    np.testing.assert_allclose(got.offset_dn, 700, rtol=1e-12)
    np.testing.assert_allclose(got.modulation_dn, 300, rtol=1e-12)


def test_demodulate_sigma_is_closed_form_for_equal_shifts():
    # N >= 4 equal shifts: var(phi) = 2 sigma_I^2 / (N B^2), sigma_I^2 = r^2 + (A-black)/g
    sensor = SensorModel(gain_e_per_dn=2.0, read_noise_e=6.0, black_level_dn=50.0)
    frames = 650 + 200 * np.cos(np.linspace(0, 6, 40)[None, :, None]
                                + 2 * np.pi * np.arange(5)[:, None, None] / 5)
    got = demodulate(frames, sensor=sensor)
    var_i = 3.0 ** 2 + (650 - 50) / 2.0
    np.testing.assert_allclose(got.sigma_phase_rad, np.sqrt(2 * var_i / (5 * 200 ** 2)),
                               rtol=1e-9)


def test_sample_variance_terms():
    sensor = SensorModel(gain_e_per_dn=4.0, read_noise_e=8.0, black_level_dn=10.0)
    got = sample_variance(np.array([0.0, 110.0]), sensor, quantised=True)
    np.testing.assert_allclose(got, [4 + 1 / 12, 4 + 1 / 12 + 25.0])  # below black: read only


def test_demodulate_rejects_too_few_frames_and_wrong_shifts():
    with pytest.raises(InputError, match="N >= 3"):
        demodulate(np.zeros((2, 4, 4)))
    with pytest.raises(InputError, match="3 shifts_rad for 4 images"):
        demodulate(np.zeros((4, 4, 4)), shifts_rad=[0, 1, 2])


# ------------------------------------------------------------- noise-free exactness

@pytest.mark.parametrize("steps,shifts", [(3, ()), (4, ()), (5, UNEQUAL), (8, ())])
def test_noise_free_multi_period_is_exact(steps, shifts):
    desc = _three_periods(steps, shifts)
    xp = _random_xp(seed=steps, low=-0.45, high=WIDTH - 0.55)  # whole coded range
    pm = decode_images(desc, synthesize_images(desc, xp, 1500.0, 1000.0))
    assert pm.valid.all()
    np.testing.assert_allclose(pm.xp, xp, rtol=0, atol=1e-6)  # acceptance: 1e-6 px
    assert np.abs(pm.xp - xp).max() < 1e-9  # float64 throughout: far better in fact
    assert pm.period_px == 16.0


@settings(max_examples=25, deadline=None)
@given(steps=st.integers(3, 9), ratio=st.floats(2.0, 40.0), coarse=st.floats(1.0, 1.3),
       gain=st.floats(0.2, 50.0), seed=st.integers(0, 2 ** 16))
def test_noise_free_decoding_is_exact_for_any_steps_and_periods(steps, ratio, coarse, gain,
                                                               seed):
    # invariant: without noise the decoded x_p is the true one, whatever the number of
    # steps, the period ratio, the coarse period's margin and the image gain
    width = 800
    sets = (PhaseSet("c", coarse * width, steps), PhaseSet("f", coarse * width / ratio, steps))
    desc = PatternDescription(width, sets, sensor=_gaussian_sensor(1e-3))
    xp = np.random.default_rng(seed).uniform(-0.5, width - 0.5, (4, 64))
    pm = decode_images(desc, synthesize_images(desc, xp, 500.0 * gain, 400.0 * gain))
    assert pm.valid.all()
    np.testing.assert_allclose(pm.xp, xp, rtol=0, atol=1e-6)


@pytest.mark.parametrize("inverse", [True, False])
def test_noise_free_gray_code_is_exact(inverse):
    sets = (PhaseSet("p16", 16.0, 4), GrayCodeSet("g", 8, orders="p16", inverse=inverse))
    desc = PatternDescription(WIDTH, sets)
    xp = _random_xp(seed=3, low=-0.45, high=WIDTH - 0.55)
    pm = decode_images(desc, synthesize_images(desc, xp, 1500.0, 1000.0))
    assert pm.valid.all()
    np.testing.assert_allclose(pm.xp, xp, rtol=0, atol=1e-6)


def test_gray_code_with_finer_sets_is_exact():
    sets = (PhaseSet("p64", 64.0, 4), PhaseSet("p8", 8.0, 4), GrayCodeSet("g", 6))
    desc = PatternDescription(WIDTH, sets)
    xp = _random_xp(seed=4)
    pm = decode_images(desc, synthesize_images(desc, xp, 1500.0, 1000.0))
    np.testing.assert_allclose(pm.xp, xp, rtol=0, atol=1e-6)


def test_horizontal_orientation_decodes_the_same_coordinate():
    sets = tuple(PhaseSet(f"p{p:g}", p, 4, orientation="horizontal") for p in (800.0, 20.0))
    desc = PatternDescription(800, sets, sensor=_gaussian_sensor(1.0))  # ratio 40 needs it
    xp = _random_xp(seed=5, high=799.0)
    pm = decode_images(desc, synthesize_images(desc, xp, 900.0, 600.0))
    assert pm.orientation == "horizontal"
    np.testing.assert_allclose(pm.xp, xp, rtol=0, atol=1e-6)


def test_chunking_does_not_change_the_result():
    desc = _three_periods()
    xp = _random_xp(seed=6)
    rng = np.random.default_rng(6)
    images = [im + rng.normal(0, 5.0, im.shape) for im in synthesize_images(desc, xp, 1500.0,
                                                                            1000.0)]
    whole = decode_images(desc, images, chunk_rows=1000)
    split = decode_images(desc, images, chunk_rows=7)
    np.testing.assert_array_equal(whole.mask, split.mask)
    np.testing.assert_allclose(whole.xp, split.xp, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ noise vs model

def _check_noise(pm: PhaseMap, xp: np.ndarray) -> float:
    """No unwrapping error among valid pixels; return std(err) / rms(sigma)."""
    valid = pm.valid
    assert valid.mean() > 0.99
    err = pm.xp[valid] - xp[valid]
    sigma = pm.sigma_xp[valid].astype(np.float64)
    assert np.abs(err).max() < 8 * sigma.max()  # a wrong fringe order is >= 16 px
    assert np.std(err / sigma) == pytest.approx(1.0, rel=0.10)
    return float(np.std(err) / np.sqrt(np.mean(sigma ** 2)))


@pytest.mark.parametrize("sigma_dn", [0.5, 2.0, 8.0, 20.0])
def test_gaussian_noise_std_matches_predicted_sigma(sigma_dn):
    desc = _three_periods(sensor=_gaussian_sensor(sigma_dn))
    xp = _random_xp(seed=10)
    rng = np.random.default_rng(int(sigma_dn * 10))
    images = [im + rng.normal(0.0, sigma_dn, im.shape)
              for im in synthesize_images(desc, xp, 1500.0, 1000.0)]
    ratio = _check_noise(decode_images(desc, images), xp)
    assert ratio == pytest.approx(1.0, rel=0.10)  # acceptance: within 10 %


@pytest.mark.parametrize("steps,shifts", [(3, ()), (4, ()), (5, UNEQUAL)])
def test_shot_read_quantisation_noise_matches_predicted_sigma(steps, shifts):
    # 12-bit camera, 4 e-/DN, 8 e- read noise; shot noise makes the variance depend on I
    # (and on phi for N = 3); integer images add the quantisation term
    sensor = SensorModel(bit_depth=12, gain_e_per_dn=4.0, read_noise_e=8.0)
    desc = _three_periods(steps, shifts, sensor=sensor)
    xp = _random_xp(seed=20 + steps)
    rng = np.random.default_rng(steps)
    images = []
    for im in synthesize_images(desc, xp, 1000.0, 900.0):
        noisy = im + rng.normal(0.0, 1.0, im.shape) * np.sqrt(4.0 + im / 4.0)
        images.append(np.clip(np.rint(noisy), 0, 4095).astype(np.uint16))
    ratio = _check_noise(decode_images(desc, images), xp)
    assert ratio == pytest.approx(1.0, rel=0.10)


def test_gray_code_noise_matches_predicted_sigma():
    sensor = _gaussian_sensor(10.0)
    desc = PatternDescription(WIDTH, (PhaseSet("p16", 16.0, 4), GrayCodeSet("g", 8)),
                              sensor=sensor)
    xp = _random_xp(seed=30)
    rng = np.random.default_rng(30)
    images = [im + rng.normal(0.0, 10.0, im.shape)
              for im in synthesize_images(desc, xp, 1500.0, 1000.0)]
    assert _check_noise(decode_images(desc, images), xp) == pytest.approx(1.0, rel=0.10)


# -------------------------------------------------------------------------- masks

def _mask_scene() -> tuple[PatternDescription, np.ndarray, list[np.ndarray]]:
    """uint16 images with a saturated, a dark, an inconsistent and an outside band."""
    sets = tuple(PhaseSet(f"p{p:g}", p, 4) for p in (1400.0, 80.0, 16.0))
    desc = PatternDescription(WIDTH, sets, sensor=SensorModel(bit_depth=12))
    xp = _random_xp(seed=40)
    xp[:, 192:224] = np.random.default_rng(41).uniform(1300, 1330, (SHAPE[0], 32))
    offset = np.full(SHAPE, 1500.0)
    modulation = np.full(SHAPE, 1000.0)
    offset[:, :32], modulation[:, :32] = 3600.0, 1000.0  # peaks at 4600 > 4095
    offset[:, 32:64], modulation[:, 32:64] = 20.0, 0.0  # dark
    images = synthesize_images(desc, xp, offset, modulation)
    shifted = xp + 0.4 * 80.0  # the 80 px set disagrees by 0.4 cycles
    images[1][:, :, 64:96] = synthesize_images(desc, shifted, offset, modulation)[1][:, :,
                                                                                     64:96]
    rng = np.random.default_rng(42)
    noisy = [np.clip(np.rint(im + rng.normal(0, 2.0, im.shape)), 0, 4095).astype(np.uint16)
             for im in images]
    return desc, xp, noisy


def test_masks_carry_the_right_reason():
    desc, xp, images = _mask_scene()
    pm = decode_images(desc, images)
    assert (pm.mask[:, :32] == MASK_SATURATED).all()
    assert (pm.mask[:, 32:64] == MASK_LOW_MODULATION).all()
    assert (pm.mask[:, 64:96] == MASK_INCONSISTENT).all()
    assert (pm.mask[:, 192:224] == MASK_OUT_OF_RANGE).all()
    rest = np.r_[96:192, 224:256]
    assert (pm.mask[:, rest] == MASK_VALID).all()
    assert np.isnan(pm.xp[~pm.valid]).all() and np.isnan(pm.sigma_xp[~pm.valid]).all()
    assert np.abs(pm.xp[pm.valid] - xp[pm.valid]).max() < 0.5
    counts = pm.counts()
    assert counts == {"valid": 64 * 128, "saturated": 64 * 32, "low_modulation": 64 * 32,
                      "inconsistent": 64 * 32, "out_of_range": 64 * 32}
    assert pm.summary().startswith("8192 of 16384 pixels valid (50.0 %); masked: saturated "
                                   "2048, low_modulation 2048")


def test_absolute_modulation_floor():
    desc = _three_periods(thresholds=Thresholds(min_modulation_dn=150.0),
                          sensor=_gaussian_sensor(1.0))
    xp = _random_xp(seed=50)
    modulation = np.where(np.arange(SHAPE[1]) < 128, 100.0, 200.0) * np.ones(SHAPE)
    pm = decode_images(desc, synthesize_images(desc, xp, 500.0, modulation))
    assert (pm.mask[:, :128] == MASK_LOW_MODULATION).all() and pm.valid[:, 128:].all()


def test_noise_too_large_to_unwrap_is_low_modulation():
    # sigma_I = 100 DN, B = 1000, 4 steps: the 1280 px set predicts sigma_x = 1280 / 2 pi
    # sqrt(2 / 4) 0.1 = 14.4 px; times the margin 2 that is 0.36 cycles of 80 px > 0.25
    desc = _three_periods(sensor=_gaussian_sensor(100.0))
    xp = _random_xp(seed=51)
    rng = np.random.default_rng(51)
    images = [im + rng.normal(0, 100.0, im.shape)
              for im in synthesize_images(desc, xp, 1500.0, 1000.0)]
    pm = decode_images(desc, images)
    # the odds of the neighbouring order, exp(-(1 - 2 |r|) / (2 sigma^2)), stay below
    # those of a 6 sigma excursion only where the residual r happens to be near 0 and
    # the pixel's estimated B high: a few pixels, each with the right order
    assert np.mean(pm.mask == MASK_LOW_MODULATION) > 0.97  # measured 0.984
    assert np.abs(pm.xp[pm.valid] - xp[pm.valid]).max() < 16.0 / 4


def test_gray_code_masks_inconsistent_and_undecidable_bits():
    desc = PatternDescription(WIDTH, (PhaseSet("p16", 16.0, 4), GrayCodeSet("g", 8,
                                                                            inverse=True)))
    # pixels at stripe centres; the Gray code of the first 16 columns says one stripe
    # further (a local fault: a fifth of the frame would look like a misstated coding)
    xp = (np.floor(_random_xp(seed=60) / 8.0) + 0.5) * 8.0
    images = synthesize_images(desc, xp, 1500.0, 1000.0)
    images[1][:, :, :16] = synthesize_images(desc, xp + 8.0, 1500.0, 1000.0)[1][:, :, :16]
    images[1][3, :, 128:192] = images[1][3 + 8, :, 128:192]  # bit 3 equals its inverse
    pm = decode_images(desc, images)
    assert (pm.mask[:, :16] == MASK_INCONSISTENT).all()
    # bit 3 undecidable: the pixel may lie anywhere in its block of 32 cells, which the
    # 16 px phase cannot order - unless the bit's two readings are neighbouring cells
    # (the bit flips at the pixel's own cell edge): the phase then picks the right one
    grey = pm.mask[:, 128:192]
    assert np.isin(grey, [MASK_LOW_MODULATION, MASK_VALID]).all()
    assert (grey == MASK_LOW_MODULATION).mean() > 0.8
    ordered = pm.valid[:, 128:192]
    np.testing.assert_allclose(pm.xp[:, 128:192][ordered], xp[:, 128:192][ordered],
                               atol=0.01)
    assert pm.valid[:, 16:128].all() and pm.valid[:, 192:].all()


# ---------------------------------------------------------------------- bad input

def test_decode_rejects_bad_stacks():
    desc = _three_periods()
    good = synthesize_images(desc, _random_xp(seed=70), 1500.0, 1000.0)
    with pytest.raises(InputError, match="got 2 image stacks for 3 sets"):
        decode_images(desc, good[:2])
    with pytest.raises(InputError, match=r"set 'p80' needs a real \(4, H, W\) stack"):
        decode_images(desc, [good[0], good[1][:3], good[2]])
    with pytest.raises(InputError, match="mismatched image sizes: set 'p16'"):
        decode_images(desc, [good[0], good[1], good[2][:, :, :100]])
    bad = good[2].copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="set 'p16' contain NaN"):
        decode_images(desc, [good[0], good[1], bad])


def test_phase_map_refuses_numbers_under_a_mask():
    xp = np.zeros((2, 2))
    mask = np.array([[0, 2], [0, 0]], np.uint8)
    with pytest.raises(InputError, match="NaN where mask != 0"):
        PhaseMap(xp, xp, xp, mask, xp, period_px=16.0)
    with pytest.raises(InputError, match="unknown reason codes"):
        PhaseMap(xp, xp, xp, np.full((2, 2), 9, np.uint8), xp, period_px=16.0)
    with pytest.raises(InputError, match="shape of xp"):
        PhaseMap(xp, xp[:1], xp, np.zeros((2, 2), np.uint8), xp, period_px=16.0)


def test_x_p_comes_from_the_finest_period_unless_fusion_is_asked_for():
    from dataclasses import replace

    from scanqa.decoding.coding import DecodeOptions

    # the 80 px set is biased by +0.5 px (as a projector's nonlinearity biases a period):
    # x_p from the finest set alone carries none of it, a fusion some, and both say so
    desc = _three_periods(sensor=_gaussian_sensor(3.0))
    xp = _random_xp(seed=80)
    rng = np.random.default_rng(80)
    images = synthesize_images(desc, xp, 1500.0, 1000.0)
    images[1] = synthesize_images(desc, xp + 0.5, 1500.0, 1000.0)[1]
    images = [im + rng.normal(0.0, 3.0, im.shape) for im in images]
    finest = decode_images(desc, images)
    fused = decode_images(replace(desc, options=DecodeOptions(fuse_periods=True)), images)
    assert finest.valid.mean() > 0.99 and fused.valid.mean() > 0.99
    bias_finest = np.nanmean(finest.xp - xp)
    bias_fused = np.nanmean(fused.xp - xp)
    assert abs(bias_finest) < 0.002  # px
    # inverse-variance weight of the 80 px set: (16/80)^2 / (1 + (16/80)^2) = 0.0385
    assert bias_fused == pytest.approx(0.5 * 0.0385, rel=0.1)
    assert np.nanmedian(fused.sigma_xp) < np.nanmedian(finest.sigma_xp)
    rows = {r["set"]: r for r in finest.provenance["decode"]["disagreement"]}
    assert rows["p80"]["median_px"] == pytest.approx(0.5, abs=0.01)
    assert "x_p: finest set 'p16' alone" in finest.summary()
    assert "inverse-variance fusion of every phase set" in fused.summary()
