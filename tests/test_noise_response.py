"""Camera noise estimated from the images, and the projector response (gamma) measured,
stored and corrected - on synthetic captures with known noise and known truth, and in
closed loop through the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from scanqa.decoding.coding import (
    GrayCodeSet,
    PatternDescription,
    PhaseSet,
    ReferenceSet,
    SensorModel,
)
from scanqa.decoding.decoder import decode_images, measure_response
from scanqa.decoding.noise import fit_variance
from scanqa.decoding.response import load_response, save_response
from scanqa.errors import ConfigError

SHAPE = (128, 256)
GAIN, READ_E = 4.0, 8.0  # the camera the images are made with: 4 e-/DN, 2 DN read noise


def _camera(frames: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Shot and read noise of a 4 e-/DN, 8 e- camera, 12-bit integers [DN]."""
    sigma = np.sqrt((READ_E / GAIN) ** 2 + np.maximum(frames, 0) / GAIN)
    return np.clip(np.rint(frames + rng.normal(size=frames.shape) * sigma), 0,
                   4095).astype(np.uint16)


def _phase(x, period, steps, a=1200.0, b=900.0, gamma=1.0):
    shifts = 2 * np.pi * np.arange(steps) / steps
    p = 0.5 + 0.5 * np.cos(2 * np.pi * x / period + shifts[:, None, None])
    return a - b + 2 * b * p ** gamma


def _gray(x, cell, bits, inverse=False, a=1200.0, b=900.0):
    c = np.clip(np.rint(x), 0, None).astype(int) // cell
    code = c ^ (c >> 1)
    planes = np.stack([(code >> (bits - 1 - k)) & 1 for k in range(bits)]).astype(float)
    if inverse:
        planes = np.stack([p for plane in planes for p in (plane, 1 - plane)])
    return a - b + 2 * b * planes


def _x(seed, width=1280.0):
    return np.random.default_rng(seed).uniform(0, width - 1, SHAPE)


#: Offset of a scene whose brightness varies (a constant level could not tell read from
#: shot noise): 100 to 2000 DN across the frame [DN].
LEVEL = 100.0 + 1900.0 * np.linspace(0.0, 1.0, SHAPE[1])[None, :] * np.ones(SHAPE)


def _noise_of(pm) -> dict:
    return pm.provenance["decode"]["noise"]


def _ratio(pm, x) -> float:
    v = pm.valid
    assert v.mean() > 0.97
    return float(np.std((pm.xp[v] - x[v]) / pm.sigma_xp[v]))


# ------------------------------------------------------------------------- noise

def test_fit_variance_recovers_a_known_model():
    rng = np.random.default_rng(0)
    level = rng.uniform(0, 3000, 200000)
    true = 4.0 + level / 4.0
    s2 = true * rng.chisquare(1, level.size)  # one degree of freedom per sample
    a, b = fit_variance(s2, np.ones(level.size), level)
    assert b == pytest.approx(0.25, rel=0.03)
    assert a == pytest.approx(4.0, abs=1.5)


@pytest.mark.parametrize("steps,source", [(4, "residuals of the N-step fits"),
                                          (3, "offsets of the phase sets")])
def test_noise_from_phase_sets_predicts_the_phase_noise(steps, source):
    sets = tuple(PhaseSet(f"p{p:g}", p, steps) for p in (1280.0, 80.0, 16.0))
    desc = PatternDescription(1280, sets, sensor=SensorModel(bit_depth=12))
    x = _x(steps)
    rng = np.random.default_rng(steps)
    pm = decode_images(desc, [_camera(_phase(x, p, steps, LEVEL, 0.8 * LEVEL), rng)
                              for p in (1280, 80, 16)])
    noise = _noise_of(pm)
    assert noise["source"].startswith(f"estimated from the images: {source}")
    assert noise["gain_e_per_dn"] == pytest.approx(GAIN, rel=0.1)
    assert _ratio(pm, x) == pytest.approx(1.0, abs=0.1)  # predicted sigma holds


def test_noise_from_white_black_repeats_and_from_inverse_sums():
    x = _x(7)
    rng = np.random.default_rng(7)
    ref = np.stack([np.full(SHAPE, 2100.0), np.full(SHAPE, 20.0)])  # black: read noise
    gray = _gray(x, 8, 8, a=1060.0, b=1040.0)
    desc = PatternDescription(1280, (ReferenceSet("wb"), GrayCodeSet("g", 8, cell_px=8.0),
                                     PhaseSet("p48", 48.0, 3)),
                              sensor=SensorModel(bit_depth=12))
    pm = decode_images(desc, [_camera(ref, rng), _camera(gray, rng),
                              _camera(_phase(x, 48.0, 3), rng)])
    noise = _noise_of(pm)
    assert "repeats of the white and black levels" in noise["source"]
    assert noise["gain_e_per_dn"] == pytest.approx(GAIN, rel=0.1)
    assert noise["read_noise_dn"] == pytest.approx(READ_E / GAIN, rel=0.25)
    assert _ratio(pm, x) == pytest.approx(1.0, abs=0.1)
    desc = PatternDescription(1280, (GrayCodeSet("g", 8, cell_px=8.0, inverse="interleaved"),
                                     PhaseSet("p48", 48.0, 3)),
                              sensor=SensorModel(bit_depth=12))
    pm = decode_images(desc, [_camera(_gray(x, 8, 8, True, LEVEL, 0.8 * LEVEL), rng),
                              _camera(_phase(x, 48.0, 3), rng)])
    noise = _noise_of(pm)
    assert "pattern + inverse sums" in noise["source"]
    assert noise["gain_e_per_dn"] == pytest.approx(GAIN, rel=0.1)


def test_without_a_noise_source_the_default_model_is_named():
    desc = PatternDescription(1280, (PhaseSet("p", 1400.0, 3),), sensor=SensorModel(bit_depth=12))
    x = _x(8)
    pm = decode_images(desc, [_camera(_phase(x, 1400.0, 3), np.random.default_rng(8))])
    assert "noise: default model (4 e-/DN, 8 e-): the images hold no noise source" in \
        pm.summary()
    # and one loud line says that every sigma is assumed and what to give
    warnings = pm.provenance["decode"]["warnings"]
    assert sum("every sigma of this scan is ASSUMED" in w for w in warnings) == 1
    assert "give [sensor] gain_e_per_dn and read_noise_e" in warnings[0]


def test_a_dark_scan_names_its_reason_and_the_key():
    sets = tuple(PhaseSet(f"p{p:g}", p, 4) for p in (1280.0, 80.0, 16.0))
    desc = PatternDescription(1280, sets, sensor=SensorModel(bit_depth=12))
    x = _x(9)
    rng = np.random.default_rng(9)
    pm = decode_images(desc, [_camera(_phase(x, p, 4, a=60.0, b=6.0), rng)
                              for p in (1280, 80, 16)])
    assert pm.valid.mean() < 0.5
    last = pm.summary().splitlines()[-1]
    assert last.startswith("most pixels are masked: low_modulation")
    assert "thresholds.unwrap_sigma_margin (now 2)" in last
    assert "give the camera's [sensor] gain_e_per_dn and read_noise_e" in last


# --------------------------------------------------------------------- response

def _flat(seed: int, tilt: float) -> np.ndarray:
    v, u = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    return 20.0 + seed + tilt * u + 0.07 * v


def test_gamma_is_measured_on_one_flat_and_corrects_another(tmp_path):
    # a projector with gamma 2.2, a Gray code ordering a 3-step set of 32 px: its phase
    # carries the 3-phi ripple of the aliased second harmonic (~0.28 rad)
    desc = PatternDescription(1280, (GrayCodeSet("g", 8, cell_px=8.0, inverse="interleaved"),
                                     PhaseSet("p32", 32.0, 3)),
                              sensor=SensorModel(bit_depth=12, gain_e_per_dn=GAIN,
                                                 read_noise_e=READ_E))

    def capture(x, seed):
        rng = np.random.default_rng(seed)
        return [_camera(_gray(x, 8, 8, inverse=True), rng),
                _camera(_phase(x, 32.0, 3, gamma=2.2), rng)]

    first, second = _flat(0, 4.1), _flat(3, 3.7)
    response, _ = measure_response(desc, capture(first, 0), "flat 1")
    save_response(tmp_path / "response.toml", response)
    loaded = load_response(tmp_path / "response.toml")
    np.testing.assert_allclose(loaded.tables[0].error_rad, response.tables[0].error_rad,
                               atol=1e-6)
    raw = decode_images(desc, capture(second, 1))
    fixed = decode_images(desc, capture(second, 1), response=loaded)
    assert raw.valid.mean() > 0.97 and fixed.valid.mean() > 0.97
    before, after = _ripple(raw, second, 32.0), _ripple(fixed, second, 32.0)
    assert before > 0.8  # px: the uncorrected ripple (measured 1.05 px)
    assert after < 0.1 * before  # acceptance: corrected error below 0.1 x
    # what is left is mostly the noise the decoder predicts (rms 0.088 px)
    err = fixed.xp[fixed.valid] - second[fixed.valid]
    assert np.std(err / fixed.sigma_xp[fixed.valid]) < 1.2
    assert "projector response" in fixed.summary()


def _ripple(pm, truth: np.ndarray, period: float, bins: int = 32) -> float:
    """RMS over the phase cycle of the mean error in bins of the true phase [px]: the
    systematic error, without the noise."""
    v = pm.valid & np.isfinite(truth)
    err = pm.xp[v] - truth[v]
    index = np.minimum((np.mod(truth[v] / period, 1.0) * bins).astype(int), bins - 1)
    means = np.array([err[index == i].mean() for i in range(bins)])
    return float(np.sqrt(np.mean((means - means.mean()) ** 2)))


def test_a_response_without_the_finest_set_is_refused(tmp_path):
    sensor = SensorModel(bit_depth=12, gain_e_per_dn=4.0, read_noise_e=8.0)
    desc = PatternDescription(1280, (PhaseSet("p1280", 1280.0, 4), PhaseSet("p80", 80.0, 4),
                                     PhaseSet("p16", 16.0, 4)), sensor=sensor)
    x = _flat(0, 4.5)
    rng = np.random.default_rng(1)
    images = [_camera(_phase(x, p, 4), rng) for p in (1280.0, 80.0, 16.0)]
    response, _ = measure_response(desc, images)
    other = PatternDescription(1280, (PhaseSet("p1280", 1280.0, 4), PhaseSet("p80", 80.0, 4),
                                      PhaseSet("p20", 20.0, 4)), sensor=sensor)
    with pytest.raises(ConfigError, match=r"no table for the finest set 'p20' \(period 20 "
                                          r"px, 4 steps; it has: .*16 px x 4\)"):
        decode_images(other, images, response=response)


@pytest.mark.slow
def test_simulated_projector_gamma_is_corrected_in_closed_loop():
    """Simulated: a gamma 2.2 projector, measured on a plane at 450 mm, checked on one at
    446 mm (another scan, another noise stream) against the simulator's truth."""
    from scanqa.model.config import load_config
    from scanqa.simulator import experiments, render, scene
    from tests.conftest import ROOT

    config = load_config(ROOT / "sample_data" / "sample_scanner.toml", profile="binned8_roi")
    config = config.replace_simulator(projector_gamma=2.2, scene_noise_rel=0.0,
                                      read_noise_e=1.0, bit_depth=16, gain_e_per_dn=40.0,
                                      mean_signal_e=8e5, full_well_e=2.4e6)
    desc = experiments.pattern_description(config, periods=[20.0])

    def scan(z, repeat):
        pos = experiments.Position(repeat, z, 0.0, 0.0, scene.plane_scene(z))
        acq = experiments.acquisition(config, pos, repeat)
        return render.render_images(config, acq, desc), render.truth_for(config, acq)

    (first, _), (second, truth) = scan(450.0, 0), scan(446.0, 1)
    response, _ = measure_response(desc, first)
    raw = decode_images(desc, second)
    fixed = decode_images(desc, second, response=response)
    assert raw.valid.mean() > 0.99 and fixed.valid.mean() > 0.99
    before, after = _ripple(raw, truth.xp, 20.0), _ripple(fixed, truth.xp, 20.0)
    assert before > 0.01  # px: the ripple of gamma 2.2 at 4 steps
    assert after < 0.1 * before  # acceptance (measured 0.0215 -> 0.0017 px)
