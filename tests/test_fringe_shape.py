"""Fringes that are not sine waves are found from the data (scanqa.decoding.waveform).

A 3-step set of 50 % square waves reads six phase values: x_p is a staircase that errs
by up to P/12 (a property of the profile, computed here from the truth, not from the
code). The decode must name the set, and its sigma_xp must carry the staircase's rms
(P / (12 sqrt 3), a uniform error over steps of P/6); the same scan with sine fringes
must not be named.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanqa.decoding.coding import GrayCodeSet, PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.patternset import ideal_patterns, synthesize_images

PERIOD = 96.0
WIDTH = 1536


def _scan(square: bool, seed: int, steps: int = 3):
    desc = PatternDescription(WIDTH, (
        GrayCodeSet("g", 5, cell_px=PERIOD / 2, inverse="interleaved", orders="fine"),
        PhaseSet("fine", PERIOD, steps)),
        sensor=SensorModel(gain_e_per_dn=20.0, read_noise_e=20.0))
    rows, cols = 40, 1400
    truth = np.linspace(20.0, WIDTH - 60.0, cols)[None, :] + np.linspace(0, 30, rows)[:, None]
    stacks = synthesize_images(desc, truth, 110.0, 70.0)
    if square:
        binary = (ideal_patterns(desc, 1, truth) >= 0.5).astype(float)
        stacks[1] = 110.0 - 70.0 + 140.0 * binary
    rng = np.random.default_rng(seed)
    images = [np.clip(np.rint(s + rng.normal(0.0, 1.0, s.shape)), 0, 255).astype(np.uint8)
              for s in stacks]
    return decode_images(desc, images), truth


def _named(pm) -> list[str]:
    return [w for w in pm.provenance["decode"]["warnings"] if "not sine waves" in w]


@pytest.mark.parametrize("seed", [0, 1])
def test_square_wave_3_step_fringes_are_named_and_carried_into_sigma(seed):
    pm, truth = _scan(square=True, seed=seed)
    valid = pm.valid
    assert valid.mean() > 0.9
    error = pm.xp[valid] - truth[valid]
    # the staircase itself: six values per period, x_p off by up to P/12
    assert 0.8 * PERIOD / 12 < np.abs(error).max() < 1.2 * PERIOD / 12
    named = _named(pm)
    assert len(named) == 1 and "'fine'" in named[0] and "clusters" in named[0], named
    staircase_rms = PERIOD / (12 * math.sqrt(3))
    assert np.median(pm.sigma_xp[valid]) >= 0.9 * staircase_rms
    assert np.std(error) <= 1.2 * np.median(pm.sigma_xp[valid])


@pytest.mark.parametrize("seed", [0, 1])
def test_sine_fringes_are_not_named(seed):
    pm, truth = _scan(square=False, seed=seed)
    assert pm.valid.mean() > 0.9
    assert _named(pm) == []
    assert np.median(pm.sigma_xp[pm.valid]) < 0.5
    assert np.abs(pm.xp[pm.valid] - truth[pm.valid]).max() < 2.0


def test_square_wave_4_step_fringes_are_named_with_their_error():
    # four shifts of a 50 % square wave read four phase values: a coarser staircase,
    # whose spread sigma_xp must carry
    pm, truth = _scan(square=True, seed=2, steps=4)
    error = pm.xp[pm.valid] - truth[pm.valid]
    named = _named(pm)
    assert len(named) == 1 and "4-step phase clusters" in named[0], named
    assert 0.8 * np.std(error) <= np.median(pm.sigma_xp[pm.valid]) <= 1.25 * np.std(error)
