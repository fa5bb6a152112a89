"""Same images through the ``fringes`` package (PyPI) and through scanqa.

fringes models ``I_n = A + B cos(2 pi v x / L - 2 pi f n / N - p0)``; with
``reverse=True`` (f -> -f) and ``p0 = 0`` the shifts are +2 pi n / N, scanqa's
convention, so both must report the same wrapped phase. fringes computes in float32,
hence the 1e-4 rad tolerance of the acceptance criterion (observed: ~2.4e-7 rad).
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from scanqa.decoding.coding import PatternDescription, PhaseSet, SensorModel
from scanqa.decoding.decoder import decode_images
from scanqa.decoding.demodulate import demodulate
from scanqa.decoding.patternset import synthesize_images

fringes = pytest.importorskip("fringes")

WIDTH = 1280
PERIODS = (1280.0, 80.0, 16.0)


@pytest.fixture(scope="module")
def decoded():
    logging.getLogger("fringes").setLevel(logging.ERROR)
    sets = tuple(PhaseSet(f"p{p:g}", p, 4) for p in PERIODS)
    desc = PatternDescription(WIDTH, sets, sensor=SensorModel(bit_depth=12))
    rng = np.random.default_rng(7)
    xp = rng.uniform(1.0, WIDTH - 2.0, (32, 128))
    offset = np.full(xp.shape, 1500.0)
    offset[:, :8] = 3800.0  # saturated in scanqa, decoded anyway by fringes
    images = [np.clip(np.rint(im + rng.normal(0, 3.0, im.shape)), 0, 4095).astype(np.uint16)
              for im in synthesize_images(desc, xp, offset, 1000.0)]
    f = fringes.Fringes(X=WIDTH, Y=16, K=len(PERIODS), N=4,
                        v=tuple(WIDTH / p for p in PERIODS), axes=(1,), reverse=True, p0=0.0,
                        dtype="uint16")
    theirs = f.decode(np.concatenate(images), verbose=True)
    return desc, xp, images, theirs


def test_wrapped_phase_agrees_within_1e4_rad(decoded):
    desc, _, images, theirs = decoded
    ours = decode_images(desc, images)
    both = ours.valid & np.isfinite(theirs.x[0, :, :, 0])
    assert both.mean() > 0.9
    for i in range(len(PERIODS)):
        phase = demodulate(images[i]).phase_rad
        diff = np.angle(np.exp(1j * (phase - theirs.p[i, :, :, 0].astype(np.float64))))
        assert np.abs(diff[both]).max() < 1e-4  # acceptance criterion [rad]


def test_modulation_and_coordinate_agree(decoded):
    desc, xp, images, theirs = decoded
    ours = decode_images(desc, images)
    both = ours.valid & np.isfinite(theirs.x[0, :, :, 0])
    b_fine = theirs.b[len(PERIODS) - 1, :, :, 0]
    np.testing.assert_allclose(ours.modulation[both], b_fine[both], rtol=1e-4)
    # both fuse all periods by inverse-variance weights; fringes' weights ignore the
    # noise model's offset term, so the fused values differ by a fraction of the noise
    diff = ours.xp[both] - theirs.x[0, :, :, 0][both]
    assert np.abs(diff).max() < 5 * np.nanmax(ours.sigma_xp)
    assert np.abs(ours.xp[both] - xp[both]).max() < 0.1
