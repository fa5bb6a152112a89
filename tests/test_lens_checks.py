"""Lens models that cannot be the device's: refused when they fold over a quarter of the
frame, warned when they fold in part of it or bend its edge implausibly.

Expected values come from the radial model's closed form, not from scanqa's
undistortion: with k1 < 0 alone, r_d = r (1 + k1 r^2) rises to its maximum
(2 / 3) sqrt(-1 / (3 k1)) at r = sqrt(-1 / (3 k1)); pixels whose distorted radius lies
beyond it have no ray.
"""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest

from scanqa.calibration.parametric import Lens, ParametricCalibration
from scanqa.calibration.parametric_checks import (
    FOLD_SHARE_REFUSED,
    LENS_GRID,
    lens_fold_share,
    lens_warnings,
)
from scanqa.errors import InputError

#: A camera and projector like the SLStudio example's (1688 x 1352 px, f 2195 px;
#: 1824 x 1140 px panel, f 2602 px), the projector 165 mm to the side.
KC = np.array([[2195.1, 0, 843.5], [0, 2195.1, 675.5], [0, 0, 1.0]])
KP = np.array([[2601.5, 0, 866.5], [0, 2601.5, 1109.1], [0, 0, 1.0]])
ROT, T = np.eye(3), np.array([-160.0, 0.0, 0.0])


def calibration(kc=(0.0,) * 5, kp=(0.0,) * 5) -> ParametricCalibration:
    return ParametricCalibration(Lens(KC, np.asarray(kc, float), 1688, 1352),
                                 Lens(KP, np.asarray(kp, float), 1824, 1140), ROT, T,
                                 source="cal.xml")


def distorted_radius_grid() -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, 1687, LENS_GRID), np.linspace(0, 1351, LENS_GRID))
    return np.hypot((u - KC[0, 2]) / KC[0, 0], (v - KC[1, 2]) / KC[1, 1])


@pytest.mark.parametrize("k1", [-1.1, -1.2])
def test_fold_share_is_the_radial_model_closed_form(k1):
    rd_max = 2.0 / 3.0 * np.sqrt(-1.0 / (3.0 * k1))
    expected = float(np.mean(distorted_radius_grid() > rd_max))
    assert 0 < expected < FOLD_SHARE_REFUSED  # the corners fold, the model is kept
    lens = Lens(KC, np.array([k1, 0, 0, 0, 0.0]), 1688, 1352)
    assert lens_fold_share(lens) == pytest.approx(expected, abs=2.0 / LENS_GRID ** 2)
    warned = lens_warnings(calibration(kc=[k1, 0, 0, 0, 0]))
    assert any(f"folds over at {100 * expected:.0f} %" in w for w in warned)


def test_lens_folding_over_most_of_the_frame_is_refused():
    k1 = -50.0  # the fold at r_d = 0.054, 119 px from the centre
    expected = float(np.mean(distorted_radius_grid() > 2.0 / 3.0 * np.sqrt(1 / 150.0)))
    assert expected > FOLD_SHARE_REFUSED
    with pytest.raises(InputError, match=rf"cal.xml: the camera's lens model \(Kc with kc = "
                                         rf"\[-50.0, .*folds over at {100 * expected:.0f} %"):
        calibration(kc=[k1, 0, 0, 0, 0])


def test_a_tiny_focal_length_is_named_with_the_matrix():
    kp = np.array([[2.6, 0, 866.5], [0, 2.6, 1109.1], [0, 0, 1.0]])
    with pytest.raises(InputError, match="projector's lens model \\(Kp with kp"):
        ParametricCalibration(Lens(KC, np.zeros(5), 1688, 1352),
                              Lens(kp, np.array([-0.03, 0, 0, 0, 0.0]), 1824, 1140), ROT, T)


def test_strong_distortion_is_warned_with_its_size():
    # k1 = 50 does not fold (r_d rises monotonically) but moves the frame's corner from
    # r = root of r + 50 r^3 = r_d to r_d: (r_d - r) / r_d
    rd = distorted_radius_grid().max()
    r = min(x.real for x in np.roots([50.0, 0.0, 1.0, -rd]) if abs(x.imag) < 1e-12)
    warned = lens_warnings(calibration(kp=[0, 0, 0, 0, 0], kc=[50.0, 0, 0, 0, 0]))
    assert len(warned) == 1 and "camera's distortion kc" in warned[0]
    percent = float(re.search(r"by up to (\d+) %", warned[0]).group(1))
    assert percent == round(100 * (rd - r) / rd)


def test_a_real_lens_is_not_warned(caplog):
    with caplog.at_level(logging.WARNING):
        cal = calibration(kc=[-0.058, 0, 0, 0, 0], kp=[-0.0315, 0, 0, 0, 0])
    assert lens_warnings(cal) == [] and caplog.records == []
